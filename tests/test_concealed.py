"""Blind explanation of the concealed recordings (data/concealed, made by make.py there).

Each folder's trajectories.csv and rig.toml carry no hint of what is hidden; the truth
beside them is read only after the explanation has been made. The recordings: one per
catalog effect, two combinations of two effects, two clean ones, and two disturbances
outside the catalog (a 3.3 Hz vibration of the image; one lug marker shifting on its lug).
"""

from __future__ import annotations

import json
import math
import os

import pytest

from fitlug.explain import explain
from fitlug.fit import fit
from fitlug.io import find_rig, read_trajectories

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.join(HERE, "..", "data", "concealed")
FOLDERS = sorted(d for d in os.listdir(ROOT) if d.startswith("rec"))

# the reported parameter that measures each effect's size, and its true value
_SIZE = {
    "lug_ripple": ("epsilon", lambda p: math.hypot(p["ripple_a"], p["ripple_b"])),
    "wheel_runout": ("epsilon", lambda p: math.hypot(p["runout_a"], p["runout_b"])),
    "body_bounce": ("A_mm", lambda p: p["bounce_A"]),
    "lug_sliding": ("inv_s_K", lambda p: p["slide_mu"]),
    "belt_sag": ("d_mm", lambda p: p["sag_d"]),
    "ground_sinkage": ("z_max_mm", lambda p: p["sink_z"]),
    "lens_distortion": ("k1_per_mm2", lambda p: p["lens_k1"]),
    "marker_depth": ("epsilon", lambda p: p["depth_eps"]),
    "camera_tilt": ("theta_rad", lambda p: p["tilt_theta"]),
    "frame_drop": ("dt_s", lambda p: p["drop_dt"]),
}


def test_the_set_is_complete():
    cases = []
    for f in FOLDERS:
        with open(os.path.join(ROOT, f, "truth.json")) as fh:
            cases.append(json.load(fh)["concealed"])
    singles = {c["effects"][0] for c in cases if len(c["effects"]) == 1 and not c["disturbance"]}
    assert singles == set(_SIZE)
    assert sum(len(c["effects"]) == 2 for c in cases) == 2
    assert sum(c["verdict"] == "none" for c in cases) == 2
    assert sum(c["disturbance"] is not None for c in cases) >= 2


#: recordings whose exact case tests/test_explain_independent.py checks on an independent
#: implementation's recording (a stronger check): left out of the blind run to keep .ci/run
#: under its 20 minutes (issue 28's family tests took their time; the marker shift, the
#: 3.3 Hz vibration and marker_depth since the three new families' tests). Issue 43 (CI
#: <= 12 min): belt_sag, frame_drop and sinkage+frame_drop too, two thirds of this file's
#: time (389 s CPU in all on 2 cores); test_explain_independent names belt_sag and
#: frame_drop alone and a combination of two effects (ripple+sag), and ground_sinkage
#: stays here alone (rec04); the three still run blind in benchmarks/bench_explain.py
#: --part concealed
CHECKED_INDEPENDENTLY = {"ripple+sag", "wheel_runout", "lens_distortion", "camera_tilt",
                         "marker_shift", "vibration", "marker_depth",
                         "belt_sag", "frame_drop", "sinkage+frame_drop"}


def _case(folder):
    with open(os.path.join(ROOT, folder, "truth.json")) as fh:
        return json.load(fh)["concealed"]["case"]


#: issue 43 item 6 (the suite over its 12 minutes): repetitions in the default run, marked
#: `bench` (deselected; `pytest -m bench tests/test_concealed.py` runs them): clean_a is the
#: second clean recording (clean_b, rec01, stays); body_bounce and ground_sinkage are named
#: with their sizes (A_mm, z_max_mm, the same reported parameters) by
#: test_explain_independent.py's test_independent_effects_are_named[body_bounce] and
#: [ground_sinkage] on the independent generator. 2026-11-28: ~25 s CPU each. Third pass
#: (2026-11-28 evening): lug_ripple (rec03, 15 s CPU) too: named alone with its epsilon
#: (the same reported parameter, within 10 % and 4 of its errors) by
#: test_independent_effects_are_named[lug_ripple], and in the explained verdict of
#: test_uncertainty.py's ripple recording. lug_sliding (its friction form, inv_s_K) and
#: clean_b stay here.
REPEATED = {"clean_a", "body_bounce", "ground_sinkage", "lug_ripple"}


@pytest.mark.parametrize("folder", [
    pytest.param(f, marks=pytest.mark.bench) if _case(f) in REPEATED else f
    for f in FOLDERS if _case(f) not in CHECKED_INDEPENDENTLY])
def test_blind_explanation(folder):
    csv = os.path.join(ROOT, folder, "trajectories.csv")
    rig = find_rig(csv)
    ex = explain(fit(read_trajectories(csv, rig=rig), rig))
    with open(os.path.join(ROOT, folder, "truth.json")) as fh:
        truth = json.load(fh)
    want = truth["concealed"]
    assert (ex.verdict, sorted(ex.effects)) == (want["verdict"], want["effects"]), want["case"]
    slip = ex.final.slip
    assert abs(slip.value - truth["slip"]) <= 3 * slip.std, (slip, truth["slip"])
    doc = ex.to_json()
    assert doc["verdict"] == want["verdict"]
    assert [e["id"] for e in doc["effects"]] == ex.effects
    if want["verdict"] != "unexplained":
        assert ex.final.chi2_per_dof <= 1.5
    for e in doc["effects"]:
        key, size = _SIZE[e["id"]]
        true = size(truth["effects"][e["id"]])
        assert e["params"][key] == pytest.approx(true, rel=0.1), e
        assert e["delta_bic"] < -10
    dist = want["disturbance"]
    if dist and dist["kind"] == "marker_shift":
        top = doc["located"][0]
        assert top["markers"] == [dist["marker"]]
        assert doc["misfit_before"]["breakdown"]["marker"][dist["marker"]]["share"] > 0.8
    if dist and dist["kind"] == "periodic_x":
        top = doc["located"][0]
        assert top["axis"] == "x"
        assert top["frequency_hz"] == pytest.approx(dist["frequency_hz"], abs=0.2)
