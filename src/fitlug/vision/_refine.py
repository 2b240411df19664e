"""Subpixel positions of many markers at once: COG discs and QS checkers.

Both work on small windows cut around a first guess, for all markers of one kind in one
batch (arrays (M, n, n)): the per-frame cost is a few dozen numpy calls, whatever the
number of markers.

COG (`refine_cog`): intensity-weighted centre of gravity of the disc with the local
background removed - a plane fitted to an annulus just outside the disc is subtracted,
then the centroid is taken in a soft circular aperture that holds the whole disc, and the
aperture is re-centred on the result. With the background at zero, the aperture's edge
only sees zero-mean noise, so the estimate has no pixel-locking bias.

QS (`refine_qs`): the point of quadrant symmetry, found in two steps. Coarse: the integer
position maximising the correlation with an ideal ±1 checker (box sums over an integral
image), with a parabola through the peak. Fine: a least-squares fit of a 2x2 checker
model to the window - two pixel-integrated tanh edges crossing at (x0, y0) at an angle
θ, with their own widths (optics, motion blur), a planar offset and a planar contrast
(lighting gradient) - by Gauss-Newton. The model is point-symmetric about (x0, y0), so
the fitted centre is the centre of symmetry; an edge profile that is not exactly tanh is
symmetric too and does not bias it.
"""

from __future__ import annotations

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


@dataclass
class CogFit:
    """Result of `refine_cog`, arrays over markers (M,): `xy` (M, 2) px (NaN when the
    window left the frame), `flux` (background-free sum, grey levels x px), `contrast`
    (disc level above the background), `radius` (disc radius from the second moment, px),
    `elongation` ((λ1 - λ2) / (λ1 + λ2) of the second moments), `noise` (background
    residual std), `inside` (bool)."""

    xy: np.ndarray
    flux: np.ndarray
    contrast: np.ndarray
    radius: np.ndarray
    elongation: np.ndarray
    noise: np.ndarray
    inside: np.ndarray


def _plane_fit(win, mask, gx, gy):
    """Least-squares plane over the masked pixels of each window: (M, n, n) values."""
    m = mask.astype(np.float64)
    x = gx[None, None, :]
    y = gy[None, :, None]
    s1 = m.sum(axis=(1, 2))
    sx, sy = (m * x).sum(axis=(1, 2)), (m * y).sum(axis=(1, 2))
    sxx, syy, sxy = (m * x * x).sum(axis=(1, 2)), (m * y * y).sum(axis=(1, 2)), (m * x * y).sum(axis=(1, 2))
    mv = m * win
    b = np.stack([mv.sum(axis=(1, 2)), (mv * x).sum(axis=(1, 2)), (mv * y).sum(axis=(1, 2))], axis=1)
    a = np.stack([np.stack([s1, sx, sy], 1), np.stack([sx, sxx, sxy], 1),
                  np.stack([sy, sxy, syy], 1)], axis=1)
    coef = np.linalg.solve(a + 1e-9 * np.eye(3), b[..., None])[..., 0]
    plane = coef[:, 0, None, None] + coef[:, 1, None, None] * x + coef[:, 2, None, None] * y
    resid = np.sqrt((m * (win - plane) ** 2).sum(axis=(1, 2)) / np.maximum(s1 - 3, 1))
    return plane, resid


def _interior_slope(win, mask, dx, dy):
    """Level and (x, y) slope of a plane fitted to the masked pixels, about (dx, dy) = 0."""
    m = mask.astype(np.float64)
    n = np.maximum(m.sum(axis=(1, 2)), 1.0)
    mx, my = (m * dx).sum(axis=(1, 2)) / n, (m * dy).sum(axis=(1, 2)) / n
    ex, ey = (dx - mx[:, None, None]) * m, (dy - my[:, None, None]) * m
    sxx, syy, sxy = (ex * ex).sum(axis=(1, 2)), (ey * ey).sum(axis=(1, 2)), (ex * ey).sum(axis=(1, 2))
    bx, by = (ex * win).sum(axis=(1, 2)), (ey * win).sum(axis=(1, 2))
    det = np.where(sxx * syy - sxy ** 2 > 0, sxx * syy - sxy ** 2, 1.0)
    ax, ay = (syy * bx - sxy * by) / det, (sxx * by - sxy * bx) / det
    level = (m * win).sum(axis=(1, 2)) / n - ax * mx - ay * my
    return level, np.stack([ax, ay], axis=1)


