"""Rendering of simulated camera frames: exact geometry, the camera mapping, the files."""

import csv
import json
import math

import numpy as np
import pytest

from fitlug.sim import RenderOptions, default_camera, render_frames, render_video
from fitlug.sim._coverage import disc_coverage, interval_overlap
from fitlug.sim._render import render_frame
from fitlug.vision import load_calibration

QUIET = RenderOptions(noise_sigma=0.0, gradient=(0.0, 0.0), vignetting=0.0, exposure_s=0.0)


def _supersampled_disc(cx, cy, r, w, h, n=64):
    s = (np.arange(n) + 0.5) / n - 0.5
    ys, xs = np.mgrid[0:h, 0:w]
    sx = xs[:, :, None, None] + s[None, None, None, :]
    sy = ys[:, :, None, None] + s[None, None, :, None]
    return ((sx - cx) ** 2 + (sy - cy) ** 2 < r * r).mean(axis=(2, 3))


@pytest.mark.parametrize("cx, cy, r", [(10.3, 9.71, 5.5), (10.0, 10.0, 0.3), (10.5, 10.5, 7.9),
                                       (2.2, 4.1, 6.0)])
def test_disc_coverage_is_the_area(cx, cy, r):
    cov = disc_coverage(cx, cy, r, 0, 0, 21, 21)
    # a disc wholly inside the block covers exactly pi r^2 (clipped ones less)
    if cx - r > -0.5 and cy - r > -0.5:
        assert cov.sum() == pytest.approx(math.pi * r * r, rel=1e-12)
    # and pixel by pixel agrees with brute-force sampling (64x64 samples per pixel, whose
    # own error is below one sample row: 1/64)
    assert np.abs(cov - _supersampled_disc(cx, cy, r, 21, 21)).max() < 1 / 64



def test_markers_of_their_own_size_and_contrast():
    # marker_scale / marker_contrast (issue 45): a disc drawn at 0.6 of the size and half
    # the contrast holds 0.36 x 0.5 of the full disc's flux, the next marker is unchanged
    cam = default_camera(0.39, (200, 120), dist_coeffs=None)
    opt = QUIET.replace(lug_level=QUIET.background, cog_level=QUIET.background + 100.0,
                        marker_scale=(0.6,), marker_contrast=(0.5,))
    sub = np.array([[[61.37, 58.82], [140.6, 61.1]]])
    img = render_frame(sub, ["cog", "cog"], cam, opt, np.random.default_rng(0), dtype=np.uint16)
    r = 0.5 * opt.cog_diameter_mm / 0.39
    flux = (img.astype(float) - opt.background)
    assert flux[:, :100].sum() == pytest.approx(50.0 * math.pi * (0.6 * r) ** 2, abs=0.5 * 110)
    assert flux[:, 100:].sum() == pytest.approx(100.0 * math.pi * r * r, abs=0.5 * 110)


def test_interval_overlap_lengths():
    ov = interval_overlap([2.25], [4.0], 0, 7)[0]  # pixel k spans [k - 1/2, k + 1/2]
    np.testing.assert_allclose(ov, [0, 0, 0.25, 1, 0.5, 0, 0])


def test_quiet_frame_holds_the_exact_marker_areas():
    cam = default_camera(0.39, (200, 120), dist_coeffs=None)
    opt = QUIET.replace(lug_level=QUIET.background, cog_level=QUIET.background + 100.0)
    sub = np.array([[[61.37, 58.82], [140.6, 61.1]]])
    img = render_frame(sub, ["cog", "qs"], cam, opt, np.random.default_rng(0), dtype=np.uint16)
    # the COG disc on a background-coloured lug: 100 grey levels over pi r^2 (to rounding)
    r = 0.5 * opt.cog_diameter_mm / 0.39
    left = img[:, :100].astype(float) - opt.background
    assert left.sum() == pytest.approx(100.0 * math.pi * r * r, abs=0.5 * left.size ** 0.5)
    # the checker: half its area light, half dark, nothing outside its square
    side = opt.qs_size_mm / 0.39
    right = img[:, 100:].astype(float) - opt.background
    expected = side * side / 2 * (opt.qs_light + opt.qs_dark - 2 * opt.background)
    assert right.sum() == pytest.approx(expected, abs=0.5 * right.size ** 0.5)
    rows, cols = np.nonzero(right)
    assert cols.min() >= np.floor(40.6 - side / 2) and cols.max() <= np.ceil(40.6 + side / 2)
    assert rows.min() >= np.floor(61.1 - side / 2) and rows.max() <= np.ceil(61.1 + side / 2)


