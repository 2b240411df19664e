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

from ._refine import cut_disc, cut_windows

N_PARAMS = 11  # x0, y0, θ, blur_u, blur_v, A, a_x, a_y, B, b_x, b_y
_A, _B = 5, 8  # offset plane and contrast plane start here


@dataclass
class QsFit:
    """Result of `refine_qs`, arrays over markers (M,): `xy` (M, 2) px (NaN when the
    window left the frame or the fit failed), `angle` (rad), `widths` (M, 2) blur across
    the two edges, px, `contrast` (half the light-dark difference, signed: > 0 when the
    top-left quadrant is light), `rms` (fit residual, grey levels), `inside` (bool),
    `params` (M, N_PARAMS) for warm starts (position in the frame, levels at the marker's
    centre), `dof` (M,) degrees of freedom of the residual (weighted pixels less the
    parameters: `rms` scatters by ~1/sqrt(2 dof) relative)."""

    xy: np.ndarray
    angle: np.ndarray
    widths: np.ndarray
    contrast: np.ndarray
    rms: np.ndarray
    inside: np.ndarray
    params: np.ndarray
    dof: np.ndarray | None = None


def _edge(u, b, derivatives=True):
    """A straight edge seen by the camera: a step blurred by two boxes - the pixel (1 px)
    and the blur across the edge (b px: motion blur and optics) - as a value in [-1, 1].

    u: (M, N) signed distance from the edge, px; b: (M, 1) blur width, px.
    Returns S, and with `derivatives` dS/du and dS/db (each (M, N)).
    """
    # the unit step convolved with two boxes: Σ ± (z)₊² / 2b over the four corners
    # z = u ± 1/2 ± b/2 (a piecewise quadratic ramp from -(1+b)/2 to (1+b)/2)
    hb = 0.5 * b
    z1 = np.maximum(u + (0.5 + hb), 0.0)
    z2 = np.maximum(u + (0.5 - hb), 0.0)
    z3 = np.maximum(u - (0.5 - hb), 0.0)
    z4 = np.maximum(u - (0.5 + hb), 0.0)
    inv = 1.0 / b
    e = (z1 * z1 - z2 * z2 - z3 * z3 + z4 * z4) * (0.5 * inv)
    if not derivatives:
        return 2.0 * e - 1.0
    du = (z1 - z2 - z3 + z4) * (2.0 * inv)
    db = (z1 + z2 - z3 - z4 - 2.0 * e) * inv
    return 2.0 * e - 1.0, du, db


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
        safe = np.where(den < 0, den, -1.0)
        return np.where(den < 0, np.clip(0.5 * (sm - sp) / safe, -0.5, 0.5), 0.0)

    fx = vertex(score[rows, iy_c, ix_c - 1], score[rows, iy_c, ix_c], score[rows, iy_c, ix_c + 1])
    fy = vertex(score[rows, iy_c - 1, ix_c], score[rows, iy_c, ix_c], score[rows, iy_c + 1, ix_c])
    fx = np.where(ix == ix_c, fx, 0.0)
    fy = np.where(iy == iy_c, fy, 0.0)
    return np.stack([off[ix] + fx, off[iy] + fy], axis=1), score[rows, iy, ix]


def _model(win, rfit, x, y, p, jacobian=True):
    """Weighted residuals (M, N), their Jacobian (M, N_PARAMS, N) (None unless asked for),
    the cost (M,) and the sum of the weights (M,), for pixels at offsets x, y (N,) from the
    window centre."""
    dx, dy = x - p[:, 0, None], y - p[:, 1, None]
    m = np.minimum(np.maximum(rfit + 0.5 - np.sqrt(dx * dx + dy * dy), 0.0), 1.0)
    c, s = np.cos(p[:, 2, None]), np.sin(p[:, 2, None])
    u, v = c * dx + s * dy, c * dy - s * dx
    gain = p[:, _B, None] + p[:, _B + 1, None] * x + p[:, _B + 2, None] * y
    base = p[:, _A, None] + p[:, _A + 1, None] * x + p[:, _A + 2, None] * y
    if not jacobian:
        prod = _edge(u, p[:, 3, None], False) * _edge(v, p[:, 4, None], False)
        res = (win - base - gain * prod) * m
        return res, None, (res * res).sum(axis=1), m.sum(axis=1)
    su, du, dbu = _edge(u, p[:, 3, None])
    sv, dv, dbv = _edge(v, p[:, 4, None])
    prod = su * sv
    res = (win - base - gain * prod) * m
    gm = gain * m
    a, b = gm * du * sv, gm * su * dv
    jac = np.empty((p.shape[0], N_PARAMS, x.size))
    jac[:, 0] = s * b - c * a
    jac[:, 1] = -(s * a + c * b)
    jac[:, 2] = v * a - u * b
    jac[:, 3] = gm * dbu * sv
    jac[:, 4] = gm * su * dbv
    jac[:, 5] = m
    jac[:, 6] = x * m
    jac[:, 7] = y * m
    jac[:, 8] = prod * m
    jac[:, 9] = x * jac[:, 8]
    jac[:, 10] = y * jac[:, 8]
    return res, jac, (res * res).sum(axis=1), m.sum(axis=1)


