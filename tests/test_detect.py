"""Finding markers and their subpixel centres on frames rendered at known positions."""

import numpy as np
import pytest

from fitlug.sim import RenderOptions, default_camera
from fitlug.sim._render import render_frame
from fitlug.vision import detect_markers, refine_cog, refine_qs

S = 0.39  # mm per px: 6 mm COG discs are 15.4 px across, 10 mm checkers 25.6 px
R_COG = 0.5 * 6.0 / S
HALF_QS = 0.5 * 10.0 / S
REALISTIC = RenderOptions(noise_sigma=2.0, gradient=(0.3, 0.15), vignetting=0.1)


def _frames(kinds, n, rng, opt=REALISTIC, size=(400, 300), blur=(0.0, 0.0)):
    """n frames with markers of `kinds` on a grid, each at a random subpixel position."""
    cam = default_camera(S, size, dist_coeffs=None)
    w, h = size
    cols = 3
    grid = np.array([[60 + 140 * (i % cols), 70 + 150 * (i // cols)] for i in range(len(kinds))],
                    dtype=float)
    tau = np.linspace(-0.5, 0.5, 7)[:, None, None]
    out = []
    for _ in range(n):
        centre = grid + rng.uniform(0, 1, grid.shape)
        sub = centre[None] + tau * np.asarray(blur)
        out.append((render_frame(sub, kinds, cam, opt, rng), sub.mean(axis=0)))
    return out


def _rms(err):
    return np.sqrt(np.mean(np.asarray(err) ** 2, axis=0))


def test_cog_centres_to_a_hundredth_of_a_pixel():
    rng = np.random.default_rng(1)
    err = []
    for img, truth in _frames(["cog"] * 6, 25, rng):
        guess = truth + rng.uniform(-0.7, 0.7, truth.shape)
        fit = refine_cog(img, guess, R_COG, n_iter=2)
        err.append(fit.xy - truth)
    err = np.concatenate(err)
    # 150 discs, noise 2 grey levels, lighting gradient and vignetting
    assert _rms(err).max() < 0.006
    assert np.abs(err.mean(axis=0)).max() < 0.0015  # no bias (pixel locking, gradient)


def test_cog_without_noise_is_exact_and_measures_the_disc():
    rng = np.random.default_rng(2)
    quiet = REALISTIC.replace(noise_sigma=0.0)
    for img, truth in _frames(["cog"] * 3, 5, rng, opt=quiet):
        fit = refine_cog(img, truth + 0.4, R_COG, n_iter=2)
        assert np.abs(fit.xy - truth).max() < 0.003  # rounding to 8 bits only
        np.testing.assert_allclose(fit.radius, R_COG, rtol=0.03)
        assert (fit.streak < 1.0).all()


def test_cog_follows_a_blurred_disc():
    rng = np.random.default_rng(3)
    err, streak = [], []
    for img, truth in _frames(["cog"] * 6, 15, rng, blur=(2.0, 0.0)):
        fit = refine_cog(img, truth + rng.uniform(-0.5, 0.5, truth.shape), R_COG, blur_px=2.5,
                         n_iter=2)
        err.append(fit.xy - truth)
        streak.append(fit.streak)
    assert _rms(np.concatenate(err)).max() < 0.01
    # 7 positions spread over 2 px: a streak of 2 px * 7/6 by its second moment
    assert np.median(np.concatenate(streak)) == pytest.approx(2.0 * 7 / 6, rel=0.1)


def test_qs_centres_to_a_hundredth_of_a_pixel():
    rng = np.random.default_rng(4)
    err = []
    for img, truth in _frames(["qs"] * 6, 20, rng, blur=(0.8, 0.0)):
        guess = truth + rng.uniform(-0.7, 0.7, truth.shape)
        fit = refine_qs(img, guess, HALF_QS, search=2, n_iter=8)
        err.append(fit.xy - truth)
        assert (fit.contrast > 0).all()  # top-left quarter light, as drawn
    err = np.concatenate(err)
    assert _rms(err).max() < 0.008
    assert np.abs(err.mean(axis=0)).max() < 0.0015


def test_qs_warm_start_from_the_previous_frame():
    rng = np.random.default_rng(5)
    frames = _frames(["qs"] * 3, 6, rng)
    fit = refine_qs(frames[0][0], frames[0][1] + 0.3, HALF_QS, n_iter=8)
    err = []
    for img, truth in frames[1:]:
        fit = refine_qs(img, truth + 0.05, HALF_QS, params=fit.params, search=0, n_iter=2)
        err.append(fit.xy - truth)
    assert np.abs(err).max() < 0.02


def test_detects_both_kinds_with_their_sizes():
    rng = np.random.default_rng(6)
    kinds = ["cog", "qs", "cog", "qs", "cog", "cog"]
    (img, truth), = _frames(kinds, 1, rng)
    det = detect_markers(img)
    assert len(det) == len(kinds)
    for k, kind in enumerate(kinds):
        d = np.hypot(*(det.xy - truth[k]).T)
        j = int(np.argmin(d))
        assert d[j] < 0.03
        assert det.kind[j] == kind
        size = R_COG if kind == "cog" else HALF_QS
        assert det.size[j] == pytest.approx(size, rel=0.03)


def test_nothing_is_found_on_noise_and_plain_shapes():
    rng = np.random.default_rng(7)
    img = np.clip(70 + 2 * rng.standard_normal((300, 400)), 0, 255).astype(np.uint8)
    img[100:130, 50:80] = 200  # a bright square is not a disc, a lone edge not a checker
    img[200:, 250:] = 30
    assert len(detect_markers(img)) == 0


def test_half_resolution_search_finds_the_same_markers():
    rng = np.random.default_rng(8)
    (img, truth), = _frames(["cog", "qs", "cog", "qs"], 1, rng)
    full = detect_markers(img, cog_radius=R_COG, qs_half=HALF_QS)
    half = detect_markers(img, cog_radius=R_COG, qs_half=HALF_QS, scale=2)
    assert len(full) == len(half) == 4
    for xy in truth:
        assert np.hypot(*(half.xy - xy).T).min() < 0.03


def test_half_size_search_finds_small_markers_and_no_squares():
    # the tracker's periodic and edge searches shrink the frame for discs >= 7 px across and
    # checkers >= 9.5 px a side: on hard renders (noise 4, blur, a lighting gradient, a bar)
    # every whole marker found at full size is found so, and a small bright square is not a
    # disc there either
    from fitlug.sim._scene import hard_clip

    clip = hard_clip(12, (480, 320), seed=5, cog_px=8.0, qs_px=10.0)
    sizes = dict(cog_radius=3.8, qs_half=5.0, noise=4.0)
    n = 0
    for i in range(0, 12, 3):
        full = detect_markers(clip.frames[i], **sizes)
        half = detect_markers(clip.frames[i], scale={"cog": 2, "qs": 2}, **sizes)
        assert len(half) == len(full)
        for j in np.flatnonzero(clip.visible[i]):
            d = np.hypot(*(half.xy - clip.truth[i, j]).T)
            assert d.min() < 0.1 and half.kind[np.argmin(d)] == clip.kinds[j]
            n += 1
    assert n >= 30
    rng = np.random.default_rng(9)
    img = np.clip(70 + 4 * rng.standard_normal((300, 400)), 0, 255).astype(np.uint8)
    for k, side in enumerate((6, 7, 8)):
        img[50 + 60 * k:50 + 60 * k + side, 100:100 + side] = 200
        img[50 + 60 * k:50 + 60 * k + side, 250 + k:250 + k + side] = 200
    assert len(detect_markers(img, scale={"cog": 2, "qs": 2}, **sizes)) == 0


def test_region_search_reports_full_frame_pixels():
    rng = np.random.default_rng(9)
    (img, truth), = _frames(["cog", "cog", "cog"], 1, rng)
    x, y = truth[1]
    det = detect_markers(img, roi=(x - 30, y - 30, x + 30, y + 30))
    assert len(det) == 1
    assert np.hypot(*(det.xy[0] - truth[1])) < 0.03


def test_windows_leaving_the_frame_give_no_position():
    img = np.full((100, 100), 70, np.uint8)
    fit = refine_cog(img, np.array([[3.0, 50.0], [np.nan, np.nan]]), R_COG)
    assert np.isnan(fit.xy).all() and not fit.inside.any()
    q = refine_qs(img, np.array([[50.0, 97.0]]), HALF_QS)
    assert np.isnan(q.xy).all()


def test_markers_already_followed_are_left_out():
    # a tracker's searches pass the markers its live tracks follow: their candidates are
    # not refined nor returned, the others come out as without them
    rng = np.random.default_rng(9)
    kinds = ["cog", "qs", "cog", "qs", "cog", "cog"]
    (img, truth), = _frames(kinds, 1, rng)
    cog = [k for k, kind in enumerate(kinds) if kind == "cog"]
    qs = [k for k, kind in enumerate(kinds) if kind == "qs"]
    # followed: two discs and one checker, their positions as a track would have them
    known = {"cog": (truth[cog[:2]] + 0.3, [R_COG, R_COG]), "qs": (truth[qs[:1]] - 0.2, [HALF_QS])}
    for scale in (1, 2):
        det = detect_markers(img, cog_radius=R_COG, qs_half=HALF_QS, scale=scale, known=known)
        assert len(det) == len(kinds) - 3
        for k in cog[2:] + qs[1:]:
            d = np.hypot(*(det.xy - truth[k]).T)
            j = int(np.argmin(d))
            assert d[j] < 0.03 and det.kind[j] == kinds[k]
        for k in cog[:2] + qs[:1]:
            assert np.hypot(*(det.xy - truth[k]).T).min() > 2 * R_COG


def test_discs_of_other_sizes_are_found_and_measured_at_their_own_size():
    # discs of one recording differ (issue 45): with the usual size known (6 px radius),
    # a disc 8 px across is found and measured through its own aperture as well, at full
    # and at half size (an aperture for 12 px discs took in a small disc's lug: half its
    # size, 0.2 px off)
    from fitlug.sim._scene import hard_clip

    sizes = (12.0, 8.0, 11.0, 12.0, 9.0, 12.0, 10.0, 12.0)
    clip = hard_clip(1, (480, 320), seed=3, cog_px=sizes)
    img, n = clip.frames[0], 0
    for scale in (1, 2):
        det = detect_markers(img, cog_radius=6.0, qs_half=5.0, noise=4.0, scale=scale)
        for j in np.flatnonzero(clip.visible[0, :len(sizes)]):
            d = np.hypot(*(det.xy - clip.truth[0, j]).T)
            i = int(np.argmin(d))
            assert d[i] < 0.1 and det.kind[i] == "cog", (sizes[j], d[i])
            assert det.size[i] == pytest.approx(0.5 * sizes[j], rel=0.05)
            n += 1
    assert n >= 12