def test_truth_follows_the_camera_mapping(tmp_path):
    t = np.arange(4) / 100.0
    xy = np.array([[[100.0 + 40 * ti, 60.0], [180.0, 90.0 - 20 * ti], [12.0, 180.0]] for ti in t])
    info = render_video(tmp_path, t, ["B01", "C1", "B02"], ["lug", "body", "lug"], xy,
                        mm_per_px=0.39, image_size=(640, 480), origin_mm=(0.0, 0.0),
                        options=QUIET, progress=False)
    assert info["origin_mm"] == (0.0, 0.0)
    cal = load_calibration(tmp_path / "calib.json")
    rows = list(csv.DictReader(line for line in open(tmp_path / "truth_px.csv")
                               if not line.startswith("#")))
    assert len(rows) == 12
    px = np.array([[float(r["x_px"]), float(r["y_px"])] for r in rows]).reshape(4, 3, 2)
    np.testing.assert_allclose(cal.mm_to_pixels(xy), px, atol=1e-9)
    np.testing.assert_allclose(cal.pixels_to_mm(px), xy, atol=1e-6)
    # y up in mm is y down in the image; the lens bends the image corner (not a pure scale)
    assert px[0, 1, 1] < px[0, 0, 1]
    # barrel distortion (k1 = -0.02, f = 2000 px) pulls the point towards the centre by
    # |k1| r³ / f² (r its distance from the centre), to first order
    centre = np.array([319.5, 239.5])
    plain = xy[0, 2] / 0.39 * [1, -1] + [0, 480] - centre
    r = np.hypot(*plain)
    pull = plain - (px[0, 2] - centre)
    assert np.dot(pull, plain) / (np.hypot(*pull) * r) > 0.999
    assert np.hypot(*pull) == pytest.approx(0.02 * r ** 3 / 2000.0 ** 2, rel=0.02)
    assert sorted(p.name for p in tmp_path.glob("frame_*.png")) == \
        [f"frame_{i:05d}.png" for i in range(4)]


def test_origin_centres_the_markers_and_is_stored(tmp_path):
    t = np.arange(2) / 100.0
    xy = np.array([[[1000.0, 500.0], [1100.0, 560.0]]] * 2)
    info = render_video(tmp_path, t, ["B01", "C1"], ["lug", "body"], xy, mm_per_px=0.39,
                        image_size=(640, 480), options=QUIET, progress=False)
    origin = np.asarray(info["origin_mm"])
    assert json.loads((tmp_path / "calib.json").read_text())["scale"]["origin_mm"] == list(origin)
    px = load_calibration(tmp_path / "calib.json").mm_to_pixels(xy[0] - origin)
    assert np.abs(px.mean(axis=0) - [320, 240]).max() < 4  # centred to the whole mm


def test_frames_are_8_bit_with_the_requested_noise():
    cam = default_camera(0.39, (160, 120), dist_coeffs=None)
    opt = RenderOptions(noise_sigma=3.0, gradient=(0.0, 0.0), vignetting=0.0)
    t = np.arange(3) / 100.0
    xy = np.full((3, 1, 2), np.nan)  # no marker in view: a flat, noisy background
    frames = list(render_frames(t, ["B01"], ["lug"], xy, camera=cam, origin_mm=(0, 0),
                                options=opt, seed=5))
    img = np.stack([f.image for f in frames]).astype(float)
    assert frames[0].image.dtype == np.uint8 and frames[0].image.shape == (120, 160)
    # the sample standard deviation of 57600 values is within 1.5 % of sigma (rounding adds 1/12)
    assert img.std() == pytest.approx(math.sqrt(9 + 1 / 12), rel=0.015)
    assert img.mean() == pytest.approx(opt.background, abs=0.05)
    again = list(render_frames(t, ["B01"], ["lug"], xy, camera=cam, origin_mm=(0, 0),
                               options=opt, seed=5))
    assert all(np.array_equal(a.image, b.image) for a, b in zip(frames, again))


def test_motion_blur_is_centred_on_the_frame_time():
    cam = default_camera(0.39, (200, 100), dist_coeffs=None)
    opt = QUIET.replace(exposure_s=0.004, n_sub=9, lug_level=QUIET.background)
    t = np.arange(3) / 100.0
    xy = np.stack([np.array([[30.0 + 200.0 * ti, 20.0]]) for ti in t])  # 200 mm/s
    fr = list(render_frames(t, ["B01"], ["lug"], xy, camera=cam, origin_mm=(0, 0), options=opt))[1]
    img = fr.image.astype(float) - opt.background
    ys, xs = np.mgrid[0:100, 0:200]
    centroid = np.array([(img * xs).sum(), (img * ys).sum()]) / img.sum()
    # the blur streak (0.8 mm = 2 px) is symmetric about the true position
    assert np.abs(centroid - fr.truth_px[0]).max() < 0.02
    assert fr.truth_px[0] == pytest.approx([(30.0 + 2.0) / 0.39, 100 - 20.0 / 0.39], abs=1e-9)


def test_bad_inputs_are_refused():
    with pytest.raises(ValueError, match="shape"):
        next(render_frames([0.0, 0.01], ["B01"], ["lug"], np.zeros((3, 1, 2))))
    with pytest.raises(ValueError, match="role"):
        next(render_frames([0.0], ["B01"], ["wheel"], np.zeros((1, 1, 2))))
    with pytest.raises(ValueError, match="increasing"):
        next(render_frames([0.0, 0.0], ["B01"], ["lug"], np.zeros((2, 1, 2))))
