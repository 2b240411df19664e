"""Tracking rendered clips with known truth: identities, gaps, the mm frame, the noise."""

import numpy as np
import pytest

from fitlug.cli import main
from fitlug.io import read_trajectories
from fitlug.sim import RenderOptions, default_camera, render_frames, render_video
from fitlug.sim._scene import stadium_scene
from fitlug.vision import TrackerConfig, measure_noise, scale_calibration, to_recording, track

S = 0.39
W, H = 400, 300
CAM = default_camera(S, (W, H), dist_coeffs=None)
OPT = RenderOptions(noise_sigma=2.0, gradient=(0.3, 0.15), vignetting=0.1)


def _mm(px):
    """Pixel positions (..., 2) to the mm of CAM with origin (0, 0)."""
    px = np.asarray(px, dtype=np.float64)
    return np.stack([S * px[..., 0], S * (H - px[..., 1])], axis=-1)


def _clip(px, roles, opt=OPT, seed=0):
    """Render marker tracks given in pixels (F, M, 2); returns frames, truth and visibility."""
    t = np.arange(px.shape[0]) / 100.0
    names = [f"M{i}" for i in range(px.shape[1])]
    frames = list(render_frames(t, names, roles, _mm(px), camera=CAM, origin_mm=(0, 0),
                                options=opt, seed=seed))
    images = np.stack([f.image for f in frames])
    truth = np.stack([f.truth_px for f in frames])
    visible = np.stack([f.visible for f in frames])
    return images, truth, visible


def _match(result, truth, tol=0.05):
    """For each track, the truth marker it follows; asserts every sample it has lies within
    `tol` px of that one marker (no wrong position, no identity swap)."""
    owner = []
    for k in range(len(result.markers)):
        xy = result.xy_px[:, k]
        ok = np.isfinite(xy[:, 0])
        d = np.hypot(*(xy[ok, None, :] - truth[ok]).transpose(2, 0, 1))  # (n, M)
        typical = np.array([np.median(c[np.isfinite(c)]) if np.isfinite(c).any() else np.inf
                            for c in d.T])
        j = int(np.argmin(typical))
        worst = np.nanmax(d[:, j])
        assert worst < tol, f"track {result.markers[k]} strays {worst:.3f} px from its marker"
        owner.append(j)
    return owner


def test_identities_survive_a_crossing():
    f = 40
    t = np.arange(f)
    px = np.zeros((f, 4, 2))
    px[:, 0] = np.stack([40 + 9.0 * t, np.full(f, 140.0)], axis=1)  # rightwards
    px[:, 1] = np.stack([395 - 9.0 * t, np.full(f, 148.0)], axis=1)  # leftwards, 8 px lower
    px[:, 2] = [200.0, 60.0]  # a checker on the body
    px[:, 3] = [80.0, 250.0]  # a still disc
    images, truth, visible = _clip(px, ["lug", "lug", "body", "lug"])
    res = track(images, fps=100)
    owner = _match(res, truth)
    assert sorted(owner) == [0, 1, 2, 3]  # one track per marker: the ids held through
    a, b = owner.index(0), owner.index(1)
    # around frame 20 the second lug (drawn later: in front) hides part of the first one's
    # disc (radius 7.7 px): a gap for the first, the second may stay (if right: `_match`);
    # positions on both sides
    hidden = np.hypot(*(px[:, 0] - px[:, 1]).T) < 2 * 7.7 + 15.4 - 8
    assert hidden.sum() >= 2
    assert np.isnan(res.xy_px[hidden, a, 0]).all()
    for k in (a, b):
        found = np.isfinite(res.xy_px[:, k, 0])
        assert found[3:12].all() and found[-12:-2].all()  # (not while at the edges)
    assert res.roles[owner.index(2)] == "body" and res.kinds[owner.index(2)] == "qs"
    assert res.roles[owner.index(3)] == "lug" and res.kinds[owner.index(3)] == "cog"


def test_occlusion_leaves_a_gap_and_keeps_the_id():
    f = 45
    t = np.arange(f)
    px = np.zeros((f, 2, 2))
    px[:, 0] = np.stack([30 + 8.0 * t, np.full(f, 150.0)], axis=1)
    px[:, 1] = [300.0, 60.0]
    opt = OPT.replace(occluders=((185, 100, 215, 200),), exposure_s=0.0)
    images, truth, visible = _clip(px, ["lug", "lug"], opt=opt, seed=1)
    res = track(images, fps=100)
    owner = _match(res, truth)  # no sample of a half-hidden disc is off by 0.05 px
    assert owner.count(0) == 1, "the marker got a new id after the occlusion"
    k = owner.index(0)
    found = np.isfinite(res.xy_px[:, k, 0])
    # every frame where the occluder hides more than a sliver (1 px) of the bright disc
    # (radius 7.7 px) is a gap
    touching = (truth[:, 0, 0] + 7.7 > 186) & (truth[:, 0, 0] - 7.7 < 214)
    assert touching.sum() >= 5
    assert not found[touching].any()
    assert found[visible[:, 0]].mean() >= 0.98  # and nearly every frame it is clear of it


