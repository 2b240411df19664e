"""The generator of physics beyond the catalog (tests/mechanisms.py) against truth it did
not produce: fitlug.sim's own integration, finite differences, the drawn parameters."""

import numpy as np
import pytest

import mechanisms as M
from fitlug.sim import simulate


def test_base_kinematics_agree_with_fitlug_sim():
    """Without a mechanism, the generator's own RK4/Simpson kinematics give fitlug.sim's
    recording (a spline of the same profile, integrated by the model) to < 0.1 µm."""
    sc = M.scenario(5).replace(noise_lug_mm=0.0, noise_body_mm=0.0)
    rec, _ = simulate(sc, 0)
    mine = M._recording(sc, M._clean(sc), 0)
    assert rec.markers == mine.markers and np.array_equal(rec.t, mine.t)
    assert np.max(np.abs(rec.x - mine.x)) < 1e-4
    assert np.max(np.abs(rec.y - mine.y)) < 1e-4


def _slip_from_motion(c, fps):
    """1 - v / v_t from central differences of the clean X and psi."""
    v = np.gradient(c["X"], 1 / fps)
    vt = np.gradient(c["psi"], 1 / fps)
    return v, vt, 1 - v / np.where(vt == 0, 1, vt)


def test_slip_speed_changes_the_belt_travel():
    """slip_speed: in the cruise, 1 - v/v_t from the integrated X and psi is s0 (1 + c v),
    the truth's slip; without it the base s0."""
    sc = M.scenario(2)
    cv = 0.3
    c = M._clean(sc, slip_of=lambda s, v: s * (1 + cv / sc.v_cruise * v))
    v, vt, s = _slip_from_motion(c, sc.fps)
    cruise = np.abs(c["a"]) < 1e-9
    cruise &= v > 0.999 * sc.v_cruise
    cruise[:2] = cruise[-2:] = False
    cruise &= np.roll(cruise, 1) & np.roll(cruise, -1)  # central differences inside it
    assert cruise.sum() > 50
    np.testing.assert_allclose(s[cruise], sc.slip * (1 + cv), rtol=1e-6)
    _, _, truth = M.make("slip_speed", 2, size=cv, faults=False)
    assert truth["slip"] == pytest.approx(sc.slip * (1 + cv))
    assert truth["family"] == "slip law"


def test_cogging_modulates_speed_with_motor_angle():
    """cogging: the body speed (finite differences of X) over the motor profile's speed is
    1 + eps (sin th + h2 sin(2 th + phi2)) at the belt travel psi, and the belt keeps the
    slip law's rate (v_t = v / (1 - s))."""
    from fitlug.sim import speed_profile

    rec, rig, truth = M.make("cogging", 4, size=0.01, faults=False)
    q = truth["params"]
    sc = M.scenario(4)
    c = M._clean(sc, M._cogging_mod(q, sc.R_mm))
    v0, _ = speed_profile(c["t"], v_cruise=sc.v_cruise, duration=sc.duration_s,
                          rest=sc.rest_s, ramp=sc.ramp_s, shape=sc.ramp)
    # speed at the frame times from the RK4 itself: X differences over one frame
    # (second order, errors ~ (2 pi f / fps)^2 / 6 of the modulation)
    v = np.gradient(c["X"], 1 / sc.fps)
    m, _ = M._cogging_mod(q, sc.R_mm)(c["psi"])
    cruise = (v0 > 0.999 * sc.v_cruise)
    cruise[:2] = cruise[-2:] = False
    w = 2 * np.pi * q["f_cruise_Hz"] / sc.fps
    tol = 0.01 * (1 + 2 * q["h2"]) * (w * w / 6 * 4 + 1e-3)
    assert np.max(np.abs(v[cruise] / v0[cruise] - 1 - m[cruise])) < tol
    assert np.std(v[cruise] / v0[cruise]) > 0.005  # the modulation is there
    assert truth["family"] == "speed modulation" and truth["coordinate"] == "psi"
    r = q["periods_per_wheel_turn"]
    assert abs(r - round(r)) > 0.15


def test_marker_mechanisms_move_what_they_say():
    """flap moves top-run lugs only, squat and idler_wobble body y only, bump bottom-run
    lugs and body y; sizes as asked; the clean recordings differ from the null by them."""
    sc = M.scenario(6)
    base = M._recording(sc, M._clean(sc), 6)
    for mech, size in (("flap", 0.2), ("squat", 0.08), ("idler_wobble", 0.1), ("bump", 0.6)):
        rec, rig, truth = M.make(mech, 6, size=size, faults=False)
        assert np.array_equal(rec.t, base.t) and rec.roles == base.roles
        lug = np.array([rec.roles[m] == "lug" for m in rec.marker_index])
        dx, dy = np.abs(rec.x - base.x), rec.y - base.y
        assert dx.max() < 1e-9  # only y moves (the noise is the same draw)
        moved_lug, moved_body = np.abs(dy[lug]).max(), np.abs(dy[~lug]).max()
        if mech == "flap":
            assert moved_body < 1e-9 and 0.9 * size < moved_lug <= size + 1e-9
        elif mech in ("squat", "idler_wobble"):
            assert moved_lug < 1e-9 and moved_body > 1e-3
        else:
            assert size - 1e-9 > moved_lug > 0.9 * size and moved_body > 0.05 * size
        assert truth["family"] == M.FAMILIES[mech][0]


def test_faults_window_and_truth():
    """With faults: ids are renamed, the window sees the bump, and the truth is complete."""
    rec, rig, truth = M.make("bump", 8)
    lo, hi = truth["window"]
    assert lo < truth["params"]["x_mm"] < hi
    assert all(m.startswith("trk") for m in rec.markers)
    assert truth["n_glitches"] >= 1 and rig.fps == truth["fps"]
    for key in ("slip", "stiffness_N_per_mm", "rolling_resistance", "family", "coordinate"):
        assert key in truth
    rec2, _, truth2 = M.make("bump", 8)
    assert np.array_equal(rec.x, rec2.x, equal_nan=True) and truth2 == truth
    with pytest.raises(ValueError, match="unknown mechanism"):
        M.make("warp_drive", 0)


def test_write_reads_back(tmp_path):
    """write(): the wide export and rig.toml read back with fitlug.io as the same recording
    (roles from rig.toml), truth.json beside them."""
    import json

    from fitlug.io import read_rig, read_trajectories

    truth = M.write(tmp_path, "flap", 275, size=0.2)
    rec, _, _ = M.make("flap", 275, size=0.2)
    rig = read_rig(tmp_path / "rig.toml")
    back = read_trajectories(tmp_path / "trajectories.csv", rig=rig)
    assert sorted(back.markers) == sorted(rec.markers)
    assert {m: r for m, r in zip(back.markers, back.roles)} == \
        {m: r for m, r in zip(rec.markers, rec.roles)}
    ok = np.isfinite(rec.x)
    assert np.isfinite(back.x).sum() == ok.sum()
    assert json.loads((tmp_path / "truth.json").read_text())["params"]["A_mm"] == 0.2
    assert truth["family"] == "segment vibration"
