"""lug_sliding fitted directly from the data, for a base fit that the sliding law distorts.

Near the friction limit (a steady F0/F_max of ~0.85 and more, ramps that take the traction
to within a few % of F_max) the linear base model bends its speed spline to follow the
law's curvature (peak accelerations 1.6 times the body markers' own, braking 2.9 times)
and its slip slope beta to the secant of the law over the ramps. Every start built on that base (the
screening's Gauss-Newton step, :func:`._candidates.sliding_starts`) puts F/F_max past 1
somewhere in the ramps, and the fit stops far from the law (issue 32: s0 0.40, chi^2/dof
~500 after explanation).

Here the start is the data's own: the speed spline of the problem's data-derived start
(the body markers' motion, :mod:`fitlug.fit._init`) in the base fit's geometry, with the
law on a grid over (z0, z_pk): z0 = F0/F_max at cruise, z_pk the largest F/F_max the
data's accelerations reach. With the base fit's steady slip S and the rig's mass m:

    mu = -ln(1 - z0) / S,  s0 = z0 / mu,  beta = (z_pk - z0) / (a_max mu)

(F_max = m a_max / (1000 (z_pk - z0)), MODEL.md §2-§3; F_max is thus bounded above the
largest traction seen). z_pk is spaced evenly in -ln(1 - z_pk): chi^2 is a narrow valley
there (F/F_max within a few % of 1 in the ramps, the slip there changes by tens of % for
1 % of F_max), so each z0's peak is refined twice between the neighbours of its best
(where the grid's best is within REFINE_GATE times the model without the law's chi^2).
The grid's chi^2 costs model evaluations only (~1 100, batched); around its best z0 a
finer grid (~1 200), searched only where the coarse one's best is already lower than the
model without the law (near the limit it is ~0.16 of that chi^2; 1.01 under a lug splay,
1.7-130 on a contact-dynamics engine's recording); where the fine grid is no lower
than the model without the law, the misfit is of another kind and nothing is fitted (a
strong runout or sag costs the grids alone); else the fine grid's N_HELD best laws each
with the law held while the rest settles, the best of them then with everything free (the
project's Levenberg-Marquardt with the exact Jacobian). The result is an ordinary fit of
the base model plus lug_sliding; the search judges it by the catalog's rules like any
other candidate.
"""

from __future__ import annotations

import math

import numpy as np

#: coarse grid of z0 = F0/F_max, and the points of -ln(1 - z_pk) per z0
Z0_GRID = tuple(np.round(np.linspace(0.3, 0.95, 14), 3))
N_PEAK = 40
#: the finer grid around the coarse grid's best: z0 within +-FINE_DZ0, N_PEAK_FINE peaks
FINE_DZ0, N_Z0_FINE, N_PEAK_FINE = 0.05, 11, 60
#: the largest z_pk on the grids (F_max at least 0.5 % above the largest traction)
Z_PEAK_MAX = 0.995
#: the fine grid's best laws fitted with the law held (their z0 at least DZ0_APART apart):
#: with the geometry and speed held the grid's chi^2 is only roughly right, and its best
#: z0 can be 0.02 off the law's (one noise seed of four at F0/F_max 0.88)
N_HELD, DZ0_APART = 3, 0.015
#: points of each refinement of a z0's peak between the neighbours of its best
N_REFINE = 21
#: the coarse grid is refined only where its best is at most this many times the chi^2 of
#: the model without the law. The refinement lowered that ratio at most 7.4-fold (1.20 ->
#: 0.16 near the friction limit, where the direct fit wins; 1.38-5.7 -> the same to 0.1 %
#: on the engine's recordings, 2026-11-29); on those of the engine at 128-279 it cost two
#: thirds of the grid for nothing
REFINE_GATE = 10.0
#: steps of the held-law fit and of the free fit
HELD_STEPS, FREE_STEPS = 100, 300
#: the most residuals a recording may have for the direct fit: its grids cost ~1 200 model
#: evaluations (~8 s at 2 900 residuals, 240 frames of 6 markers, on a loaded 2-core
#: machine); longer recordings (and the chunked path) keep the search's own fit only
MAX_RESIDUALS = 50_000


def _peaks(z0, S, a_max, us):
    """(z0, z_pk, s0, beta, mu) rows at z0 for peaks z_pk = 1 - exp(-u), u in `us`."""
    mu = -math.log1p(-z0) / S
    return [(z0, -math.expm1(-u), z0 / mu, (-math.expm1(-u) - z0) / (a_max * mu), mu)
            for u in us]


def _grid(z0s, S, a_max, n_pk):
    """(z0, z_pk, s0, beta, mu) rows of the grid."""
    rows = []
    u_hi = -math.log1p(-Z_PEAK_MAX)
    for z0 in z0s:
        if not 0 < z0 < Z_PEAK_MAX:
            continue
        rows += _peaks(z0, S, a_max, np.linspace(-math.log1p(-z0) + 0.02, u_hi, n_pk))
    return rows


