"""Body surge: the body's position X -> X + Delta(t) for the body and everything it
carries, not for the belt's travel psi; Delta a free function of time (MODEL.md §2,
"Real tracks": the body is a mass on the lugs' shear springs and surges fore and aft at
its own frequency, a few Hz, as lugs touch down and lift off; content a smooth X(t) does
not follow). docs/readings.md reads it as §5's body motion in x.

What moves with the surge: the body markers by Delta(t); a lug marker off the ground by
Delta(t) (the belt runs round the body's wheels); a lug marker in contact by
h Delta(t) + (1 - h) Delta(t_e), t_e its lug's touch-down: the lug's tip holds on the
ground and the lug's shear takes up the surge (MODEL.md §2's marker height h and
relaxation tau, lug_shear: the shear is psi - X since touch-down, so it is exact in the
model's own terms), and after lift-off the shear's share relaxes with tau. Without the
marker's placement in the fit (h = 1) the lugs carry the surge whole.

Delta is a cubic B-spline in t, its breakpoints SPACINGS_S apart at most (content up to a
few Hz; a chain's chordal action at the lug-passing frequency, ~8 Hz on the reference
rig, is left out of reach). It is tried only where the model does not describe the path
(chi^2/dof above GROSS_CHI2: a contact-dynamics track); on a kinematic recording a free
function of time in the body's x would take up a part of any misfit.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ...model._host import kinematics_host
from .._criterion import GROSS_CHI2
from ._base import Choice, Family, best_size, bspline, names

#: the B-spline's breakpoint spacings tried (s); the lowest Delta BIC is kept
SPACINGS_S = (0.4, 0.2, 0.1)
#: least body-x samples in view
MIN_BODY_ROWS = 40


class BodySurge(Family):
    """Delta(t) = sum_k c_k B_k(t) added to the body's X, not to the belt's travel."""

    name = "body surge"

    @classmethod
    def applies(cls, part):
        return part.get("axis") == "x"

    @classmethod
    def fit(cls, ctx, proj, parts):
        body = (ctx.role == 1) & (ctx.axis == 0) & ctx.valid
        if body.sum() < MIN_BODY_ROWS:
            return None
        if not ctx.res.chi2_per_dof > GROSS_CHI2:
            return None
        lo, hi = float(np.min(ctx.t[body])), float(np.max(ctx.t[body]))
        if hi - lo < 2 * SPACINGS_S[0]:
            return None
        carried = _carried(ctx)
        builds = []
        for dt in SPACINGS_S:
            n_int = max(int(np.ceil((hi - lo) / dt)), 2)
            builds.append((n_int, _columns(ctx, carried, lo, hi, n_int), 0))
        found = best_size(proj, builds)
        if found is None:
            return None
        n_int, fitted = found
        xs = np.linspace(lo, hi, max(8 * n_int + 1, 201))
        lay = ctx.res.problem.lay
        smooth = _smooth_part(lay, xs, lo, hi, n_int)
        # the surge about the body's smooth motion: Delta less what the speed spline's X(t)
        # can hold (in a ramp its knots are 0.035-0.07 s apart, and there Delta and X
        # trade: the raw Delta of the reference engine run spans 61 mm, its part outside
        # the smooth motion 1.3 mm); at xs once (the shape's band evaluates it 400 times)
        at_xs = bspline(xs, lo, hi, n_int) - _smooth_rows(lay, xs) @ smooth

        def delta(x, c):
            x = np.asarray(x, float)
            M = at_xs if x is xs else bspline(x, lo, hi, n_int) - _smooth_rows(lay, x) @ smooth
            return M @ np.asarray(c)

        def describe(c):
            d = delta(xs, c)
            f = _peak_hz(xs, d)
            params = {"rms_mm": float(np.sqrt(np.mean(d * d))),
                      "peak_to_peak_mm": float(np.ptp(d)), "frequency_hz": f,
                      "breakpoint_spacing_s": (hi - lo) / n_int,
                      "coefficients": [float(v) for v in c]}
            text = (f"the body surges fore and aft on its lugs' shear springs, "
                    f"{params['peak_to_peak_mm']:.2g} mm peak to peak ({params['rms_mm']:.2g} "
                    f"mm rms) about its smooth motion" + (f", strongest at {f:.2g} Hz" if f else "")
                    + ": the body, a mass on the lugs in contact, moves on them as lugs touch "
                      "down and lift off, while the belt runs on round its wheels (MODEL.md "
                      "§2, real tracks)")
            return params, text

        spacing = (hi - lo) / n_int
        return Choice(cls.name, "t", fitted, names(ctx, ctx.axis == 0), "x", "body", None,
                      delta, xs, "mm", "s", describe,
                      label=f"B-spline in t, breakpoints {spacing:.2g} s apart",
                      rows=body, row_coord=ctx.t, row_coord_name="time (s), body x",
                      extra={"real_track": True})


def _smooth_rows(lay, t) -> np.ndarray:
    """(len(t), 1 + K): a constant and the speed spline's X(t) functions at t."""
    from ...model._model import integrated_basis_rows

    out = np.zeros((len(t), 1 + lay.n_coef))
    out[:, 0] = 1.0
    for sel, rows in integrated_basis_rows(lay, t):
        out[sel, 1:] = rows
    return out


