"""An independent contact-dynamics crawler (MuJoCo) as a test source for fitlug.

Nothing here uses fitlug's model, fit or kinematic simulator: the motion comes from a
closed chain of rigid links driven by friction round two wheels, lugs on shear springs with
Coulomb friction at their tips, and a free chassis on a skid (docs/engine.md). MuJoCo is an
optional dependency (`pip install fitlug[engine]`), imported only when a case is run.
"""

from __future__ import annotations

from ._case import EngineCase as EngineCase

__all__ = ["EngineCase", "simulate_engine", "same_physics", "CASES"]


def simulate_engine(case: EngineCase, out_dir: str | None = None, seed: int = 0,
                    probes: dict | None = None) -> dict:
    """Run `case` in MuJoCo and measure what the engine itself says (truth.json's figures).

    Args:
        case: the settings (mm, s, kg, N).
        out_dir: when given, write the recording folder there (trajectories.csv, rig.toml,
            truth.json).
        seed: seed of the markers' white noise.
        probes: the "probes" of an earlier run whose physics is the same (`same_physics`):
            only the camera (fps, markers, noise) differs, so it is not simulated again.

    Returns:
        The truth dict (slip at cruise, shear, contacts, body motion, force balance), with
        the raw 1 kHz probes under the key "probes" (not written).

    Raises:
        ImportError: mujoco is not installed.
        ValueError: settings the engine cannot build (see EngineCase).
    """
    from ._measure import measure
    from ._run import run_case

    if probes is None:
        probes = run_case(case)
    truth = measure(case, probes)
    if out_dir is not None:
        from ._write import write_recording

        write_recording(case, probes, truth, out_dir, seed)
    return dict(truth, probes=probes)


def same_physics(a: EngineCase, b: EngineCase) -> bool:
    """Whether two cases differ only in what the camera sees (fps, markers, noise)."""
    camera = {"name", "notes", "fps", "marker_h", "lug_markers", "body_markers",
              "noise_lug_mm", "noise_body_mm", "camera_window_mm"}
    da, db = a.settings(), b.settings()
    return all(da[k] == db[k] for k in da if k not in camera | {"duration_s"})


def __getattr__(name):
    if name == "CASES":
        from ._cases import CASES

        return CASES
    raise AttributeError(name)
