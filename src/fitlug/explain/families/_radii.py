"""Path shape, arc radii per wheel (MODEL.md §5): the front and rear wheels differ in pitch
radius, R_f = R + dR/2 and R_r = R - dR/2.

Both wheels stand on the ground (the bottom run level), so their centres are at heights
R_r and R_f, D apart. The top run is the belts' second common tangent, the mirror image of
the ground line in the line of centres: tilted by 2 alpha, tan alpha = dR / D, and D long
like the bottom run; the rear wheel is wrapped over pi - 2 alpha, the front over
pi + 2 alpha, so the belt's length is P = 2 D + R_r (pi - 2 alpha) + R_f (pi + 2 alpha).
A radial offset on the arcs (:mod:`._path`) cannot make this: the arcs' lengths change
(each lug reaches the top run at another belt travel) and the top run tilts by 2 dR / D
(a 3 mm difference on a 117 mm span: 51 mrad, 3 mm at the run's ends).

The term is the path itself with dR, exact (:func:`._exact.refine` refits it with the
fit's R, D, e and the phases), its linear column d r / d dR at dR = 0 for the criterion.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ...fit._residuals import _weighted
from ...model import sampled_kinematics
from ...model._model import CATALOG, _hook, ctx_of
from ._base import Choice
from ._exact import _exact_fn, _model_of

NAME = "path shape"


def path_radii(sigma, R, D, e, dR, top_dy=None, bottom_dy=None):
    """(path_x, path_y) of belt coordinate `sigma` for wheels of pitch radii R -+ dR/2
    (rear, front), marker offset e (JAX); dR = 0 is MODEL.md §2's stadium."""
    R_r, R_f = R - dR / 2, R + dR / 2
    al = jnp.arctan2(dR, D)
    wr, wf = jnp.pi - 2 * al, jnp.pi + 2 * al
    P = 2 * D + R_r * wr + R_f * wf
    u = jnp.mod(sigma, P)
    b1, b2, b3 = D, D + R_r * wr, 2 * D + R_r * wr
    seg = jnp.where(u < b1, 0, jnp.where(u < b2, 1, jnp.where(u < b3, 2, 3)))
    c2, s2 = jnp.cos(2 * al), jnp.sin(2 * al)
    phi_r = (u - b1) / R_r
    phi_f = -2 * al + (u - b3) / R_f
    q = u - b2  # along the top run from the rear wheel
    x = jnp.select([seg == 0, seg == 1, seg == 2],
                   [D / 2 - u, -D / 2 - (R_r + e) * jnp.sin(phi_r),
                    -D / 2 - R_r * s2 + q * c2 - e * s2],
                   D / 2 + (R_f + e) * jnp.sin(phi_f))
    y_bottom = -e + (0.0 if bottom_dy is None else bottom_dy(jnp.clip(u, 0.0, D)))
    y_top = R_r + R_r * c2 + q * s2 + e * c2 + (
        0.0 if top_dy is None else top_dy(jnp.clip(q / D, 0.0, 1.0)))
    y = jnp.select([seg == 0, seg == 1, seg == 2],
                   [y_bottom, R_r - (R_r + e) * jnp.cos(phi_r), y_top],
                   R_f + (R_f + e) * jnp.cos(phi_f))
    return x, y


def _positions(p, lay, Xl, psil, Xb, psib, dR):
    """fitlug.model.positions with the wheels' radii R -+ dR/2."""
    ctx = ctx_of(p, lay)
    top, bottom = _hook(lay, "top_dy"), _hook(lay, "bottom_dy")
    top_dy = (lambda xi: sum(f(p, xi, ctx) for f in top)) if top else None
    bottom_dy = (lambda u: sum(f(p, u, ctx) for f in bottom)) if bottom else None
    px, py = path_radii(p["sigma0"][lay.lug_i] + psil, p["R"], p["D"], p["e"], dR, top_dy,
                        bottom_dy)
    lx, ly = Xl + p["x_off"] + px, p["y_off"] + py
    cx = p["cx"][lay.body_j]
    bx, by = Xb + cx, p["cy"][lay.body_j]
    for f in _hook(lay, "body_dy"):
        by = by + f(p, psib, cx, ctx)
    for eff in sorted((CATALOG[e] for e in lay.effects if CATALOG[e].image is not None),
                      key=lambda c: c.order):
        lx, ly = eff.image(p, lx, ly, True)
        bx, by = eff.image(p, bx, by, False)
    return lx, ly, bx, by


def radii_residuals(res):
    """(flat, c) -> weighted residuals of `res`'s model with dR = c[0] (JAX, with its exact
    Jacobian, as :func:`._exact.refine` takes it)."""
    lay, obs, params_at = _model_of(res)

    def fn(flat, c):
        p = params_at(flat)
        return _weighted(_positions(p, lay, *sampled_kinematics(p, lay), c[0]), obs)

    exact = _exact_fn(fn)
    # one compiled program (called eagerly, each of its operations compiled on its own:
    # ~110 programs, seconds, per recording)
    column = jax.jit(lambda flat: jax.jvp(lambda c: fn(flat, c), (jnp.zeros(1),),
                                          (jnp.ones(1),))[1])
    exact.column = lambda flat: np.asarray(column(jnp.asarray(flat, float)))
    return exact


def radii_choice(ctx, proj, sel) -> Choice | None:
    """The arc radii term at the fit of `ctx` (rows `sel`: the lug markers), or None."""
    exact = radii_residuals(ctx.res)
    B = np.where(ctx.valid, exact.column(ctx.res.flat), 0.0)[:, None]
    if not np.any(B):
        return None
    return _choice(ctx, proj.fit(B, 0), sel, exact, ctx.R, ctx.D)


def _choice(ctx, fitted, sel, exact, R, D):
    """The term's Choice read with the mean pitch radius R and the span D (mm)."""
    xs = np.linspace(0.0, 1.0, 41)

    def shape(x, c):  # the pitch line's height change along the top run
        al = np.arctan2(float(c[0]), D)
        return (R - c[0] / 2) * (1 + np.cos(2 * al)) + np.asarray(x) * D * np.sin(2 * al) \
            - 2 * R

    def describe(c):
        d = float(c[0])
        tilt = 2 * np.arctan2(d, D)
        params = {"delta_R_mm": d, "R_front_mm": R + d / 2, "R_rear_mm": R - d / 2,
                  "top_run_tilt_mrad": float(1000 * tilt), "span_mm": D}
        big = "front" if d > 0 else "rear"
        text = (f"the front and rear wheels differ in pitch radius by {abs(d):.3g} mm (front "
                f"{R + d / 2:.3g} mm, rear {R - d / 2:.3g} mm): the top run climbs "
                f"{abs(1000 * tilt):.3g} mrad towards the {big} wheel and the belt wraps "
                f"the {big} wheel over more than a half turn")
        return params, text

    return Choice(NAME, "wheel", fitted, [ctx.markers[i] for i in np.unique(ctx.marker[sel])],
                  None, "arcs", None, shape, xs, "mm (top run's pitch line)",
                  "0 rear wheel, 1 front wheel", describe,
                  label="arc radii per wheel (front and rear pitch radius)", rows=sel,
                  row_coord=np.nan_to_num(ctx.u), row_coord_name="belt coordinate u (mm)",
                  ambiguity=("a wheel's pitch radius measured on the rig would tell it from "
                             "a top run held tilted by a guide"), exact=exact,
                  extra={"exact_first": True, "at_final": lambda final: _choice(
                      ctx, fitted, sel, exact, float(final.params["R"]),
                      float(final.params["D"]))})