def _smooth_part(lay, ts, lo, hi, n_int) -> np.ndarray:
    """(1 + K, m): least-squares coefficients, on the times ts, of each B-spline function
    of Delta in the smooth motion's functions (:func:`_smooth_rows`)."""
    A = _smooth_rows(lay, ts)
    return np.linalg.lstsq(A, bspline(ts, lo, hi, n_int), rcond=None)[0]


def _carried(ctx):
    """Per row: (d psi_lag / d Delta at the row's t, at its lug's touch-down t_e, at its
    lift-off t_l) as weights (a, b, c) with (t, t_e, t_l); see the module docstring."""
    p = ctx.res.params
    h = float(p["shear_h"]) if "shear_h" in p else 1.0
    tau = abs(float(p["shear_tau"])) if "shear_tau" in p else 0.0
    lug = ctx.role == 0
    lay = ctx.res.problem.lay
    psin = np.maximum.accumulate(np.asarray(ctx.psi_nodes, float))
    # the belt coordinate before the lag (ctx.u is the lagged one, a lug's shear of
    # several mm behind), as the model's lug_lag takes it: sigma0 + psi(t)
    psi_row = kinematics_host({k: jnp.asarray(v, float) for k, v in p.items()}, lay,
                              ctx.t)["psi"]
    lug_i = np.concatenate([np.asarray(lay.lug_i)] * 2
                           + [np.zeros(2 * len(np.asarray(lay.body_t)), int)])
    sigma = np.asarray(p["sigma0"], float)[lug_i] + psi_row
    u = np.where(lug, np.mod(sigma, ctx.pitch * float(lay.n_belt)), 0.0)
    t_e = np.interp(psi_row - u, psin, ctx.grid)
    t_l = np.minimum(np.interp(psi_row - u + ctx.D, psin, ctx.grid), ctx.t)
    on_run = lug & (u < ctx.D)
    decay = np.exp(-np.maximum(ctx.t - t_l, 0.0) / max(tau, 1e-6))
    # psi_lag = psi - (1 - h) d, d = (psi - X) - (psi_e - X(t_e)) on the run, relaxing
    # (S_l - S_e) exp(-dt / tau) after it: X -> X + Delta moves psi_lag by
    # (1 - h) (Delta(t) - Delta(t_e)) on the run, (1 - h) decay (Delta(t_l) - Delta(t_e)) off
    k = (1.0 - h) * np.where(on_run, 1.0, np.where(lug, decay, 0.0))
    return {"t_e": t_e, "t_l": np.where(on_run, ctx.t, t_l), "k": k}


def _columns(ctx, carried, lo, hi, n_int):
    Bt = bspline(ctx.t, lo, hi, n_int)
    lag = carried["k"][:, None] * (bspline(carried["t_l"], lo, hi, n_int)
                                   - bspline(carried["t_e"], lo, hi, n_int))
    B = ctx.dr_dX[:, None] * Bt + ctx.dr_dpsi[:, None] * lag
    return np.where(ctx.valid[:, None], B, 0.0)


def _peak_hz(t, d) -> float | None:
    """The strongest frequency of d(t) (uniform t) above 0.2 Hz, or None."""
    if len(t) < 8 or not np.any(d):
        return None
    dt = float(t[1] - t[0])
    spec = np.abs(np.fft.rfft(d * np.hanning(len(d)))) ** 2
    f = np.fft.rfftfreq(len(d), dt)
    ok = f > 0.2
    if not np.any(ok):
        return None
    return float(f[ok][np.argmax(spec[ok])])
