"""The fit extended by its kept family terms, as a :class:`fitlug.fit.FitResult`.

The terms' coefficients c (covariance C, marginal over the fit's parameters) and the fit's
parameters moved with them (d = -J^+ (r + B c)): the residuals are evaluated exactly at the
moved parameters plus the terms (B c); the fit's covariance gains K C K^T, K = J^+ B (the
block inverse of the extended normal matrix), and every derived quantity (slip, dl', k/m,
C_rr) is recomputed with it, so its error carries the terms' uncertainty. `robust` records
the extended covariance so that the posterior is stretched to it (fitlug.posterior).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ...fit import FitResult
from ...fit._residuals import residuals_host
from ...fit._result import compute_quantities


def extended(res, ctx, proj, B: np.ndarray, c: np.ndarray, C: np.ndarray,
             k_extra: int, flat=None, r=None, slip_h=None) -> FitResult:
    """`res` with terms of columns B (S, m), coefficients c and their covariance C;
    `proj` the :class:`._solve.Projector` of `res`; `k_extra` parameters counted
    (coefficients and free frequencies); `flat`, `r`: the fit's parameters and the
    residuals when an exact term was refitted (:func:`._exact.refine`); `slip_h` (m,):
    d headline slip / d c where a term changes the steady slip (a slip law in the speed:
    the headline is then the slip at the term's reference speed, see :func:`_slip_moved`)."""
    K = proj.solve(B)
    if flat is None:
        flat = np.asarray(res.flat, float) - proj.solve(ctx.r + B @ c)
    cov = np.asarray(res.cov, float) + K @ C @ K.T
    prob = res.problem
    packing = res.packing
    fixed = {k: jnp.asarray(v, float) for k, v in res.params.items() if k not in packing.names}
    p = params_at(res, flat)
    if r is None:
        r = residuals_host({k: jnp.asarray(v) for k, v in p.items()}, prob.lay,
                           prob.obs) + B @ c
    chi2 = float(r @ r)
    fixed_np = {k: np.asarray(v) for k, v in fixed.items()}
    q = compute_quantities(p, packing, flat, cov, prob.lay, prob.rig.mass_kg, fixed_np,
                           prob.rig.drawbar_pull_N)
    slip_term = None
    if slip_h is not None and np.any(slip_h):
        q, slip_term = _slip_moved(q, p, packing, flat, cov, K, C, c, slip_h, prob, fixed_np)
    std = {k: e.std for k, e in q.items()}
    robust = {"method": "family term", "clusters": None, "cov": cov,
              "covs": {"family term": (cov, None)}, "robust_std": std,
              "naive_std": {k: e.std for k, e in res.quantities.items()},
              "headline": True, "label": "least squares, family term marginalised",
              "uncertainty_method": ("least squares under the model extended by the family "
                                     "term(s), their uncertainty included"),
              "slip_term": slip_term}
    return FitResult(problem=prob, params=p, packing=packing, flat=flat, cov=cov,
                     residuals=r, chi2=chi2, dof=int(res.dof - k_extra),
                     converged=res.converged, steps=res.steps, quantities=q, robust=robust)


def params_at(res, flat) -> dict:
    """`res`'s parameters (numpy, its order) with the packed ones at `flat`."""
    packing = res.packing
    p = {**{k: np.asarray(v) for k, v in res.params.items() if k not in packing.names},
         **{k: np.asarray(v) for k, v in packing.unpack(jnp.asarray(flat), {}).items()}}
    return {k: p[k] for k in res.params}


def _slip_moved(q, p, packing, flat, cov, K, C, c, h, prob, fixed_np):
    """The headline slip moved by a term h . c, its variance from the joint covariance of
    the fit and the term: Var(slip) + h' C h + 2 Cov(slip, h' c), Cov(flat, c) = -K C
    (the block inverse). Returns (quantities, what the posterior needs to draw the term
    beside its samples: value, variance, covariance with the steady slip, its variance)."""
    import dataclasses

    from ...fit._result import _derived_with_jacobian

    fixed = {k: jnp.asarray(v, float) for k, v in fixed_np.items()}
    mass, pull = prob.rig.mass_kg, prob.rig.drawbar_pull_N
    _, jac = _derived_with_jacobian(jnp.asarray(flat, float), packing, fixed, prob.lay,
                                    jnp.asarray(mass or 0.0, float),
                                    jnp.asarray(pull or 0.0, float), mass is not None,
                                    bool(pull))
    gs = np.asarray(jac["slip"], float)
    var_s, var_g, cov_sg = joint_variances(gs, cov, K, C, h)
    g = float(h @ c)
    est = q["slip"]
    std = float(np.sqrt(max(var_s + var_g + 2 * cov_sg, 0.0)))
    out = dict(q)
    out["slip"] = dataclasses.replace(est, value=float(est.value) + g, std=std, ci95=None)
    return out, {"value": g, "var": var_g, "cov_with_slip": cov_sg, "slip_var": var_s,
                 "steady_slip": float(est.value)}


def joint_variances(gs, cov, K, C, h) -> tuple:
    """(Var(gs . theta), Var(h . c), Cov(gs . theta, h . c)) under the joint covariance of
    the fit's parameters theta and a term's coefficients c: Cov(theta) = `cov` (the fit's
    plus K C K'), Cov(c) = C, Cov(theta, c) = -K C (the block inverse of the extended
    normal matrix, K = J^+ B)."""
    return (float(gs @ cov @ gs), float(h @ C @ h), float(-(gs @ K) @ C @ h))
