"""Subpixel centres of COG markers (bright discs), many at once; window cutting for both kinds.

`refine_cog` works on small windows cut around first guesses, for all discs of a frame
in one batch (arrays (M, N) of the N pixels of each window), with the sums done as one
matrix product against the pixel coordinates: the per-frame cost is a few dozen numpy
calls whatever the number of markers.

The estimate is the intensity-weighted centre of gravity of the disc with its local
background removed:

1. a plane fitted to an annulus just outside the disc is subtracted (local background);
2. a centroid in a soft circular aperture holding the whole disc (its anti-aliased edge
   and motion blur included) moves the guess onto the disc;
3. the final centroid, in the aperture re-centred there, of the window divided by the
   disc's own brightness plane (fitted on its interior) and with the interior replaced
   by that plane's level. With a motion-blur direction the aperture is the stadium the
   disc sweeps and the interior the lens all its positions share.

Step 3 matters: a lighting gradient across the disc pulls an intensity-weighted centroid
by (relative slope) x (second moment), which flat-fielding removes; the interior pixels
carry noise but no position information, which replacing them removes. With the
background at zero the aperture's edge only sees zero-mean noise, so the estimate has no
pixel-locking bias.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np


def cut_windows(frame: np.ndarray, centres: np.ndarray, half: int):
    """Windows (M, 2h+1, 2h+1) float64 around integer centres (M, 2) (x, y).

    Returns (windows, inside): windows reaching past the frame edge are clamped and
    flagged False in `inside` (M,).
    """
    h, w = frame.shape
    cx, cy = centres[:, 0], centres[:, 1]
    inside = (cx - half >= 0) & (cx + half < w) & (cy - half >= 0) & (cy + half < h)
    off = np.arange(-half, half + 1)
    ys = np.clip(cy[:, None] + off, 0, h - 1)
    xs = np.clip(cx[:, None] + off, 0, w - 1)
    return frame[ys[:, :, None], xs[:, None, :]].astype(np.float64), inside


@functools.lru_cache(maxsize=64)
def _disc_offsets(radius: float):
    half = int(np.ceil(radius))
    off = np.arange(-half, half + 1)
    yy, xx = np.meshgrid(off, off, indexing="ij")
    keep = (xx * xx + yy * yy) <= radius * radius
    xs, ys = xx[keep], yy[keep]
    fx, fy = xs.astype(np.float64), ys.astype(np.float64)
    basis = np.stack([np.ones_like(fx), fx, fy, fx * fx, fx * fy, fy * fy], axis=1)
    return half, xs, ys, fx, fy, basis


@functools.lru_cache(maxsize=64)
def _flat_offsets(radius: float, width: int):
    """Offsets of the disc's pixels in a flattened frame `width` px wide."""
    half, xs, ys = _disc_offsets(radius)[:3]
    return ys.astype(np.int64) * width + xs


@functools.lru_cache(maxsize=64)
def _disc_f32(radius: float):
    """The disc's offsets X, Y (N,), basis (N, 6), distance from the centre (N,) and the
    plane's basis (3, N): 1, X, Y, float32."""
    fx, fy, basis = _disc_offsets(radius)[3:]
    f32 = np.float32
    b32 = basis.astype(f32)
    return (*_typed_offsets(radius, np.dtype(f32).str), b32,
            np.sqrt(fx * fx + fy * fy).astype(f32), np.ascontiguousarray(b32[:, :3].T))


