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

import functools
from dataclasses import dataclass

import numpy as np

from ._refine import _disc_offsets, cut_disc, cut_windows

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


# the four corners z = u + 1/2 + b/2, u + 1/2 - b/2, u - 1/2 + b/2, u - 1/2 - b/2
_CORNER_U = np.array([0.5, 0.5, -0.5, -0.5])[:, None]
_CORNER_B = np.array([0.5, -0.5, 0.5, -0.5])[:, None]
_SIGNS = np.array([1.0, -1.0, -1.0, 1.0])  # the four corners' signs
_SUMS = np.array([_SIGNS, [1.0, 1.0, -1.0, -1.0]])  # Σ ± z for dS/du, and for dS/db


def _edge(u, b, derivatives=True):
    """A straight edge seen by the camera: a step blurred by two boxes - the pixel (1 px)
    and the blur across the edge (b px: motion blur and optics) - as a value in [-1, 1].

    u: (..., N) signed distance from the edge, px; b: (..., 1) blur width, px.
    Returns S, and with `derivatives` dS/du and dS/db (each (..., N)).
    """
    # the unit step convolved with two boxes: Σ ± (z)₊² / 2b over the four corners
    # z = u ± 1/2 ± b/2 (a piecewise quadratic ramp from -(1+b)/2 to (1+b)/2); the four
    # corners as one array (..., 4, N)
    z = u[..., None, :] + (_CORNER_U + _CORNER_B * b[..., None])
    np.maximum(z, 0.0, out=z)
    inv = 1.0 / b
    e2 = (_SIGNS @ (z * z)) * inv  # twice the ramp in [0, 1]
    if not derivatives:
        return e2 - 1.0
    sums = _SUMS @ z  # (..., 2, N)
    du = sums[..., 0, :] * (2.0 * inv)
    db = (sums[..., 1, :] - e2) * inv
    return e2 - 1.0, du, db


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


# cos(θ - phase) gives the rotation [[cos θ, sin θ], [-sin θ, cos θ]] in one call
_ROT_PHASE = np.array([[0.0, 0.5 * np.pi], [-0.5 * np.pi, 0.0]])


def _model(win, rfit, xy, basis, p, jacobian=True):
    """Weighted residuals (M, N), their Jacobian (M, N_PARAMS, N) (None unless asked for),
    the cost (M,) and the sum of the weights (M,), for pixels at offsets xy (2, N) from the
    window centre; basis (3, N): 1, x, y of those pixels.

    Both edges and both planes are evaluated as one stacked array each (the arrays are
    small: the cost is in the number of numpy calls, not in their sizes)."""
    m_ = p.shape[0]
    d = xy - p[:, :2, None]  # (M, 2, N)
    m = np.sqrt(np.einsum("mkn,mkn->mn", d, d))
    np.subtract(rfit + 0.5, m, out=m)
    np.maximum(m, 0.0, out=m)
    np.minimum(m, 1.0, out=m)
    rot = np.cos(p[:, 2, None, None] - _ROT_PHASE)  # (M, 2, 2)
    uv = rot @ d  # u, v: along the two edges' normals
    planes = p[:, _A:, None].reshape(m_, 2, 3) @ basis  # offset and contrast planes
    base, gain = planes[:, 0], planes[:, 1]
    if not jacobian:
        sg = _edge(uv, p[:, 3:5, None], False)
        res = (win - base - gain * sg[:, 0] * sg[:, 1]) * m
        return res, None, np.einsum("mn,mn->m", res, res), m.sum(axis=1)
    sg, ds, db = _edge(uv, p[:, 3:5, None])
    prod = sg[:, 0] * sg[:, 1]
    res = (win - base - gain * prod) * m
    gm = (gain * m)[:, None]
    swap = sg[:, ::-1]  # (sv, su)
    ab = gm * ds * swap  # a = gm du sv, b = gm su dv
    jac = np.empty((m_, N_PARAMS, xy.shape[1]))
    # d/dx0, d/dy0: -(rotation transposed) (a, b); d/dθ: v a - u b
    np.matmul(-rot.transpose(0, 2, 1), ab, out=jac[:, 0:2])
    np.subtract(uv[:, 1] * ab[:, 0], uv[:, 0] * ab[:, 1], out=jac[:, 2])
    np.multiply(gm * db, swap, out=jac[:, 3:5])
    np.multiply(m[:, None], basis, out=jac[:, _A:_A + 3])
    np.multiply((prod * m)[:, None], basis, out=jac[:, _B:_B + 3])
    return res, jac, np.einsum("mn,mn->m", res, res), m.sum(axis=1)


_SLOPES = np.array([_A + 1, _A + 2, _B + 1, _B + 2])  # the planes' slopes
EXTRA_STEPS = 3
# held slopes: their rows and columns of the damped normal matrix zeroed, 1 on the diagonal
_FREE = np.ones(N_PARAMS)
_FREE[_SLOPES] = 0.0
_HOLD_KEEP = _FREE[:, None] * _FREE[None, :]
_SLOPE_BLOCK = (_SLOPES[:, None] * N_PARAMS + _SLOPES[None, :]).ravel()  # in a flat (11 x 11)
_RIDGE4 = 1e-9 * np.eye(4)
# bounds of a step (centre 1 px, blur widths 0.25 px) and of the blur widths
_STEP_HI = np.full(N_PARAMS, np.inf)
_STEP_HI[:2], _STEP_HI[3:5] = 1.0, 0.25
_STEP_LO = -_STEP_HI
_WIDTH_LO, _WIDTH_HI = np.full(N_PARAMS, -np.inf), np.full(N_PARAMS, np.inf)
_WIDTH_LO[3:5], _WIDTH_HI[3:5] = 0.05, 8.0


