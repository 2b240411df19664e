"""A recording folder from the engine's probes: trajectories.csv, rig.toml, truth.json."""

from __future__ import annotations

import json
import os

import numpy as np

from ._case import EngineCase


def marker_tracks(case: EngineCase, o: dict, rng: np.random.Generator) -> list:
    """[(name, role, t, x, y)] at the camera's frames, mm in the ground frame (x from the
    chassis' start, y up), with white noise at the case's levels."""
    every = round(1000.0 / case.fps)
    idx = np.arange(0, len(o["t"]), every)
    t = o["t"][idx]
    x0 = o["chassis_x0"] * 1e3
    h = case.marker_h
    out = []
    for k, j in enumerate(case.lug_markers):
        # a marker at height fraction h of a linearly shearing lug: between tip and base
        pos = (h * o["bases"][idx, j] + (1 - h) * o["tips"][idx, j]) * 1e3
        noise = rng.normal(0.0, case.noise_lug_mm, pos.shape)
        out.append((f"B{k + 1:02d}", "lug", t, pos[:, 0] - x0 + noise[:, 0],
                    pos[:, 1] + noise[:, 1]))
    th = o["pitch"][idx]
    ox = (o["chassis_x0"] + o["X"][idx]) * 1e3
    oz = (o["chassis_z0"] + o["Z"][idx]) * 1e3
    for k, (bx, bz) in enumerate(case.body_markers):
        x = ox + bx * np.cos(th) + bz * np.sin(th)
        z = oz - bx * np.sin(th) + bz * np.cos(th)
        noise = rng.normal(0.0, case.noise_body_mm, (len(t), 2))
        out.append((f"C{k + 1}", "body", t, x - x0 + noise[:, 0], z + noise[:, 1]))
    return out


def _atomic(path: str, text: str) -> None:
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        f.write(text)
    os.replace(tmp, path)


def write_recording(case: EngineCase, o: dict, truth: dict, out_dir: str, seed: int) -> None:
    """Write the three files of one case into `out_dir` (created), each atomically."""
    os.makedirs(out_dir, exist_ok=True)
    rng = np.random.default_rng(seed)
    tracks = marker_tracks(case, o, rng)
    lines = [f"# fps: {case.fps:g}", "# source: fitlug engine (MuJoCo contact dynamics)",
             "# units: mm", f"# case: {case.name}",
             "time_s,marker,role,x_mm,y_mm,frame"]
    T = len(tracks[0][2])
    lo, hi = case.camera_window_mm or (-float("inf"), float("inf"))
    for f in range(T):
        for name, role, t, x, y in tracks:
            if lo <= x[f] <= hi:  # the camera sees the marker
                lines.append(f"{t[f]:.6g},{name},{role},{x[f]:.4f},{y[f]:.4f},{f}")
    _atomic(os.path.join(out_dir, "trajectories.csv"), "\n".join(lines) + "\n")
    rig = truth["rig"]
    text = ["[track]", f"load_bearing_length_mm = {rig['L_mm']}",
            f"lugs_in_contact = {rig['n']}", f"lug_pitch_mm = {rig['lug_pitch_mm']:.6g}", "",
            "[vehicle]", f"mass_kg = {rig['mass_kg']}"]
    if rig["drawbar_pull_N"]:
        text.append(f"drawbar_pull_N = {rig['drawbar_pull_N']}")
    text += ["", "[markers]", "body = [" + ", ".join(
        f'"C{k + 1}"' for k in range(len(case.body_markers))) + "]",
        "", "[camera]", f"fps = {case.fps:g}"]
    _atomic(os.path.join(out_dir, "rig.toml"), "\n".join(text) + "\n")
    doc = dict(truth, seed=seed, settings=case.settings())
    _atomic(os.path.join(out_dir, "truth.json"), json.dumps(doc, indent=1, default=float) + "\n")