def test_markers_leaving_and_entering_get_their_own_ids():
    f = 50
    t = np.arange(f)
    px = np.full((f, 4, 2), np.nan)
    px[:, 0] = np.stack([250 + 10.0 * t, np.full(f, 150.0)], axis=1)  # leaves on the right
    px[20:, 1] = np.stack([-20 + 10.0 * t[:30], np.full(30, 150.0)], axis=1)  # enters on the left
    px[:, 2] = [100.0, 60.0]
    px[:, 3] = np.stack([np.full(f, 330.0), 330 - 6.0 * t], axis=1)  # a checker from below
    images, truth, visible = _clip(px, ["lug", "lug", "body", "body"], seed=2)
    res = track(images, fps=100)  # markers coming into view are found at the frame's edges
    owner = _match(res, truth)
    assert sorted(owner) == [0, 1, 2, 3]  # the newcomer is not given the old marker's id
    k0 = owner.index(0)
    assert np.isfinite(res.xy_px[:9, k0, 0]).all()
    assert np.isnan(res.xy_px[16:, k0, 0]).all()  # out of view: gaps, never a position
    for j in (1, 3):
        first = np.flatnonzero(np.isfinite(res.xy_px[:, owner.index(j), 0]))[0]
        assert first <= np.flatnonzero(visible[:, j])[0] + 3  # picked up soon after it enters


def test_a_small_marker_appearing_mid_picture_is_picked_up_by_the_periodic_search():
    # small markers (8 px discs, 10 px checkers, noise 4): the whole-frame search for new
    # markers runs on a half-size frame once their sizes are known; a disc that appears in
    # the middle of the picture (neither at an edge nor where a track was lost) is found
    # by it and followed from then on (the scan for bright spots, which would find it at
    # once, is off here)
    f = 36
    t = np.arange(f)
    px = np.full((f, 4, 2), np.nan)
    px[:, 0] = np.stack([60 + 2.0 * t, np.full(f, 80.0)], axis=1)
    px[:, 1] = [300.0, 230.0]
    px[:, 2] = [120.0, 200.0]  # a checker
    px[14:, 3] = np.stack([200 + 1.5 * t[:f - 14], np.full(f - 14, 150.0)], axis=1)
    opt = OPT.replace(noise_sigma=4.0, cog_diameter_mm=8 * S, lug_diameter_mm=16 * S,
                      qs_size_mm=10 * S)
    images, truth, visible = _clip(px, ["lug", "lug", "body", "lug"], opt=opt, seed=3)
    cfg = TrackerConfig(redetect_every=10, edge_every=0, watch_frames=0, scan_every=0)
    res = track(images, fps=100, config=cfg)
    owner = _match(res, truth, tol=0.1)
    assert sorted(owner) == [0, 1, 2, 3]
    late = np.isfinite(res.xy_px[:, owner.index(3), 0])
    assert not late[:20].any() and late[20:].all()  # found at the search of frame 20
    for j in (0, 1, 2):
        assert np.isfinite(res.xy_px[:, owner.index(j), 0]).all()


def test_tracks_reach_the_accuracy_of_single_frames():
    tt, names, roles, xy = stadium_scene(60, speed_mm_s=120.0, n_lug_markers=6)
    cam = default_camera(S, (640, 360), dist_coeffs=None)
    frames = list(render_frames(tt, names, roles, xy, camera=cam, options=OPT, seed=3))
    images = np.stack([f.image for f in frames])
    truth = np.stack([f.truth_px for f in frames])
    res = track(images, fps=100)
    owner = _match(res, truth, tol=0.04)
    assert sorted(owner) == list(range(len(names)))
    for k, j in enumerate(owner):
        err = res.xy_px[:, k] - truth[:, j]
        ok = np.isfinite(err[:, 0])
        assert ok.mean() > 0.95
        rms = np.sqrt(np.mean(err[ok] ** 2, axis=0))
        assert rms.max() < 0.01, f"{res.kinds[k]} marker: rms {rms} px"
        assert 0.0 < res.quality[ok, k].min() and res.quality[ok, k].max() <= 1.0


def test_roles_can_be_swapped():
    px = np.zeros((8, 2, 2))
    px[:, 0] = [100.0, 100.0]
    px[:, 1] = [250.0, 180.0]
    images, truth, _ = _clip(px, ["lug", "body"], seed=4)
    res = track(images, fps=100, config=TrackerConfig(roles={"cog": "body", "qs": "lug"}))
    owner = _match(res, truth)
    assert res.roles[owner.index(0)] == "body" and res.roles[owner.index(1)] == "lug"
    assert res.markers[owner.index(0)] == "C1" and res.markers[owner.index(1)] == "B01"


