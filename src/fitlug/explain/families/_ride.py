"""Ground profile, the frame riding the bump exactly (modes "frame" and "frame_own" of
:mod:`._ground`): the frame's heave and pitch from the wheels' lift, applied as an exact
rotation (not its first order) to the body markers and the lug markers off the ground,
the bottom-run lugs lifted by the profile. A 2 mm bump 150 mm wide pitches the frame by
19 mrad: the rotation's second order (70 mm x theta^2 / 2, 12 um) left chi^2/dof 2.4 to
the linear term and drew a second one.

The spline bases are evaluated at the base fit's places (the wheels' and the lugs' ground
x) and moved to the refitted ones by their derivative: a base fit pulled 1 mm off in X by
the bump's misfit put the wheels' lift 40 um (10 sigma) off on the bump's 0.04 flank.
"""

from __future__ import annotations

import jax.numpy as jnp

from ...fit._residuals import _weighted
from ...model import positions, sampled_kinematics
from ...model._model import ctx_of
from ...model._path import stadium
from ._base import bspline_on
from ._exact import _exact_fn, _model_of


def ride_residuals(ctx, breaks, mode: str):
    """(flat, c) -> weighted residuals of the fit's model with the profile of coefficients
    c (the ground's, then in "frame_own" the wheels' lift) exactly."""
    res = ctx.res
    lay, obs, params_at = _model_of(res)
    n_l, n_b = lay.lug_t.shape[0], lay.body_t.shape[0]
    nb = len(breaks) + 2
    D = ctx.D
    sl, sb = slice(0, n_l), slice(2 * n_l, 2 * n_l + n_b)
    def at(x):  # (basis, its derivative in x) at x
        h = 0.01
        return (jnp.asarray(bspline_on(x, breaks)),
                jnp.asarray((bspline_on(x + h, breaks) - bspline_on(x - h, breaks)) / (2 * h)))

    x_l = ctx.x_ground[sl]
    Bg = at(x_l)
    mids = [ctx.X[sl] + ctx.x_off, ctx.X[sb] + ctx.x_off]
    Gf = [at(m + D / 2) for m in mids]
    Gr = [at(m - D / 2) for m in mids]

    def ride(x, y, X, p, k, cw):
        dm = X + p["x_off"] - mids[k]  # the wheels moved with the fit
        lf = Gf[k][0] @ cw + dm * (Gf[k][1] @ cw)
        lr = Gr[k][0] @ cw + dm * (Gr[k][1] @ cw)
        th = jnp.arcsin((lf - lr) / p["D"])
        ox, oy = X + p["x_off"], p["y_off"]
        qx, qy = x - ox, y - oy
        c, s = jnp.cos(th), jnp.sin(th)
        return ox + c * qx - s * qy, oy + 0.5 * (lf + lr) + s * qx + c * qy

    def fn(flat, c):
        p = params_at(flat)
        Xl, psil, Xb, psib = sampled_kinematics(p, lay)
        lx, ly, bx, by = positions(p, lay, Xl, psil, Xb, psib)
        cg = c[:nb]
        cw = c[nb:] if mode == "frame_own" else cg
        bottom = stadium(p["sigma0"][lay.lug_i] + psil, ctx_of(p, lay))[2] == 0
        rx, ry = ride(lx, ly, Xl, p, 0, cw)  # (lx: the lugs' ground x, no image map)
        lx = jnp.where(bottom, lx, rx)
        ly = jnp.where(bottom, ly + Bg[0] @ cg + (lx - x_l) * (Bg[1] @ cg), ry)
        bx, by = ride(bx, by, Xb, p, 1, cw)
        return _weighted((lx, ly, bx, by), obs)

    return _exact_fn(fn)