_SLOPES = np.array([_A + 1, _A + 2, _B + 1, _B + 2])  # the planes' slopes
EXTRA_STEPS = 3


def _fit(win, rfit, x, y, p, n_iter, prior=None, hold=False):
    """Levenberg-Marquardt on the checker model, all markers at once.

    p (M, N_PARAMS) is the start; returns the best parameters found and the residual RMS.
    The pixels are weighted by a soft disc of radius rfit centred on the current estimate:
    a window symmetric about the centre keeps whatever the model leaves unexplained (it is
    point-symmetric too) from pulling the centre. A step that raises the cost is undone
    and retried with more damping. prior: blur widths (M, 2) to stay near (those of the
    previous frame), held with a small fraction of the data's own weight so that a flat
    direction of the cost cannot wander off frame after frame. hold: keep the slopes of
    the offset and contrast planes at their start values (averaged over frames: fitted in
    one frame on the few pixels of a small checker they are noisy, and they correlate with
    the centre); the slopes this frame's data alone would give at the fitted centre (one
    Gauss-Newton step) come back as the third result (else the fitted ones).
    """
    diag = np.arange(N_PARAMS)
    lam = np.full(p.shape[0], 1e-3)
    best, best_cost = p, np.full(p.shape[0], np.inf)
    best_data = weight = hess = grad = pw = at = None
    moved = np.zeros(p.shape[0], dtype=bool)  # a step after the start was accepted
    it, extra = 0, 0
    while True:
        # a marker whose steps were all rejected gets up to EXTRA_STEPS more (its centre
        # would otherwise be its start)
        last = it >= n_iter and (moved.all() or extra >= EXTRA_STEPS or n_iter == 0)
        if it >= n_iter and not last:
            extra += 1
        it += 1
        # the last evaluation only checks the last step: no Jacobian needed
        res, jac, data_cost, w = _model(win, rfit, x, y, p, jacobian=not last)
        cost = data_cost
        if prior is not None:
            dev = p[:, 3:5] - prior
            if pw is None:
                pw = 0.05 * np.einsum("mpn,mpn->mp", jac[:, 3:5], jac[:, 3:5])
            cost = cost + (pw * dev * dev).sum(axis=1)
        better = cost <= best_cost
        moved |= better & np.isfinite(best_cost)
        if last or not better.any():
            if better.any():
                best = np.where(better[:, None], p, best)
                best_data = np.where(better, data_cost, best_data)
                weight = np.where(better, w, weight)
            if last:
                break
        else:
            h = jac @ jac.transpose(0, 2, 1)
            gr = (jac @ res[:, :, None])[..., 0]
            if prior is not None:
                h[:, 3, 3] += pw[:, 0]
                h[:, 4, 4] += pw[:, 1]
                gr[:, 3:5] -= pw * dev
            if hess is None:
                best, best_data, weight, hess, grad = p, data_cost, w, h, gr
            else:
                best = np.where(better[:, None], p, best)
                best_data = np.where(better, data_cost, best_data)
                weight = np.where(better, w, weight)
                hess = np.where(better[:, None, None], h, hess)
                grad = np.where(better[:, None], gr, grad)
            at = best  # where hess and grad were taken
        best_cost = np.where(better, cost, best_cost)
        lam = np.where(better, 0.3 * lam, 10.0 * lam)
        damped = hess.copy()
        damped[:, diag, diag] *= 1.0 + lam[:, None]
        damped[:, diag, diag] += 1e-9
        g = grad.copy()
        if hold:
            damped[:, _SLOPES, :] = 0.0
            damped[:, :, _SLOPES] = 0.0
            damped[:, _SLOPES, _SLOPES] = 1.0
            g[:, _SLOPES] = 0.0
        step = np.linalg.solve(damped, g[..., None])[..., 0]
        # after a rejected step the next one is taken with the blur widths held: near their
        # lower bound (a still marker, no motion blur) the cost is flat in them, their
        # Gauss-Newton step is huge and its clip does not shrink with the damping, so every
        # step was rejected and the centre stayed at its start - the prediction from the
        # previous frames (frame-to-frame correlated errors: r1 ~ 0.15-0.5 for still or
        # slow checkers, seen as a structured misfit of the body markers in the fit)
        held = ~better
        if held.any():
            dh, gh = damped[held], g[held]
            for k in (3, 4):
                dh[:, k, :] = 0.0
                dh[:, :, k] = 0.0
                dh[:, k, k] = 1.0
                gh[:, k] = 0.0
            step[held] = np.linalg.solve(dh, gh[..., None])[..., 0]
        step[:, :2] = np.clip(step[:, :2], -1.0, 1.0)
        step[:, 3:5] = np.clip(step[:, 3:5], -0.25, 0.25)
        p = best + step
        p[:, 3:5] = np.clip(p[:, 3:5], 0.05, 8.0)
    dof = np.maximum(weight - N_PARAMS, 1)
    rms = np.sqrt(best_data / dof)
    slopes = best[:, _SLOPES].copy()
    if hold and hess is not None:
        # the gradient at the final parameters, linearised from where it was taken
        g = grad - (hess @ (best - at)[..., None])[..., 0]
        sub = hess[:, _SLOPES[:, None], _SLOPES[None, :]] + 1e-9 * np.eye(4)
        slopes += np.linalg.solve(sub, g[:, _SLOPES, None])[..., 0]
    return best, rms, slopes, dof


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
              search: int = 2, n_iter: int = 4, hold_slopes: bool = False) -> QsFit:
    """Centres of QS markers near first guesses.

    frame: (H, W) grey image; xy0: (M, 2) first guesses px; half_size: half the side of
    the checkers, px, scalar or (M,); params: (M, N_PARAMS) results of the previous frame
    (warm start: angle, blur widths and levels), or None; search: ± range of the coarse
    search, px (0: trust xy0 and skip it); hold_slopes: keep the lighting's slopes across
    the checker (offset and contrast planes) at those of `params` (their average along a
    track: a small checker's own are noisy), returning in `params` the slopes this frame
    alone gives, for that average. The fit uses the pixels of the largest disc
    inside the checker that the blur of its outer edge does not reach.
    """
    xy0 = np.asarray(xy0, dtype=np.float64).reshape(-1, 2)
    m = xy0.shape[0]
    ok = np.isfinite(xy0).all(axis=1)
    hs = np.broadcast_to(np.asarray(half_size, dtype=np.float64), (m,))
    base = np.where(ok[:, None], np.rint(xy0), 0).astype(np.int64)
    inside = ok.copy()
    if search > 0:
        hq = max(2, int(0.7 * hs.min()))
        win, ins = cut_windows(frame, base, hq + search + 1)
        offs, _ = qs_coarse(win, hq, search)
        inside &= ins
        start = base + offs
    else:
        start = np.where(ok[:, None], xy0, 0.0)
    base = np.rint(start).astype(np.int64)
    p = np.zeros((m, N_PARAMS))
    p[:, :2] = start - base
    if params is None:
        sq, _ = cut_windows(frame, base, max(5, int(0.5 * hs.min())))
        p[:, 3:5] = _edge_widths(sq)
    else:  # levels come at the marker's centre: refer them to this window's centre
        p[:, 2:] = params[:, 2:]
        p[:, _A] -= p[:, _A + 1] * p[:, 0] + p[:, _A + 2] * p[:, 1]
        p[:, _B] -= p[:, _B + 1] * p[:, 0] + p[:, _B + 2] * p[:, 1]
    rfit = np.maximum(hs - 1.0 - 0.5 * p[:, 3:5].max(axis=1) - 0.25, 2.5)[:, None]
    win, x, y, ins = cut_disc(frame, base, float(rfit.max()) + 1.25)
    inside &= ins
    if params is None:  # levels from the data: mean, and the checker's signed half-contrast
        mask = ((x - p[:, :1]) ** 2 + (y - p[:, 1:2]) ** 2 <= rfit ** 2).astype(np.float64)
        n = mask.sum(axis=1)
        p[:, _A] = (win * mask).sum(axis=1) / n
        sign = np.sign(x - p[:, :1]) * np.sign(y - p[:, 1:2])
        p[:, _B] = ((win - p[:, _A, None]) * sign * mask).sum(axis=1) / n
    hold = hold_slopes and params is not None
    p, rms, slopes, dof = _fit(win, rfit, x, y, p, n_iter, None if params is None else params[:, 3:5],
                          hold=hold)
    xy = base + p[:, :2]
    bad = ~inside | ~np.isfinite(xy).all(axis=1) | (np.abs(p[:, :2]) > 2).any(axis=1)
    xy[bad] = np.nan
    out = p.copy()  # levels at the marker's centre, position in the frame: for warm starts
    out[:, :2] = xy
    out[:, _A] += p[:, _A + 1] * p[:, 0] + p[:, _A + 2] * p[:, 1]
    out[:, _B] += p[:, _B + 1] * p[:, 0] + p[:, _B + 2] * p[:, 1]
    out[:, _SLOPES] = slopes
    return QsFit(xy, p[:, 2].copy(), p[:, 3:5].copy(), out[:, _B].copy(), rms, inside, out, dof)
