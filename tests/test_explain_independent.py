"""Blind explanation of recordings made by the independent generator (tests/independent_sim.py).

That generator implements MODEL.md §2 and §3 from the text alone (numpy, RK4 at 0.1 ms,
smoothstep ramps, its own geometry), not with fitlug's model or simulator, so these
tests check the explanation against the contract rather than against itself: each catalog
effect is named with its size, a clean recording gives 'none', a combination gives both
effects, and two disturbances outside the catalog give 'unexplained' with their place.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import independent_sim as ind
from fitlug.explain import explain
from fitlug.fit import fit

SEED = 11
FPS = 120.0
#: the catalog cases' frame rate (issue 43 item 6, the CI's time): half of FPS, 3 000
#: samples instead of 6 000, every assertion unchanged (the sizes are a few to a few
#: hundred noise sigmas); 2026-11-28 this file 450 -> ~290 s CPU. lug_sliding stays at FPS:
#: at 60 fps its sliding is not named (the verdict is wrong), so it needs the frames
FPS_CATALOG = 60.0
FPS_OF = {"lug_sliding": FPS}

# case -> independent effects; sizes are a few to a few hundred noise sigmas
CASES = {
    "clean": {},
    "lug_ripple": {"lug_ripple": {"ripple_eps": 0.003, "ripple_phi": 1.0}},
    "wheel_runout": {"wheel_runout": {"runout_eps": 0.006, "runout_phi": -0.7}},
    "body_bounce": {"body_bounce": {"bounce_A": 0.03, "bounce_B": 1e-4, "bounce_phi": 0.4}},
    "lug_sliding": {"lug_sliding": {"s_K": 0.2}},
    "belt_sag": {"belt_sag": {"sag_d": 0.5}},
    "ground_sinkage": {"ground_sinkage": {"sink_z": 0.3, "sink_us": 30.0}},
    "lens_distortion": {"lens_distortion": {"lens_k1": 2e-8, "lens_cx": 300.0,
                                            "lens_cy": 40.0}},
    "marker_depth": {"marker_depth": {"depth_eps": 0.005, "depth_cx": 100.0,
                                      "depth_cy": 30.0}},
    "camera_tilt": {"camera_tilt": {"tilt_theta": 1e-3}},
    "frame_drop": {"frame_drop": {"drop_dt": 1.0 / FPS_CATALOG, "drop_tstar": 2.5}},
    "ripple+sag": {"lug_ripple": {"ripple_eps": 0.0025, "ripple_phi": -2.0},
                   "belt_sag": {"sag_d": 0.4}},
}

# reported parameter (fit.json) -> the independent generator's value
SIZE = {
    "lug_ripple": ("epsilon", lambda p: p["ripple_eps"]),
    "wheel_runout": ("epsilon", lambda p: p["runout_eps"]),
    "body_bounce": ("A_mm", lambda p: p["bounce_A"]),
    "lug_sliding": ("s_K", lambda p: p["s_K"]),
    "belt_sag": ("d_mm", lambda p: p["sag_d"]),
    "ground_sinkage": ("z_max_mm", lambda p: p["sink_z"]),
    "lens_distortion": ("k1_per_mm2", lambda p: p["lens_k1"]),
    "marker_depth": ("epsilon", lambda p: p["depth_eps"]),
    "camera_tilt": ("theta_rad", lambda p: p["tilt_theta"]),
    "frame_drop": ("dt_s", lambda p: p["drop_dt"]),
}


def _explained(rec, rig):
    return explain(fit(rec, rig))


@pytest.mark.parametrize("case", list(CASES))
def test_independent_effects_are_named(case):
    effects = CASES[case]
    rec, rig, truth = ind.make(seed=SEED, fps=FPS_OF.get(case, FPS_CATALOG), effects=effects)
    ex = _explained(rec, rig)
    want = "explained" if effects else "none"
    assert (ex.verdict, sorted(ex.effects)) == (want, sorted(effects))
    assert ex.final.chi2_per_dof <= 1.5
    slip = ex.final.slip
    assert abs(slip.value - truth["slip"]) <= 3 * slip.std, (slip, truth["slip"])
    doc = ex.to_json()
    for e in doc["effects"]:
        key, size = SIZE[e["id"]]
        true = size(effects[e["id"]])
        got, std = e["params"][key], e["params_std"][key]
        assert got == pytest.approx(true, rel=0.1), e
        assert std is not None and 0 < std < 0.1 * abs(true), e
        assert abs(got - true) <= 4 * std + 1e-3 * abs(true), (e, true)
        assert e["delta_bic"] < -10


# The two disturbances outside the catalog: explained in full, the heaviest cases of this
# file (2026-11-28: 71 and 49 s of its 450 s CPU), marked `bench` (issue 43 item 6; the
# default run deselects them, `pytest -m bench tests/test_explain_independent.py` runs
# them). The same disturbances on fitlug's simulator are explained in full by
# test_uncertainty.py, which checks what these check and more: the vibration (3.3 Hz in x)
# located on x at its frequency and taken out as image motion
# (test_a_camera_vibration_is_taken_out_and_the_errors_stay_sharp), the marker shifted by
# (0.3, 0.2) mm located on its marker, not systematics, its shift and instant measured
# (test_unexplained_headline_interval_holds_the_truth). What only the shift's case here
# has, the glitch finder beside a jump that stays, is a fit and stays in the default run
# (test_glitches_beside_a_marker_shift_are_listed_and_the_shift_is_not).


@pytest.mark.bench
def test_a_vibration_outside_the_catalog_is_unexplained_and_located():
    """A 3.3 Hz x vibration of the image, locked to nothing on the belt."""
    rec, rig, truth = ind.make(seed=SEED, fps=FPS)
    rec = rec.with_(x=rec.x + 0.015 * np.sin(2 * math.pi * 3.3 * rec.t + 0.4))
    ex = _explained(rec, rig)
    assert ex.verdict == "unexplained"
    assert ex.effects == []
    top = ex.to_json()["located"][0]
    assert top["axis"] == "x"
    assert top["frequency_hz"] == pytest.approx(3.3, abs=0.15)


def _shifted_and_glitched():
    """The point tracked on one lug marker jumps by a fixed (0.3, 0.2) mm at t = 2.8 s and
    stays there (a sticker coming loose, a reflection), with glitches of other samples
    (0.5-2 mm, some two frames long)."""
    from test_glitches import inject

    rec, rig, truth = ind.make(seed=SEED, fps=FPS)
    lug = [m for m in rec.markers if rec.role_of(m) == "lug"]
    name = lug[len(lug) // 2]
    k = list(rec.markers).index(name)
    sel = (rec.marker_index == k) & (rec.t >= 2.8)
    x, y = rec.x.copy(), rec.y.copy()
    x[sel] += 0.3
    y[sel] += 0.2
    bad, glitched = inject(rec.with_(x=x, y=y), 8, 1, pairs=2)
    return bad, rig, name, glitched


def test_glitches_beside_a_marker_shift_are_listed_and_the_shift_is_not():
    """The glitches are found and listed; the jump that stays is not one of them."""
    from test_glitches import listed

    bad, rig, name, glitched = _shifted_and_glitched()
    assert listed(fit(bad, rig)) == glitched


@pytest.mark.bench
def test_a_marker_shifting_on_its_lug_is_unexplained_and_located():
    """Nothing in the catalog shifts one marker on its lug: the explanation says
    'unexplained' and the jump stays located on its marker."""
    from test_glitches import listed

    bad, rig, name, glitched = _shifted_and_glitched()
    res = fit(bad, rig)
    assert listed(res) == glitched
    ex = explain(res)
    assert ex.verdict == "unexplained"
    assert ex.effects == []
    doc = ex.to_json()
    assert doc["located"][0]["markers"] == [name]
    assert "systematics" not in doc  # 0.3 mm is far above a tracker's floor
