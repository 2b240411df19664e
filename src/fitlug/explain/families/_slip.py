"""Slip law: s = s_lin + g(.) in place of the linear law s_lin = 2F/(k n L) (MODEL.md §5;
lug_sliding is its catalog case, a law in F alone that saturates).

The slip moves the belt travel only, d psi / dt = v / (1 - s), so a change g of the slip
moves psi by int v g / (1 - s)^2 dt, and the term's columns are that through the fit's
d r / d psi. Three forms, each a polynomial without a constant (a constant is s0 itself,
and at rest, v = 0, the slip moves nothing):

- in the speed v:              g = sum_k c_k (|v| / v_ref)^k             (k = 1..n)
- in traction and speed (F,v): g = (s_lin / s0) sum_k c_k (|v| / v_ref)^k (slip growing in
  proportion to the elastic slip: drag of the lug tips, a rate-dependent rubber);
- in the traction F:           g = sum_k c_k ((s_lin - s0) / ds)^(k+1)   (a law bending away
  from the straight line, not the catalog's saturating one).

v_ref is the highest body speed in view (the recording's cruise when it is seen). With a
law in the speed the steady slip depends on the speed: the headline slip is the one at
v_ref and zero acceleration, s0 + sum_k c_k, with its error from the joint covariance of
the fit and the term (:func:`._extend.extended`). The term is refitted exactly, not
linearised (:func:`._exact.refine`): the slip changes by several per cent of itself.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ...model import slip_law
from ._base import Choice, Family, names
from ._exact import residuals_with

MAX_POWER = 3
#: the forms: name -> coordinate
FORMS = {"v": "v", "Fv": "F,v", "F": "F"}
#: Delta BIC below which two forms are called indistinguishable
AMBIGUOUS_DBIC = 10.0


class SlipLaw(Family):
    """g(v), (s_lin / s0) g(v) or g(F) added to the linear slip law."""

    name = "slip law"

    @classmethod
    def applies(cls, part):
        return part.get("axis") == "x"

    @classmethod
    def fit(cls, ctx, proj, parts):
        sel = ctx.valid & (ctx.dr_dpsi != 0)
        if sel.sum() < 20:
            return None
        v_abs = np.abs(ctx.v_nodes)
        v_rows = np.interp(ctx.t, ctx.grid, v_abs)
        v_top = float(np.max(v_rows[ctx.valid], initial=0.0))
        if not v_top > 0:
            return None
        # the cruise: the median speed within 1 % of the top (a spline's ringing at the end
        # of a ramp would otherwise set it), the top itself when no plateau is in view
        v_ref = float(np.median(v_rows[ctx.valid & (v_rows >= 0.99 * v_top)]))
        vt = np.where(ctx.vt_nodes == 0, 1.0, ctx.vt_nodes)
        s_ref = float(ctx.res.quantities["slip"].value)
        s = np.where(ctx.vt_nodes == 0, s_ref, 1.0 - ctx.v_nodes / vt)
        ds = float(np.max(np.abs(s - s_ref)[v_abs > 0.05 * v_ref], initial=0.0))
        gain = ctx.v_nodes / (1.0 - s) ** 2  # d (d psi / dt) / d s
        u = v_abs / v_ref

        def basis(form, n):
            if form == "v":
                return np.stack([u ** k for k in range(1, n + 1)], 1)
            if form == "Fv":
                return np.stack([(s / s_ref) * u ** k for k in range(1, n + 1)], 1)
            return np.stack([((s - s_ref) / ds) ** (k + 1) for k in range(1, n + 1)], 1)

        def cols(form, n):
            dpsi = ctx.cumulative(basis(form, n), gain)
            return np.where(ctx.valid[:, None], ctx.dr_dpsi[:, None] * dpsi, 0.0)

        found = []
        for form in FORMS:
            if form == "F" and not ds > 1e-9:
                continue
            for n in range(1, MAX_POWER + (0 if form == "F" else 1)):
                found.append((form, n, proj.fit(cols(form, n), 0)))
        if not found:
            return None
        found.sort(key=lambda q: q[2].delta_bic)
        form, n, fitted = found[0]
        rivals = [q for q in found if q[0] != form]
        close = [q for q in rivals if q[2].delta_bic - fitted.delta_bic < AMBIGUOUS_DBIC]
        coord = FORMS[form]
        unit = ("mm/s: the body speed v, at steady traction" if form != "F" else
                "traction change (fraction of the largest in view)")
        xs = np.linspace(0.0, v_ref, 41) if form != "F" else np.linspace(-1.0, 1.0, 41)

        def g_of(x, c):  # the slip change at zero acceleration (v forms), or at F (F form)
            x = np.asarray(x, float)
            if form == "F":
                return sum(c[k - 1] * x ** (k + 1) for k in range(1, n + 1))
            return sum(c[k - 1] * (x / v_ref) ** k for k in range(1, n + 1))

        def describe(c):
            params = {"form": _FORM_TEXT[form], "powers": n,
                      "coefficients": [float(q) for q in c]}
            if form == "F":
                dev = float(np.max(np.abs(g_of(xs, c))))
                params["largest_change"] = dev
                text = (f"the slip bends away from the straight line in the traction by up to "
                        f"{dev:.2g} over the tractions in view: the lugs stiffen or soften "
                        "with load")
                return params, text
            g = float(g_of(v_ref, c))
            params.update({"v_ref_mm_s": v_ref, "slip_change_at_v_ref": g,
                           "slip_at_rest_linear": s_ref})
            grow = "grows" if g > 0 else "falls"
            rest = s_ref - g  # the base fit's slip is near the one at cruise
            text = (f"the slip {grow} with speed, by {abs(g):.2g} ({abs(100 * g / rest):.2g} % "
                    f"of the slip at rest) at {v_ref:.0f} mm/s")
            text += (": in proportion to the traction, as lug tips dragging or a rubber "
                     "stiffness that depends on the rate would" if form == "Fv" else
                     ": a drag of the lug tips or a rate-dependent rubber")
            return params, text

        amb = ""
        if close:
            other = {q[0] for q in close}
            if form != "F" and "F" not in other:
                amb = ("this recording cannot tell a slip change proportional to the traction "
                       "from one at any traction; a recording under another drawbar pull "
                       "would")
            else:
                amb = ("this recording cannot tell a slip law in the speed from one in the "
                       "traction (they rise together in its ramps); a recording with a "
                       "gentler or steeper ramp, or at another cruise speed, would")
        h = np.ones(n) if form != "F" else np.zeros(n)  # d headline slip / d c
        sel_x = sel & (ctx.axis == 0) & (ctx.role == 0)
        return Choice(cls.name, coord, fitted, names(ctx, sel), "x", None, None, g_of, xs,
                      "slip change", unit, describe,
                      label=f"{_FORM_TEXT[form]}, {n} power(s)", ambiguity=amb,
                      rows=sel_x if sel_x.any() else sel, row_coord=v_rows,
                      row_coord_name="body speed (mm/s), lug x",
                      exact=_exact(ctx.res, form, v_ref, ds),
                      extra={"slip_headline": h, "v_ref_mm_s": v_ref,
                             "slip_law": {"form": form, "v_ref_mm_s": v_ref, "ds": ds}})


_FORM_TEXT = {"v": "s = s_lin + g(v)", "Fv": "s = s_lin (1 + g(v) / s0)",
              "F": "s = s_lin + g(F)"}


def _change(form: str, u, s_lin, s0, ds: float, c):
    """g for coefficients c at speeds u = |v| / v_ref and linear-law slips s_lin (numpy or
    JAX arrays alike: the exact refit differentiates it)."""
    k = np.arange(1, len(c) + 1)
    if form == "F":
        return (((s_lin - s0) / ds)[..., None] ** (k + 1)) @ c
    g = (u[..., None] ** k) @ c
    return g * (s_lin / s0) if form == "Fv" else g


def slip_change(law: dict, v, s_lin, s0: float) -> np.ndarray:
    """The term's slip change g at body speeds v (mm/s) where the linear law gives s_lin,
    s0 its steady slip; `law`: {"form", "v_ref_mm_s", "ds", "coefficients"} (a FitResult's
    robust["slip_term"]["law"]): what the report draws as the model's slip."""
    return _change(law["form"], np.abs(np.asarray(v, float)) / law["v_ref_mm_s"],
                   np.asarray(s_lin, float), s0, law["ds"],
                   np.asarray(law["coefficients"], float))


def _exact(res, form: str, v_ref: float, ds: float):
    """(flat, c) -> weighted residuals of `res`'s model with the slip term exactly."""
    lay = res.problem.lay

    def rates(p, v0, a0, c):
        s_lin = slip_law(p, lay, a0)
        s0 = slip_law(p, lay, jnp.asarray(0.0))
        return v0, v0 / (1.0 - (s_lin + _change(form, jnp.abs(v0) / v_ref, s_lin, s0, ds, c)))

    return residuals_with(res, rates)