def _fit(win, rfit, xy, basis, p, n_iter, prior=None, hold=False):
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
    m_ = p.shape[0]
    lam = np.full(m_, 1e-3)
    best, best_cost = p, np.full(p.shape[0], np.inf)
    best_data = weight = hess = grad = pw = at = None
    moved = np.zeros(p.shape[0], dtype=bool)  # a step after the start was accepted
    it, extra = 0, 0
    while True:
        # the evaluations after the n_iter-th step only check it: no Jacobian needed
        last = it >= n_iter
        it += 1
        res, jac, data_cost, w = _model(win, rfit, xy, basis, p, jacobian=not last)
        cost = data_cost
        if prior is not None:
            dev = p[:, 3:5] - prior
            if pw is None:
                pw = 0.05 * np.einsum("mpn,mpn->mp", jac[:, 3:5], jac[:, 3:5])
            cost = cost + (pw * dev * dev).sum(axis=1)
        better = cost <= best_cost
        if it > 1:  # (the start's costs are all infinite: nothing moved yet)
            moved |= better & np.isfinite(best_cost)
        if last or not better.any():
            if better.any():
                best = np.where(better[:, None], p, best)
                best_data = np.where(better, data_cost, best_data)
                weight = np.where(better, w, weight)
            if last:
                # a marker whose steps were all rejected gets up to EXTRA_STEPS more, each
                # damped more (its centre would otherwise be its start; its normal equations
                # are still those of its start); the others stay where they are
                stuck = ~moved
                if n_iter == 0 or extra >= EXTRA_STEPS or not stuck.any():
                    break
                extra += 1
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
        damped = hess * _HOLD_KEEP if hold else hess.copy()
        dg = damped.reshape(m_, -1)[:, ::N_PARAMS + 1]  # the diagonal (a view)
        dg *= 1.0 + lam[:, None]
        dg += 1e-9
        if hold:
            dg[:, _SLOPES] = 1.0
            g = grad * _FREE
        else:
            g = grad.copy()
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
        if last:
            step[~stuck] = 0.0
        np.minimum(step, _STEP_HI, out=step)
        np.maximum(step, _STEP_LO, out=step)
        p = best + step
        np.maximum(p, _WIDTH_LO, out=p)
        np.minimum(p, _WIDTH_HI, out=p)
    dof = np.maximum(weight - N_PARAMS, 1)
    rms = np.sqrt(best_data / dof)
    slopes = best[:, _SLOPES].copy()
    if hold and hess is not None:
        # the gradient at the final parameters, linearised from where it was taken
        g = grad - (hess @ (best - at)[..., None])[..., 0]
        sub = hess.reshape(m_, -1)[:, _SLOPE_BLOCK].reshape(m_, 4, 4) + _RIDGE4
        slopes += np.linalg.solve(sub, g[:, _SLOPES, None])[..., 0]
    return best, rms, slopes, dof


@functools.lru_cache(maxsize=64)
def _offsets_basis(radius):
    """Offsets (2, N) of the pixels of `cut_disc`'s disc and the planes' basis (3, N): 1, x, y."""
    x, y = _disc_offsets(radius)[3:5]
    return np.stack([x, y]), np.stack([np.ones_like(x), x, y])


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
    hs = np.asarray(half_size, dtype=np.float64)
    hs = np.full(m, hs) if hs.ndim == 0 else hs.reshape(m)  # (not np.broadcast_to: slower)
    inside = ok.copy()
    if search > 0:
        base = np.where(ok[:, None], np.rint(xy0), 0).astype(np.int64)
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
        planes = p[:, _A:].reshape(m, 2, 3)  # (a view) both planes at once
        planes[:, :, 0] -= planes[:, :, 1] * p[:, :1] + planes[:, :, 2] * p[:, 1:2]
    rfit = np.maximum(hs - 1.0 - 0.5 * p[:, 3:5].max(axis=1) - 0.25, 2.5)[:, None]
    reach = np.ceil((float(rfit.max()) + 1.25) * 4.0) / 4.0
    win, x, y, ins = cut_disc(frame, base, reach)
    xy_b, basis = _offsets_basis(reach)
    inside &= ins
    if params is None:  # levels from the data: mean, and the checker's signed half-contrast
        mask = ((x - p[:, :1]) ** 2 + (y - p[:, 1:2]) ** 2 <= rfit ** 2).astype(np.float64)
        n = mask.sum(axis=1)
        p[:, _A] = (win * mask).sum(axis=1) / n
        sign = np.sign(x - p[:, :1]) * np.sign(y - p[:, 1:2])
        p[:, _B] = ((win - p[:, _A, None]) * sign * mask).sum(axis=1) / n
    hold = hold_slopes and params is not None
    prior = None if params is None else params[:, 3:5]
    p, rms, slopes, dof = _fit(win, rfit, xy_b, basis, p, n_iter, prior, hold=hold)
    xy = base + p[:, :2]
    bad = ~inside | ~np.isfinite(xy).all(axis=1) | (np.abs(p[:, :2]) > 2).any(axis=1)
    xy[bad] = np.nan
    out = p.copy()  # levels at the marker's centre, position in the frame: for warm starts
    out[:, :2] = xy
    planes = out[:, _A:].reshape(m, 2, 3)
    planes[:, :, 0] += planes[:, :, 1] * p[:, :1] + planes[:, :, 2] * p[:, 1:2]
    out[:, _SLOPES] = slopes
    return QsFit(xy, p[:, 2].copy(), p[:, 3:5].copy(), out[:, _B].copy(), rms, inside, out, dof)