def test_noise_of_a_still_rig_is_recovered():
    rng = np.random.default_rng(5)
    f, jitter = 80, 0.05  # px: the markers shake, the camera is quiet
    base = np.array([[80.0, 80.0], [200.0, 80.0], [320.0, 80.0], [120.0, 220.0], [280.0, 220.0]])
    px = base[None] + rng.normal(0.0, jitter, (f, 5, 2))
    opt = OPT.replace(noise_sigma=0.5, exposure_s=0.0)
    images, truth, _ = _clip(px, ["lug", "lug", "lug", "body", "body"], opt=opt, seed=6)
    noise = measure_noise(images, frames=None, calibration=scale_calibration(S, (W, H)))
    for role, n_markers in (("lug", 3), ("body", 2)):
        row = noise.per_role[role]
        assert len(row["markers"]) == n_markers and row["n"] == f * n_markers
        # the sample std of the jitter the markers really had (the truth), and its spread
        j = [i for i in range(5) if (i < 3) == (role == "lug")]
        d = truth[:, j] - truth[:, j].mean(axis=0)
        expected = np.sqrt(np.sum(d ** 2) / (2 * n_markers * (f - 1)))
        sd = expected / np.sqrt(2 * 2 * n_markers * (f - 1))
        assert abs(row["std_px"] - expected) < 3 * sd + 0.002  # + the tracker's own noise
        assert row["std_mm"] == pytest.approx(S * row["std_px"], rel=1e-9)
        assert expected == pytest.approx(jitter, rel=0.15)


def test_track_command_writes_the_input_mm_frame(tmp_path):
    tt, names, roles, xy = stadium_scene(25, speed_mm_s=150.0, n_lug_markers=6)
    clip = tmp_path / "clip"
    render_video(clip, tt, names, roles, xy, image_size=(640, 480), options=OPT, seed=7,
                 progress=False)
    out = tmp_path / "trajectories.csv"
    code = main(["track", str(clip), "--fps", "100", "--calib", str(clip / "calib.json"),
                 "-o", str(out), "--overlay", str(tmp_path / "overlay.png"), "-q"])
    assert code == 0 and (tmp_path / "overlay.png").stat().st_size > 0
    rec = read_trajectories(out)
    assert sorted(rec.roles) == sorted(roles)
    assert rec.meta["fps"] == "100"
    assert {"frame", "x_px", "y_px", "quality"} <= {k for k in ("frame", "x_px", "y_px", "quality")
                                                     if getattr(rec, k) is not None}
    t_index = np.rint(rec.t * 100).astype(int)
    for k, marker in enumerate(rec.markers):
        sel = rec.marker_index == k
        pts = np.stack([rec.x[sel], rec.y[sel]], axis=1)
        d = np.hypot(*(pts[:, None, :] - xy[t_index[sel]]).transpose(2, 0, 1))
        j = int(np.argmin(np.nanmedian(d, axis=0)))
        assert roles[j] == rec.roles[k]
        assert np.isfinite(pts[:, 0]).mean() > 0.95
        assert np.sqrt(np.nanmean(d[:, j] ** 2)) < 0.005  # mm: undistorted, scaled, y up


def test_noise_command_prints_both_types(tmp_path, capsys):
    rng = np.random.default_rng(9)
    px = np.array([[100.0, 100.0], [250.0, 180.0]])[None] + rng.normal(0, 0.03, (12, 2, 2))
    t = np.arange(12) / 100.0
    render_video(tmp_path, t, ["B01", "C1"], ["lug", "body"], _mm(px), camera=CAM,
                 origin_mm=(0, 0), options=OPT.replace(exposure_s=0.0), progress=False)
    out = tmp_path / "noise.json"
    assert main(["noise", str(tmp_path), "--mm-per-px", str(S), "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "body" in text and "lug" in text and "σ mm" in text
    import json
    got = json.loads(out.read_text())
    assert got["frames"] == 12 and set(got["per_role"]) == {"body", "lug"}
    assert 0.01 < got["per_role"]["lug"]["std_px"] < 0.06


def test_track_command_needs_a_scale(tmp_path, capsys):
    px = np.zeros((3, 1, 2)) + [100.0, 100.0]
    t = np.arange(3) / 100.0
    render_video(tmp_path, t, ["B01"], ["lug"], _mm(px), camera=CAM, origin_mm=(0, 0),
                 progress=False)
    code = main(["track", str(tmp_path), "--fps", "100", "-o", str(tmp_path / "t.csv")])
    assert code == 2
    assert "--mm-per-px" in capsys.readouterr().err
    assert not (tmp_path / "t.csv").exists()


def test_to_recording_maps_pixels_to_ground_mm():
    px = np.zeros((6, 2, 2)) + [[100.0, 100.0], [250.0, 180.0]]
    images, truth, _ = _clip(px, ["lug", "body"], seed=8)
    res = track(images, fps=50)
    rec = to_recording(res, scale_calibration(S, (W, H)), origin_mm=(10.0, -5.0))
    assert rec.fps == pytest.approx(50.0)
    for k in range(rec.n_markers):
        sel = rec.marker_index == k
        np.testing.assert_allclose(rec.x[sel], S * rec.x_px[sel] + 10.0)
        np.testing.assert_allclose(rec.y[sel], S * (H - rec.y_px[sel]) - 5.0)
