"""Recordings as a real camera and tracker deliver them (markers that come and go, split ids).

Truth comes from tests/independent_sim.py (MODEL.md written independently); the faults
from tests/realism.py. Glitches are off here: their handling is another module's.
"""

from __future__ import annotations

import os
import sys

import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(__file__))

import independent_sim as isim  # noqa: E402
from realism import FOV_MM, realistic, shift_time, write_realistic  # noqa: E402

from fitlug.fit import fit  # noqa: E402
from fitlug.fit._problem import build_problem  # noqa: E402
from fitlug.io import Recording, read_rig, read_trajectories  # noqa: E402
from fitlug.model import place_knots  # noqa: E402
from fitlug.report._fitjson import fit_json  # noqa: E402

TRAVEL = dict(v_max=240.0)  # 0.72 m of travel: the robot crosses the 637 mm picture


def _orig(info, name):
    return info["fragments"][name][0]


def test_transform_cuts_the_picture_and_splits_ids():
    rec, rig, _ = isim.make(3, **TRAVEL)
    out, info = realistic(rec, seed=3, glitches=False, occlusion_rate=0.5)
    lo, hi = info["fov"]
    assert hi - lo == pytest.approx(FOV_MM)
    ok = np.isfinite(out.x)
    assert np.all((out.x[ok] >= lo) & (out.x[ok] <= hi))
    assert rec.x.min() < lo and rec.x.max() > hi  # the picture does cut the recording
    assert len(out.markers) > rec.n_markers  # ids were split
    assert all(m.startswith("trk") for m in out.markers)
    assert set(out.markers).isdisjoint(rec.markers)
    # body markers come and go too
    body = [m for m, r in zip(out.markers, out.roles) if r == "body"]
    assert all(info["fragments"][m][3] - info["fragments"][m][2] < 4.9 for m in body)
    # reproducible
    out2, _ = realistic(rec, seed=3, glitches=False, occlusion_rate=0.5)
    assert out2 == out
    # glitches: 0.1-0.2 % of the valid samples, 0.5-1 mm
    _, info_g = realistic(rec, seed=3, glitches=True)
    sizes = np.hypot([g[2] for g in info_g["glitches"]], [g[3] for g in info_g["glitches"]])
    assert np.all((sizes >= 0.5) & (sizes <= 1.0)) and len(sizes) >= 1


def test_fragments_joined_and_lugs_a_pitch_apart_kept_apart():
    rec, rig, _ = isim.make(5, **TRAVEL)
    out, info = realistic(rec, seed=5, glitches=False, occlusion_rate=0.6)
    prob = build_problem(out, rig)
    joined = prob.init_info["joined"]
    assert joined, "no fragments were joined"
    for j in joined:  # every join is right: one original marker per group
        assert len({_orig(info, m) for m in j["ids"]}) == 1, j
    # no original marker was left in two pieces that could have been joined: fitted
    # markers <= originals + pieces that overlap in time (none here) -> equal count
    originals = {_orig(info, m) for m in out.markers}
    assert len(prob.rec.markers) == len(originals)
    cov = prob.init_info["markers"]
    assert {c["id"] for c in cov} == set(prob.rec.markers)
    assert all(0 < c["coverage"] <= 1 and c["n_samples"] > 0 for c in cov)
    assert sum(len(c["ids"]) for c in cov) == len(out.markers)

    # two different lug markers a whole pitch apart, seen at different times, and one
    # marker split in two: only the split one is joined
    sel = np.ones(rec.n_samples, bool)
    names = list(rec.markers)
    mi = rec.marker_index.copy()
    L0, L1, L2 = (rec.markers.index(n) for n in ("L0", "L1", "L2"))
    sel &= ~((mi == L0) & (rec.t > 2.0)) & ~((mi == L1) & (rec.t < 2.6))
    split = (mi == L2) & (rec.t > 3.0)
    names += ["q7"]
    mi[split] = len(rec.markers)
    sel &= ~((rec.marker_index == L2) & (rec.t > 2.7) & (rec.t <= 3.0))
    roles = list(rec.roles) + ["lug"]
    names = ["zz", "ab", "m3"] + names[3:]  # names carry nothing
    r = Recording(markers=tuple(names), roles=tuple(roles), t=rec.t[sel],
                  marker_index=mi[sel], x=rec.x[sel], y=rec.y[sel], meta=rec.meta)
    prob = build_problem(r, rig)
    assert [sorted(j["ids"]) for j in prob.init_info["joined"]] == [["m3", "q7"]]