def cut_disc(frame: np.ndarray, centres: np.ndarray, radius: float, dtype=np.float64):
    """The pixels within `radius` of integer centres (M, 2): values (M, N) of `dtype`, their
    offsets X, Y (N,) from the centre (shared arrays: read-only), and `inside` (M,) as in
    `cut_windows`."""
    radius = np.ceil(float(radius) * 4.0) / 4.0  # few sizes
    half, xs, ys = _disc_offsets(radius)[:3]
    fx, fy = _typed_offsets(radius, np.dtype(dtype).str)
    h, w = frame.shape
    inside = ((centres >= half) & (centres < (w - half, h - half))).all(axis=1)
    cx, cy = centres[:, 0], centres[:, 1]
    all_inside = inside.all()
    if all_inside and frame.flags.c_contiguous:
        # one take from the flattened frame (a view): a few times faster than indexing
        # rows and columns
        vals = frame.reshape(-1).take((cy * w + cx)[:, None] + _flat_offsets(radius, w))
    elif all_inside:
        vals = frame[cy[:, None] + ys, cx[:, None] + xs]
    else:
        vals = frame[np.clip(cy[:, None] + ys, 0, h - 1), np.clip(cx[:, None] + xs, 0, w - 1)]
    return vals.astype(dtype), fx, fy, inside


@functools.lru_cache(maxsize=64)
def _typed_offsets(radius: float, dtype: str):
    """The disc's offsets X, Y (N,) as `dtype` (shared, read-only)."""
    out = tuple(v.astype(dtype) for v in _disc_offsets(radius)[3:5])
    for v in out:
        v.flags.writeable = False
    return out


@dataclass
class CogFit:
    """Result of `refine_cog`, arrays over markers (M,): `xy` (M, 2) px (NaN when the
    window left the frame), `flux` (background-free sum, grey levels x px), `contrast`
    (mean disc level above the background), `radius` (disc radius from the second moment
    across the blur, px), `streak` (motion-blur length from the second moments, px; noise
    makes it come out long: average `shear` over frames instead), `shear` (M, 2) the
    traceless second moments ((mxx - myy) / 2, mxy), px²,
    `noise` (background residual std), `level` (the disc's brightness above the
    background at its centre, fitted on its interior), `slope` (M, 2) relative brightness
    slope of the disc fitted on its interior in this frame, 1/px (used for flat-fielding
    unless `gain_slope` was given), `inside` (bool). flux / level is the
    disc's area whatever the lighting: a partly hidden disc shows less. `contrast`,
    `streak` and `noise` are None when refine_cog was asked for no `stats`."""

    xy: np.ndarray
    flux: np.ndarray
    contrast: np.ndarray
    radius: np.ndarray
    streak: np.ndarray
    shear: np.ndarray
    noise: np.ndarray
    level: np.ndarray
    slope: np.ndarray
    inside: np.ndarray


_NORMAL = np.array([0, 1, 2, 1, 3, 4, 2, 4, 5])  # the 3x3 normal matrix from 1, x, y, x², xy, y²
_RIDGE = np.array([1e-9, 0, 0, 1e-9, 0, 1e-9])  # 1e-9 on its diagonal (no weight at all: a
# zero plane)
# its adjugate (symmetric, the same six places): cofactor k = n[a] n[b] - n[c] n[d]
_COFACTORS = np.array([[3, 2, 1, 0, 1, 0], [5, 4, 4, 5, 2, 3],
                       [4, 1, 2, 2, 0, 1], [4, 5, 3, 2, 4, 1]])


_FIRST_A, _FIRST_B = np.array([0, 0, 1]), np.array([0, 1, 1])  # x x, x y, y y from x, y


def _weighted_plane(weights, values, basis):
    """Least-squares plane a + b x + c y through `values` (M, N) with `weights` (M, N).

    basis: (N, 6) columns 1, x, y, x², xy, y². Returns coefficients (M, 3).

    The 3x3 normal equations are solved in closed form (adjugate over determinant,
    vectorised over markers): a handful of numpy calls rather than a batched LAPACK solve,
    whose per-call cost is several times theirs for these tiny systems."""
    n = (weights @ basis) + _RIDGE  # (M, 6) the normal matrix's entries (float64 from here)
    rhs = (weights * values) @ basis[:, :3]  # (cast to float64 by the product below)
    g = n[:, _COFACTORS]  # (M, 4, 6)
    cof = g[:, 0] * g[:, 1] - g[:, 2] * g[:, 3]  # c00, c01, c02, c11, c12, c22
    det = np.einsum("mk,mk->m", n[:, :3], cof[:, :3])
    return np.einsum("mij,mj->mi", cof[:, _NORMAL].reshape(-1, 3, 3), rhs) / det[:, None]


