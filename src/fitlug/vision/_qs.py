"""Subpixel centres of QS markers (2x2 checkers): the point of quadrant symmetry.

Two steps, for all markers of a frame in one batch. Coarse (`qs_coarse`): the integer
position maximising the correlation with an ideal ±1 checker (box sums over an integral
image), with a parabola through the peak. Fine (`refine_qs`): a least-squares fit of a
checker model to a round window inside the marker - two straight edges crossing at
(x0, y0) at an angle θ, each a step blurred by the pixel and by a box of its own width
(motion blur and optics), a planar offset and a planar contrast (lighting gradient) -
by damped Gauss-Newton. The
model is point-symmetric about (x0, y0) and antisymmetric under a quarter turn, so the
fitted centre is the centre of quadrant symmetry.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._refine import cut_windows

N_PARAMS = 11  # x0, y0, θ, blur_u, blur_v, A, a_x, a_y, B, b_x, b_y
_A, _B = 5, 8  # offset plane and contrast plane start here


@dataclass
class QsFit:
    """Result of `refine_qs`, arrays over markers (M,): `xy` (M, 2) px (NaN when the
    window left the frame or the fit failed), `angle` (rad), `widths` (M, 2) blur
    across the two edges, px, `contrast` (half the light-dark difference, signed: > 0 when the top-left quadrant
    is light), `rms` (fit residual, grey levels), `inside` (bool), `params` (M, N_PARAMS) for
    warm starts."""

    xy: np.ndarray
    angle: np.ndarray
    widths: np.ndarray
    contrast: np.ndarray
    rms: np.ndarray
    inside: np.ndarray
    params: np.ndarray


_SIGNS = np.array([[s1, s2] for s1 in (1.0, -1.0) for s2 in (1.0, -1.0)])
_PARITY = _SIGNS.prod(axis=1)


def _edge(u, b):
    """A straight edge seen by the camera: a step blurred by two boxes - the pixel (1 px)
    and the blur across the edge (b px: motion blur and optics) - as a value in [-1, 1].

    u: (M, n, n) signed distance from the edge, px; b: (M, 1, 1) blur width, px.
    Returns S, dS/du and dS/db (each (M, n, n)).
    """
    off = 0.5 * (_SIGNS[:, 0] + _SIGNS[:, 1] * b[..., None])
    zp = np.maximum(u[..., None] + off, 0.0)  # (M, n, n, 4)
    e = ((zp * zp) @ _PARITY) * (0.5 / b)  # Σ ± z²/2 / b: the blurred unit step
    du = (zp @ _PARITY) / b
    db = (zp @ (0.5 * _PARITY * _SIGNS[:, 1])) / b - e / b
    return 2 * e - 1, 2 * du, 2 * db


def qs_coarse(win: np.ndarray, half_q: int, search: int):
    """Integer offsets (M, 2) (x, y) from the window centre maximising |checker correlation|,
    refined by a parabola through the peak; returns (offsets, correlation at the peak)."""
    m, n, _ = win.shape
    ii = np.zeros((m, n + 1, n + 1))
    ii[:, 1:, 1:] = win.cumsum(axis=1).cumsum(axis=2)
    ctr = n // 2
    off = np.arange(-search, search + 1)
    cy = ctr + off[:, None]  # candidate centres (rows), (K, 1)
    cx = ctr + off[None, :]

    def box(y0, y1, x0, x1):  # sum of win[y0:y1, x0:x1] for every candidate
        return ii[:, y1, x1] - ii[:, y0, x1] - ii[:, y1, x0] + ii[:, y0, x0]

    h = half_q
    # quadrants excluding the centre row/column, which straddle the edges
    tl = box(cy - h, cy, cx - h, cx)
    br = box(cy + 1, cy + 1 + h, cx + 1, cx + 1 + h)
    tr = box(cy - h, cy, cx + 1, cx + 1 + h)
    bl = box(cy + 1, cy + 1 + h, cx - h, cx)
    score = np.abs(tl + br - tr - bl)  # (M, K, K)
    k = score.shape[1]
    flat = score.reshape(m, -1).argmax(axis=1)
    iy, ix = np.divmod(flat, k)
    iy_c, ix_c = np.clip(iy, 1, k - 2), np.clip(ix, 1, k - 2)
    rows = np.arange(m)

    def vertex(sm, s0, sp):
        den = sm - 2 * s0 + sp
        return np.where(den < 0, np.clip(0.5 * (sm - sp) / np.where(den < 0, den, -1), -0.5, 0.5), 0.0)

    fx = vertex(score[rows, iy_c, ix_c - 1], score[rows, iy_c, ix_c], score[rows, iy_c, ix_c + 1])
    fy = vertex(score[rows, iy_c - 1, ix_c], score[rows, iy_c, ix_c], score[rows, iy_c + 1, ix_c])
    fx = np.where(ix == ix_c, fx, 0.0)
    fy = np.where(iy == iy_c, fy, 0.0)
    return np.stack([off[ix] + fx, off[iy] + fy], axis=1), score[rows, iy, ix]


def _fit(win, rfit, g, p, n_iter):
    """Damped Gauss-Newton on the checker model; p (M, N_PARAMS) is updated and returned.

    The pixels are weighted by a soft disc of radius rfit centred on the current estimate:
    a window symmetric about the centre keeps whatever the model leaves unexplained (it is
    point-symmetric too) from pulling the centre.
    """
    x = g[None, None, :]
    y = g[None, :, None]
    eye = np.eye(N_PARAMS)
    for _ in range(n_iter):
        x0, y0, th, bu, bv = (p[:, i, None, None] for i in range(5))
        dx, dy = x - x0, y - y0
        m = np.clip(rfit + 0.5 - np.sqrt(dx * dx + dy * dy), 0.0, 1.0)
        c, s = np.cos(th), np.sin(th)
        u, v = c * dx + s * dy, c * dy - s * dx
        su, du, dbu = _edge(u, bu)
        sv, dv, dbv = _edge(v, bv)
        prod = su * sv
        gain = p[:, _B, None, None] + p[:, _B + 1, None, None] * x + p[:, _B + 2, None, None] * y
        model = p[:, _A, None, None] + p[:, _A + 1, None, None] * x + p[:, _A + 2, None, None] * y \
            + gain * prod
        a, b = gain * du * sv, gain * su * dv
        ones = np.ones_like(prod)
        jac = np.stack([-c * a + s * b, -s * a - c * b, v * a - u * b, gain * dbu * sv,
                        gain * su * dbv, ones, x * ones, y * ones,
                        prod, x * prod, y * prod], axis=1) * m[:, None]
        jac = jac.reshape(jac.shape[0], N_PARAMS, -1)
        res = ((win - model) * m).reshape(jac.shape[0], -1)
        hess = jac @ jac.transpose(0, 2, 1)
        grad = (jac @ res[:, :, None])[..., 0]
        damp = 1e-3 * np.einsum("mii->mi", hess)[:, :, None] * eye + 1e-9 * eye
        step = np.linalg.solve(hess + damp, grad[..., None])[..., 0]
        step[:, :2] = np.clip(step[:, :2], -1.0, 1.0)
        step[:, 3:5] = np.clip(step[:, 3:5], -0.5, 0.5)
        p = p + step
        p[:, 3:5] = np.clip(p[:, 3:5], 0.05, 8.0)
    rms = np.sqrt((res ** 2).sum(axis=1) / np.maximum(m.sum(axis=(1, 2)) - N_PARAMS, 1))
    return p, rms


def _edge_widths(win):
    """Rough blur widths (M, 2) px across the vertical and the horizontal edge, from the
    differences along rows and columns: a ramp of width L gives (Σ|d|)² / Σd² = L."""
    out = []
    c = win.shape[1] // 2  # the edges pass within a pixel of the window centre: use ±4 px
    for d in (np.diff(win[:, :, c - 4:c + 5], axis=2),
              np.diff(win[:, c - 4:c + 5, :], axis=1).transpose(0, 2, 1)):
        s1 = np.abs(d).sum(axis=2)
        s2 = (d * d).sum(axis=2)
        width = np.median(s1 * s1 / np.maximum(s2, 1e-12), axis=1)
        out.append(np.clip(width - 0.3, 0.3, 6.0))
    return np.stack(out, axis=1)


def refine_qs(frame: np.ndarray, xy0: np.ndarray, half_size, *, params: np.ndarray | None = None,
              search: int = 2, n_iter: int = 4) -> QsFit:
    """Centres of QS markers near first guesses.

    frame: (H, W) grey image; xy0: (M, 2) first guesses px; half_size: half the side of
    the checker, px (scalar: one window size for the batch); params: (M, N_PARAMS) results
    of the previous frame (warm start: angle, widths and levels), or None; search: ± range
    of the coarse search, px (0: trust xy0 and skip it).
    """
    xy0 = np.asarray(xy0, dtype=np.float64).reshape(-1, 2)
    m = xy0.shape[0]
    ok = np.isfinite(xy0).all(axis=1)
    hs = float(half_size)
    rfit = max(2.5, 0.85 * hs - 1.5)  # pixels well inside the checker only
    base = np.where(ok[:, None], np.rint(xy0), 0).astype(np.int64)
    inside = ok.copy()
    if search > 0:
        hq = max(2, int(0.7 * hs))
        win, ins = cut_windows(frame, base, hq + search + 1)
        offs, _ = qs_coarse(win, hq, search)
        inside &= ins
        start = base + offs
    else:
        start = np.where(ok[:, None], xy0, 0.0)
    base = np.rint(start).astype(np.int64)
    half = int(np.ceil(rfit + 1.5))
    win, ins = cut_windows(frame, base, half)
    inside &= ins
    g = np.arange(-half, half + 1, dtype=np.float64)
    mask = (g[None, :] ** 2 + g[:, None] ** 2) <= rfit ** 2
    p = np.zeros((m, N_PARAMS))
    p[:, :2] = start - base
    if params is not None:
        p[:, 2:] = params[:, 2:]
        p[:, _A + 1:_A + 3] = 0.0  # planar terms are relative to the window: start flat
        p[:, _B + 1:_B + 3] = 0.0
    else:
        p[:, 3:5] = _edge_widths(win)
    # levels from the data: mean, and the checker's signed half-contrast
    sx = np.sign(g[None, None, :] - p[:, 0, None, None])
    sy = np.sign(g[None, :, None] - p[:, 1, None, None])
    n = mask.sum()
    p[:, _A] = (win * mask).sum(axis=(1, 2)) / n
    p[:, _B] = ((win - p[:, _A, None, None]) * sx * sy * mask).sum(axis=(1, 2)) / n
    if params is not None:  # keep the known polarity if the guess is poor
        p[:, _B] = np.where(np.sign(p[:, _B]) == np.sign(params[:, _B]), p[:, _B], params[:, _B])
    p, rms = _fit(win, rfit, g, p, n_iter)
    xy = base + p[:, :2]
    bad = ~inside | ~np.isfinite(xy).all(axis=1) | (np.abs(p[:, :2]) > half).any(axis=1)
    xy[bad] = np.nan
    return QsFit(xy, p[:, 2].copy(), p[:, 3:5].copy(), p[:, _B].copy(), rms, inside, p)