def refine_cog(frame: np.ndarray, xy0: np.ndarray, radius, *, blur_px: float = 0.0,
               n_iter: int = 3) -> CogFit:
    """Centre of gravity of bright discs near first guesses.

    frame: (H, W) grey image (any numeric dtype); xy0: (M, 2) first guesses, px, within
    about one radius of the centres; radius: disc radius px, scalar or (M,); blur_px:
    longest motion-blur streak expected, px (widens the aperture).
    """
    xy0 = np.asarray(xy0, dtype=np.float64).reshape(-1, 2)
    r = np.broadcast_to(np.asarray(radius, dtype=np.float64), xy0.shape[:1])
    ra = r + 1.0 + 0.5 * blur_px  # aperture: whole disc, its anti-aliased edge, the blur
    half = int(np.ceil(ra.max() + 4.5)) if r.size else 1
    ok = np.isfinite(xy0).all(axis=1)
    base = np.where(ok[:, None], np.rint(xy0), 0).astype(np.int64)
    win, inside = cut_windows(frame, base, half)
    g = np.arange(-half, half + 1, dtype=np.float64)
    c = np.where(ok[:, None], xy0 - base, 0.0)  # guess relative to the window centre
    rho2 = (g[None, None, :] - c[:, 0, None, None]) ** 2 + (g[None, :, None] - c[:, 1, None, None]) ** 2
    ring = (rho2 >= ((ra + 1.0) ** 2)[:, None, None]) & (rho2 <= ((ra + 3.5) ** 2)[:, None, None])
    plane, noise = _plane_fit(win, ring, g, g)
    win = win - plane
    for _ in range(n_iter):
        dx = g[None, None, :] - c[:, 0, None, None]
        dy = g[None, :, None] - c[:, 1, None, None]
        rho = np.sqrt(dx * dx + dy * dy)
        wgt = win * np.clip(ra[:, None, None] + 0.5 - rho, 0.0, 1.0)
        flux = wgt.sum(axis=(1, 2))
        safe = np.where(flux > 0, flux, 1.0)
        c = c + np.stack([(wgt * dx).sum(axis=(1, 2)), (wgt * dy).sum(axis=(1, 2))], axis=1) / safe[:, None]
    dx = g[None, None, :] - c[:, 0, None, None]
    dy = g[None, :, None] - c[:, 1, None, None]
    wgt = win * np.clip(ra[:, None, None] + 0.5 - np.sqrt(dx * dx + dy * dy), 0.0, 1.0)
    flux = wgt.sum(axis=(1, 2))
    safe = np.where(flux > 0, flux, 1.0)
    mxx, myy = (wgt * dx * dx).sum(axis=(1, 2)) / safe, (wgt * dy * dy).sum(axis=(1, 2)) / safe
    mxy = (wgt * dx * dy).sum(axis=(1, 2)) / safe
    # Flat-field: the disc's own brightness slope (lighting gradient, vignetting) pulls an
    # intensity-weighted centroid by slope x second moment; fit the slope on the disc's
    # interior and take that pull off. (It also takes off most of the interior pixels'
    # noise, which carries no position information.)
    inner = (np.sqrt(dx * dx + dy * dy) <= (r - 0.75 - 0.5 * blur_px)[:, None, None])
    lvl, slope = _interior_slope(win, inner, dx, dy)
    rel = slope / np.where(np.abs(lvl) > 0, lvl, 1.0)[:, None]
    c = c - np.stack([rel[:, 0] * mxx + rel[:, 1] * mxy, rel[:, 0] * mxy + rel[:, 1] * myy], axis=1)
    tr = mxx + myy
    elong = np.sqrt((mxx - myy) ** 2 + 4 * mxy ** 2) / np.where(tr > 0, tr, 1.0)
    radius_m = np.sqrt(np.maximum(2 * tr, 0))  # uniform disc: <ρ²> = R²/2
    contrast = flux / (np.pi * np.maximum(radius_m, 1e-9) ** 2)
    xy = base + c
    bad = ~(ok & inside & (flux > 0))
    xy[bad] = np.nan
    return CogFit(xy, flux, contrast, radius_m, elong, noise, inside & ok)