def _per_marker(v, m, dtype):
    """A scalar or (M,) as a column (M, 1) of `dtype` (np.broadcast_to costs more than the
    rest of a small step)."""
    v = np.asarray(v, dtype=dtype)
    return np.full((m, 1), v, dtype=dtype) if v.ndim == 0 else v.reshape(m, 1)


def refine_cog(frame: np.ndarray, xy0: np.ndarray, radius, *, blur_px=0.0, blur_dir=None,
               n_iter: int = 1, gain_slope=None, stats: bool = True) -> CogFit:
    """Centre of gravity of bright discs near first guesses.

    frame: (H, W) grey image (any numeric dtype); xy0: (M, 2) first guesses, px, within
    about one radius of the centres; radius: disc radius px, scalar or (M,); blur_px:
    motion-blur streak expected, px, scalar or (M,) (widens the aperture); blur_dir: (M, 2)
    unit vectors along the streaks if known (the aperture and the interior then follow
    the streak's shape, a stadium and a lens, rather than widening all round); n_iter:
    plain centroid steps before the final one (1 is enough from a guess within a pixel);
    gain_slope: (M, 2) relative brightness slope of each disc, 1/px, if known, else
    fitted on the disc's interior; stats: also `contrast`, `streak` and `noise` (else None:
    a tracker following the discs has no use for them).
    """
    xy0 = np.asarray(xy0, dtype=np.float64).reshape(-1, 2)
    m = xy0.shape[0]
    f32 = np.float32  # the sums below need no more: float32 halves the memory traffic
    # (the per-frame cost is in the number of numpy calls on small arrays: few of them)
    r = _per_marker(radius, m, f32)
    half = f32(0.5) * _per_marker(blur_px, m, f32)
    ra = r + f32(1.0) + half  # aperture: disc, anti-aliased edge, blur
    ok = np.isfinite(xy0).all(axis=1)
    xy0 = np.where(ok[:, None], xy0, 0.0)  # (a guess that is not one: the window at 0, 0)
    base = np.rint(xy0).astype(np.int64)
    reach = np.ceil((float(ra.max()) + 3.0 if m else 1.0) * 4.0) / 4.0
    win, _, _, inside = cut_disc(frame, base, reach, dtype=f32)
    gx, gy, basis, rho0, basis3t = _disc_f32(reach)
    # 1. local background: a plane through an annulus outside the disc (about the window
    #    centre, within half a pixel of the guess)
    ring = (np.abs(rho0 - (ra + f32(1.625))) <= f32(1.125)).astype(f32)
    win -= _weighted_plane(ring, win, basis).astype(f32) @ basis3t
    # the annulus may reach past the dark surround of a small disc (the lug's edge, the
    # lighter surface beyond it): pixels well above the plane are not background. Their
    # spread is measured on the pixels below the plane (which they do not reach); fit
    # again without them.
    n_ring = ring.sum(axis=1)
    for _ in range(2):
        below = ring * (win < 0)
        scale = np.sqrt(np.einsum("mn,mn,mn->m", below, win, win)
                        / np.maximum(below.sum(axis=1), 1))
        keep = ring * (win <= f32(3.0) * scale[:, None] + f32(0.5))
        n_keep = keep.sum(axis=1)
        if (n_keep == n_ring).all():
            break
        win -= _weighted_plane(keep, win, basis).astype(f32) @ basis3t
        ring, n_ring = keep, n_keep
    noise = np.sqrt(np.einsum("mn,mn,mn->m", ring, win, win, dtype=np.float64)
                    / np.maximum(n_ring.astype(np.float64) - 3, 1)) if stats else None
    # 2. plain centroid steps in the aperture
    c = (xy0 - base).astype(f32)
    for _ in range(n_iter):
        dx, dy = gx - c[:, :1], gy - c[:, 1:]
        wgt = np.sqrt(dx * dx + dy * dy)
        np.subtract(ra + f32(0.5), wgt, out=wgt)
        np.maximum(wgt, 0, out=wgt)
        np.minimum(wgt, 1, out=wgt)
        wgt *= win
        mom = (wgt @ basis[:, :3]).astype(np.float64)
        c = (mom[:, 1:3] / np.where(mom[:, :1] > 0, mom[:, :1], 1.0)).astype(f32)
    # 3. flat-fielded centroid, the interior replaced by its fitted level
    dx, dy = gx - c[:, :1], gy - c[:, 1:]
    rho2 = dx * dx + dy * dy
    if blur_dir is None:
        rho = np.sqrt(rho2)
        wi = r - f32(0.5) - half - rho
        ap = ra + f32(0.5) - rho
    else:
        # a disc swept along a segment: covered by all its positions inside both end discs
        # (the lens), by none beyond the disc's reach from the segment (the stadium)
        u = np.asarray(blur_dir, dtype=f32).reshape(-1, 2)
        along = np.abs(dx * u[:, :1] + dy * u[:, 1:])
        across2 = np.maximum(rho2 - along * along, 0)
        wi = r - f32(0.5) - np.sqrt(across2 + (along + half) ** 2)
        ap = r + f32(1.5) - np.sqrt(across2 + np.maximum(along - half, 0) ** 2)
    for a in (wi, ap):
        np.maximum(a, 0, out=a)
        np.minimum(a, 1, out=a)
    coef = _weighted_plane(wi, win, basis)
    cc = c.astype(np.float64)
    level = coef[:, 0] + np.einsum("mk,mk->m", coef[:, 1:], cc)
    fitted = coef[:, 1:3] / np.where(np.abs(level) > 0, level, 1.0)[:, None]
    rel = (fitted if gain_slope is None else np.asarray(gain_slope, dtype=np.float64)).astype(f32)
    rel = rel.reshape(-1, 2)
    flat = win / (f32(1.0) + rel[:, :1] * dx + rel[:, 1:] * dy)
    wgt = (flat + wi * (level.astype(f32)[:, None] - flat)) * ap
    mom = (wgt @ basis).astype(np.float64)  # raw moments about the window centre
    flux = mom[:, 0]
    f = np.where(flux > 0, flux, 1.0)
    nm = mom[:, 1:] / f[:, None]  # x, y, x², xy, y² normalised; central second moments:
    mxx, mxy, myy = (nm[:, 2:] - nm[:, _FIRST_A] * nm[:, _FIRST_B]).T
    # A disc of radius R blurred along a streak of length L, sampled by pixels: second
    # moments R²/4 + 1/12 across the streak and R²/4 + 1/12 + L²/12 along it.
    diff = mxx - myy
    half_tr, half_diff = 0.5 * (mxx + myy), np.sqrt(0.25 * diff ** 2 + mxy ** 2)
    radius_m = 2.0 * np.sqrt(np.maximum(half_tr - half_diff - 1.0 / 12.0, 0.0))
    streak = contrast = None
    if stats:
        streak = np.sqrt(24.0 * half_diff)
        contrast = flux / (np.pi * np.maximum(radius_m, 1e-9) ** 2)
    xy = nm[:, :2] + base
    good = ok & inside
    xy[~(good & (flux > 0))] = np.nan
    shear = np.empty((m, 2))
    shear[:, 0], shear[:, 1] = 0.5 * diff, mxy
    return CogFit(xy, flux, contrast, radius_m, streak, shear, noise, level, fitted, good)
