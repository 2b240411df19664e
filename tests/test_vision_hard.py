"""Tracking hard footage (issue 14): small markers, noise sigma = 4 grey levels, a strong
lighting gradient, motion blur, a dark bar sweeping across, markers leaving the picture.

Truth from the renderer (`hard_clip`): every frame where a marker is whole in the picture
and clear of the bar and of the other markers must give a sample of it (>= 98 %), every
sample lies on the one marker its track follows (no identity swap, no stray), and the
positions reach the RMS targets (COG <= 0.02 px, QS <= 0.015 px per axis).

Discs of different sizes in one recording (issue 45): small and dim discs (8-12 px across,
two at half contrast) among larger ones, in view from the first frame and coming into view
later across the picture's edge, must be picked up like the others (every marker >= 98 %
of its clear frames).
"""

import numpy as np
import pytest

from fitlug.sim._scene import hard_clip
from fitlug.vision import track


@pytest.fixture(scope="module")
def tracked():
    clip = hard_clip(100, (480, 320), seed=3)  # COG discs 9 px across, checkers 10 px
    return clip, track(clip.frames, fps=100.0)


def _owners(res, truth, stray_px=0.15):
    """The truth marker each track follows; asserts all its samples lie on that marker."""
    owner = []
    for k in range(len(res.markers)):
        xy = res.xy_px[:, k]
        ok = np.isfinite(xy[:, 0])
        d = np.hypot(*(xy[ok, None, :] - truth[ok]).transpose(2, 0, 1))  # (n, M)
        j = int(np.argmin(np.nanmedian(d, axis=0)))
        worst = np.nanmax(d[:, j])
        assert worst < stray_px, f"track {res.markers[k]} strays {worst:.3f} px from marker {j}"
        owner.append(j)
    return owner


def test_the_scene_is_hard(tracked):
    clip, _ = tracked
    vis = clip.visible
    kinds = np.array(clip.kinds)
    # markers hidden by the bar for a few frames, some leaving the picture, all small
    assert (~vis[:, kinds == "cog"]).sum() >= 8 * 3
    assert not vis[-1].all() and vis[0].sum() >= 8
    assert clip.options.noise_sigma == 4.0
    assert 8.0 <= clip.options.cog_diameter_mm / clip.camera.mm_per_px <= 10.0
    inside = np.isfinite(clip.truth[..., 0]) & (clip.truth[..., 0] < 480)
    assert (inside & ~vis).any()  # in the picture but not whole or not clear: no sample owed


def test_small_markers_are_found_without_swaps(tracked):
    clip, res = tracked
    owner = _owners(res, clip.truth)
    found = np.zeros(clip.visible.shape, bool)
    for k, j in enumerate(owner):
        found[:, j] |= np.isfinite(res.xy_px[:, k, 0])
    for kind in ("cog", "qs"):
        cols = [j for j, k in enumerate(clip.kinds) if k == kind]
        vis = clip.visible[:, cols]
        assert found[:, cols][vis].mean() >= 0.98, f"{kind}: {found[:, cols][vis].mean():.1%}"
    per_marker = [found[clip.visible[:, j], j].mean() for j in range(len(clip.kinds))]
    assert min(per_marker) >= 0.95, per_marker
    # one track per marker for most: a marker may be split (a new id after a loss), never
    # two markers under one id (checked above)
    assert len(res.markers) <= len(clip.kinds) + 2


def test_positions_reach_the_targets(tracked):
    clip, res = tracked
    owner = _owners(res, clip.truth)
    for kind, target in (("cog", 0.02), ("qs", 0.015)):
        err = [res.xy_px[:, k] - clip.truth[:, j] for k, j in enumerate(owner)
               if clip.kinds[j] == kind]
        vis = [clip.visible[:, j] for k, j in enumerate(owner) if clip.kinds[j] == kind]
        e = np.concatenate([x[v & np.isfinite(x[:, 0])] for x, v in zip(err, vis)])
        rms = np.sqrt(np.mean(e ** 2, axis=0))
        assert e.shape[0] > 50
        assert rms.max() <= target, f"{kind}: rms {rms} px"
        assert np.abs(e.mean(axis=0)).max() < 0.5 * target  # and no bias


# discs 8-12 px across (per lug marker), two at half or 0.6 of the contrast; the rig's rear
# starts just inside the picture so that two lug markers on the top run come into view later
SIZES = (12.0, 8.0, 11.0, 12.0, 9.0, 12.0, 10.0, 12.0)
DIM = (1.0, 1.0, 1.0, 0.5, 1.0, 1.0, 0.6, 1.0)


@pytest.fixture(scope="module")
def mixed():
    w, h, s = 400, 280, 0.39
    r, d = 0.22 * h * s, 0.45 * w * s  # (hard_clip's stadium for this picture)
    clip = hard_clip(100, (w, h), seed=3, cog_px=SIZES, cog_contrast=DIM,
                     origin_mm=(-(0.5 * d + r) + 0.05 * w * s, r - 0.5 * h * s))
    return clip, track(clip.frames, fps=100.0)


def test_discs_of_every_size_are_picked_up(mixed):
    clip, res = mixed
    vis, kinds = clip.visible, np.array(clip.kinds)
    # the scene: small and dim discs in view from the first frame, others coming into view
    # later, all of them hidden by the bar for a few frames
    first = vis.argmax(axis=0)
    assert (first[kinds == "cog"] == 0).sum() >= 5 and (first[kinds == "cog"] >= 20).sum() >= 2
    small = [j for j in range(len(SIZES)) if SIZES[j] <= 10.0]
    assert {8.0, 9.0, 10.0} <= {SIZES[j] for j in small} and first[small].max() >= 20
    hidden = np.isfinite(clip.truth[..., 0]) & ~vis
    assert all(hidden[first[j]:, j].sum() >= 3 for j in small)
    owner = _owners(res, clip.truth)  # (every sample on the marker its track follows)
    found = np.zeros(vis.shape, bool)
    for k, j in enumerate(owner):
        found[:, j] |= np.isfinite(res.xy_px[:, k, 0])
    rate = [float(found[vis[:, j], j].mean()) for j in range(len(clip.kinds))]
    assert min(rate) >= 0.98, [(SIZES[j] if j < len(SIZES) else "qs", round(r, 3))
                               for j, r in enumerate(rate)]
    assert len(res.markers) <= len(clip.kinds) + 2  # (a marker may be split, never swapped)
    for kind, target in (("cog", 0.02), ("qs", 0.015)):
        e = np.concatenate([(res.xy_px[:, k] - clip.truth[:, j])[vis[:, j] & np.isfinite(
            res.xy_px[:, k, 0])] for k, j in enumerate(owner) if clip.kinds[j] == kind])
        rms = np.sqrt(np.mean(e ** 2, axis=0))
        assert rms.max() <= target, f"{kind}: rms {rms} px"