def direct_sliding(res, eng, theta) -> np.ndarray | None:
    """Engine vector of `res`'s model plus lug_sliding fitted from the data's own start,
    or None where that does not apply (a slip law already in the model, no positive
    steady slip, no acceleration in the data, more than MAX_RESIDUALS residuals). Never raises on a fit that fails: None."""
    import jax.numpy as jnp

    from .._errors import FitlugError
    from ..fit import fit_problem, free_parameters
    from ..model._host import speed_values_host

    if "lug_sliding" in res.effects or "slide_mu" not in eng.slices \
            or eng.chunked or eng.n_res > MAX_RESIDUALS:
        return None
    prob = res.problem
    S = float(res.params["s0"])
    if not 0 < S < 1:
        return None
    prob_f, p = prob.with_effects(tuple(res.effects) + ("lug_sliding",), res.params)
    v0 = np.asarray(prob_f.p0["v"])
    _, a_n, _, a_m = speed_values_host(prob_f.lay, jnp.asarray(v0))
    a_max = float(max(np.max(np.asarray(a_n)), np.max(np.asarray(a_m))))
    if not a_max > 0:
        return None
    th0 = eng.with_values(theta, {"v": v0})
    law = ("s0", "beta", "slide_mu")

    def chi2_of(rows):
        T = np.array([eng.with_values(th0, dict(zip(law, r[2:]))) for r in rows])
        return eng.chi2_best(T)[0]

    def refined(z0s, n_pk, gate=None):
        # per z0 the peak's valley is narrower than the grid's step: twice, N_REFINE points
        # between the neighbours of each z0's best peak (not where the grid's best is more
        # than `gate` times the model without the law: no refinement gets there)
        rows = _grid(z0s, S, a_max, n_pk)
        c2 = chi2_of(rows)
        if gate is not None and not np.min(c2) <= gate * c2_cur:
            return rows, c2
        for _ in range(2):
            best = float(np.min(c2))
            extra = []
            for z in sorted({r[0] for r in rows}):
                idx = [i for i, r in enumerate(rows) if r[0] == z]
                us = np.array([-math.log1p(-rows[i][1]) for i in idx])
                order = np.argsort(us)
                j = int(np.argmin(c2[np.array(idx)[order]]))
                lo, hi = us[order][max(j - 1, 0)], us[order][min(j + 1, len(us) - 1)]
                extra += _peaks(z, S, a_max, np.linspace(lo, hi, N_REFINE))
            rows = rows + extra
            c2 = np.concatenate([c2, chi2_of(extra)])
            if not np.min(c2) < best:
                # the valley's floor is not between the grid's points: a second pass
                # would not find it either (an engine's recording: the same minimum to
                # the digit, 1.2 s)
                break
        return rows, c2

    r_cur = eng.residuals(theta)[0]
    c2_cur = float(r_cur @ r_cur)

    def lower(c2):  # a grid point below the model without the law
        return bool(np.isfinite(np.min(c2)) and np.min(c2) < c2_cur)

    # each grid no lower than the model without the law: a misfit of another kind (the
    # coarse grid, refined at every z0's peak, decides before the fine one: on an engine's
    # contact dynamics the fine grid cost ~9 s and was never lower)
    rows, c2 = refined(Z0_GRID, N_PEAK, gate=REFINE_GATE)
    if not lower(c2):
        return None
    z0 = rows[int(np.argmin(c2))][0]
    rows, c2 = refined(np.linspace(z0 - FINE_DZ0, z0 + FINE_DZ0, N_Z0_FINE), N_PEAK_FINE)
    if not lower(c2):
        return None
    picks = []  # the best row of each z0, the N_HELD best of those at least DZ0_APART apart
    for i in np.argsort(c2):
        if len(picks) == N_HELD or not np.isfinite(c2[i]):
            break
        if all(abs(rows[i][0] - rows[j][0]) >= DZ0_APART for j in picks):
            picks.append(i)
    free = free_parameters(prob_f.lay)
    best = None
    try:
        for i in picks:
            params = eng.params(eng.with_values(th0, dict(zip(law, rows[i][2:]))))
            start = {k: np.asarray(params[k]) if k in params else np.asarray(v)
                     for k, v in p.items()}
            out = fit_problem(prob_f, start, free=[k for k in free if k not in law],
                              max_steps=HELD_STEPS, require_convergence=False)
            if np.isfinite(out.chi2) and (best is None or out.chi2 < best.chi2):
                best = out
        if best is None or not best.chi2 < float(r_cur @ r_cur):
            return None
        out = fit_problem(prob_f, best.params, free=free, max_steps=FREE_STEPS,
                          require_convergence=False)
    except (FitlugError, FloatingPointError, np.linalg.LinAlgError):
        return None
    if not np.isfinite(out.chi2):
        return None
    return eng.with_values(theta, {k: v for k, v in out.params.items() if k in eng.slices})


def direct_candidate(res, eng, theta, out):
    """The search's lug_sliding fit `out` (an engine LMResult), or the direct fit from the
    data's own start (:func:`direct_sliding`) where that is lower in chi^2."""
    from ._engine import LMResult

    th = direct_sliding(res, eng, theta)
    if th is None:
        return out
    r = eng.residuals(th)[0]
    c2 = float(r @ r)
    if not (np.isfinite(c2) and c2 < out.chi2):
        return out
    return LMResult(th, r, c2, out.iterations, True)

