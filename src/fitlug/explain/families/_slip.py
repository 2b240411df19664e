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
the refitted model's fastest cruise v_c (:func:`cruise_speed`; stated with the term and in
fit.json's slip) and zero acceleration, s0 + sum_k c_k (v_c / v_ref)^k, with its error
from the joint covariance of
the fit and the term (:func:`._extend.extended`). The term is refitted exactly, not
linearised (:func:`._exact.refine`): the slip changes by several per cent of itself.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ...model import slip_law
from .._criterion import BIC_THRESHOLD, MIN_SHARE_REMOVED
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
        v_ref = cruise_speed(v_rows, ctx.a, ctx.valid)
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
        found, refined = _exactly(ctx, proj, found, cols, v_ref, ds)
        form, n, fitted = found[0]
        # the headline's speed: the cruise of the refitted model (the base fit's speed is
        # pulled by the misfit: 120.2 mm/s on a 120.0 mm/s cruise)
        v_head = _cruise_at(ctx, refined[(form, n)][0]) if (form, n) in refined else v_ref
        s_rest = None
        if (form, n) in refined:
            from ._extend import params_at

            s_rest = float(params_at(ctx.res, refined[(form, n)][0])["s0"])
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
            g = float(g_of(v_head, c))
            params.update({"v_ref_mm_s": v_head, "slip_change_at_v_ref": g,
                           "slip_at_rest_linear": s_rest if s_rest is not None
                           else s_ref - g})
            grow = "grows" if g > 0 else "falls"
            # the refitted law's slip at rest (else: the base fit's is near the cruise's)
            rest = s_rest if s_rest is not None else s_ref - g
            text = (f"the slip {grow} with speed, by {abs(g):.2g} ({abs(100 * g / rest):.2g} % "
                    f"of the slip at rest) at {v_head:.0f} mm/s")
            text += (": in proportion to the traction, as lug tips dragging or a rubber "
                     "stiffness that depends on the rate would" if form == "Fv" else
                     ": a rolling resistance that grows with speed (C_rr(v), "
                     f"{(rest + g) / rest:.3g} times its value at rest here), a drag of the "
                     "lug tips or a rate-dependent rubber")
            text += f"; the headline slip is the steady slip at {v_head:.1f} mm/s"
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
        # d headline slip / d c: the slip change at v_head and zero acceleration
        h = (v_head / v_ref) ** np.arange(1, n + 1) if form != "F" else np.zeros(n)
        sel_x = sel & (ctx.axis == 0) & (ctx.role == 0)
        return Choice(cls.name, coord, fitted, names(ctx, sel), "x", None, None, g_of, xs,
                      "slip change", unit, describe,
                      label=f"{_FORM_TEXT[form]}, {n} power(s)", ambiguity=amb,
                      rows=sel_x if sel_x.any() else sel, row_coord=v_rows,
                      row_coord_name="body speed (mm/s), lug x",
                      exact=_exact(ctx.res, form, v_ref, ds),
                      extra={"slip_headline": h, "v_ref_mm_s": v_head,
                             "slip_law": {"form": form, "v_ref_mm_s": v_ref, "ds": ds,
                                          "v_headline_mm_s": v_head if form != "F" else None},
                             "exact_first": True, "refined": refined.get((form, n))})


#: a row is at cruise where its |a| is below this share of the largest |a| in view
CRUISE_ACCELERATION = 0.03


def cruise_speed(v, a, valid) -> float:
    """The speed (mm/s) at which the headline slip is stated: the median speed of the
    fastest plateau in view (rows whose |a| is below CRUISE_ACCELERATION of the largest,
    within 1 % of the fastest of them), else the median within 1 % of the top speed. The
    median of all speeds within 1 % of the top put it at 120.4 mm/s on a 120.0 mm/s cruise
    (a spline's overshoot at the end of the ramp)."""
    v, a = np.abs(v), np.abs(a)
    top = float(np.max(v[valid], initial=0.0))
    calm = valid & (a <= CRUISE_ACCELERATION * float(np.max(a[valid], initial=0.0))) \
        & (v >= 0.5 * top)
    if calm.sum() >= 20:
        fast = calm & (v >= 0.99 * float(np.max(v[calm])))
        return float(np.median(v[fast]))
    return float(np.median(v[valid & (v >= 0.99 * top)]))


#: the forms refitted exactly before one is chosen: the best size of each form by the
#: linear step, and the one-power forms
EXACT_CANDIDATES = 5


def _cruise_at(ctx, flat) -> float:
    """:func:`cruise_speed` of the model of `ctx`'s fit at parameters `flat`, over the
    recording's span."""
    from ...model import integrate
    from ._extend import params_at

    p = {k: jnp.asarray(v, float) for k, v in params_at(ctx.res, flat).items()}
    v = np.asarray(integrate(p, ctx.res.problem.lay)[2])
    t_lo, t_hi = float(np.min(ctx.t[ctx.valid])), float(np.max(ctx.t[ctx.valid]))
    inside = (ctx.grid >= t_lo) & (ctx.grid <= t_hi)
    return cruise_speed(v, np.gradient(v, ctx.grid), inside)


def _exactly(ctx, proj, found, cols, v_ref, ds):
    """`found` [(form, n, Fitted)] re-ranked by the exact refit of the best size of each
    form and of the one-power forms (their chi^2 removed and Delta BIC from the refit):
    at a fit far off, the linear step ranks the forms wrongly (a rolling resistance linear
    in the speed, s_lin + c v: the linear step chose (s_lin / s0) g(v) with three powers,
    chi^2/dof 1.13 after its refit, where one power of g(v) reaches 1.0). Returns (found
    re-sorted, {(form, n): refine's answer})."""
    import dataclasses

    from ._exact import refine

    if proj.Js.shape[1] != len(ctx.res.flat):  # a second term: the first's columns in proj
        return found, {}
    chi2_0 = float(ctx.r[ctx.valid] @ ctx.r[ctx.valid])
    best = found[0][2]
    if not (best.delta_bic < BIC_THRESHOLD
            and best.dchi2 >= MIN_SHARE_REMOVED * (chi2_0 - ctx.res.dof)):
        return found, {}  # no form earns its place: the exact refits would not change that
    pick = []
    for form in FORMS:
        best = [q for q in found if q[0] == form]
        for q in best[:1] + [q for q in best if q[1] == 1]:
            if q not in pick:
                pick.append(q)
    pick = sorted(pick, key=lambda q: q[2].delta_bic)[:EXACT_CANDIDATES]
    out, refined = [], {}
    for form, n, f in found:
        if (form, n, f) not in pick:
            continue
        got = refine(proj, ctx, f.B, f.c, _exact(ctx.res, form, v_ref, ds), np.arange(n))
        r = got[2]
        dchi2 = chi2_0 - float(r[ctx.valid] @ r[ctx.valid])
        if not np.isfinite(dchi2):
            continue
        refined[(form, n)] = got
        out.append((form, n, dataclasses.replace(
            f, dchi2=dchi2, delta_bic=f.delta_bic + f.dchi2 - dchi2)))
    if not out:
        return found, refined
    return sorted(out, key=lambda q: q[2].delta_bic), refined


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