def test_knots_ignore_markers_entering_and_leaving():
    """A field of view that cuts the body markers adds no dense knots in the cruise."""
    rec, rig, _ = isim.make(2, **TRAVEL)
    out, _ = realistic(rec, seed=2, glitches=False, occlusion_rate=0.5)
    full = build_problem(rec, rig).init_info["breaks"]
    cut = build_problem(out, rig).init_info["breaks"]
    for br in (full, cut):
        cruise = br[(br > 1.8) & (br < 3.2)]
        assert len(cruise) <= 3, br  # cruise: about a wheel period apart (0.76 s here)
    # an isolated jump of one body sample (a glitch) is not a ramp
    body = [m for m, r in enumerate(rec.roles) if r == "body"]
    tracks = [(rec.t[rec.marker_index == m], rec.x[rec.marker_index == m].copy())
              for m in body]
    k = int(np.searchsorted(tracks[0][0], 2.5))
    tracks[0][1][k] += 0.8
    t, x = tracks[1]
    br = place_knots(t, x, t_lo=0.0, t_hi=5.0, R=30.0, pitch=20.0, tracks=tracks)
    assert len(br[(br > 1.8) & (br < 3.2)]) <= 3, br


def _z(res, truth):
    return (res.slip.value - truth["slip"]) / res.slip.std


@pytest.fixture(scope="module")
def fov_fits():
    out = []
    for seed in (21, 22, 23):
        rec, rig, truth = isim.make(seed, **TRAVEL)
        cut, info = realistic(rec, seed=seed, glitches=False)
        out.append((fit(cut, rig), truth, info))
    return out


def test_fov_cut_recordings_fit_to_the_truth(fov_fits):
    for res, truth, info in fov_fits:
        assert res.converged
        assert abs(_z(res, truth)) < 3, (res.slip.value, res.slip.std, truth["slip"])
        assert 0.8 < res.chi2_per_dof < 1.2
        for j in res.problem.init_info["joined"]:
            assert len({_orig(info, m) for m in j["ids"]}) == 1


def test_fit_json_has_markers_and_joined(fov_fits):
    res, _, info = fov_fits[0]
    out = fit_json(res)
    assert {m["id"] for m in out["markers"]} == set(res.problem.rec.markers)
    ids = [i for m in out["markers"] for i in m["ids"]]
    assert sorted(ids) == sorted(info["fragments"])  # every tracker id accounted for
    for m in out["markers"]:
        assert set(m) == {"id", "role", "ids", "n_samples", "coverage", "t_range_s"}
        assert m["t_range_s"][0] <= m["t_range_s"][1]
    assert all(set(j) == {"marker", "ids", "reason"} for j in out["joined"])
    assert any(m["coverage"] < 0.9 for m in out["markers"])  # the picture cut them


def test_other_rig_250fps_time_offset_wide_export(tmp_path):
    """250 fps, n = 10, L = 160 mm, time stamps from 12.3 s, the wide export form."""
    rec, rig, truth = isim.make(7, fps=250.0, n=10, L=160.0, **TRAVEL)
    rec = shift_time(rec, 12.3)
    cut, _ = realistic(rec, seed=7, glitches=False)
    path = write_realistic(tmp_path, cut, rig, wide=True)
    rig2 = read_rig(tmp_path / "rig.toml")
    back = read_trajectories(path, rig=rig2)
    res = fit(back, rig2)
    assert res.converged
    assert abs(_z(res, truth)) < 3, (res.slip.value, res.slip.std, truth["slip"])


def test_one_sample_fragment_is_left_out():
    rec, rig, _ = isim.make(4, **TRAVEL)
    out, _ = realistic(rec, seed=4, glitches=False)
    body = [m for m, r in enumerate(out.roles) if r == "body"]
    keep = np.ones(out.n_samples, bool)
    rows = np.flatnonzero((out.marker_index == body[0]) & np.isfinite(out.x))
    keep[rows[1:]] = False  # a body fragment seen once
    one = out.with_(t=out.t[keep], marker_index=out.marker_index[keep], x=out.x[keep],
                    y=out.y[keep])
    prob = build_problem(one, rig)
    assert out.markers[body[0]] not in [prob.rec.markers[m] for m in prob.body_ids]
