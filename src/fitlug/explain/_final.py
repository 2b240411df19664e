"""The final model (base + named effects) as a FitResult, polished with its exact Jacobian.

The forward selection leaves the parameters within 1e-3 of chi^2's minimum. Running the
project's Levenberg-Marquardt (fit_problem) again from there costs a fresh trace of the
solver for the new effect set and ~30 damped steps to meet its 1e-9 tolerances; a few
undamped Gauss-Newton steps with the exact Jacobian of the final model reach the same
minimum (quadratic convergence from that close), and the result is assembled exactly as
fit_problem assembles it: same packing, covariance (fitlug.fit.covariance), derived
quantities with delta-method errors (compute_quantities), dof and convergence flag.
Convergence is declared when the last Gauss-Newton step lowers chi^2 by less than
1e-6 and its predicted decrease is below 1e-6 too, both in units of max(1, chi^2/dof)
(a gross misfit's chi^2 is in units of a noise it does not have). The steps and the covariance come
from :func:`gauss_newton_step` and :func:`covariance_of` (dense, or from the chunked
normal equations on long recordings).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ..fit import FitResult, free_parameters, residual_noise, reweighted
from ..fit._chunks import blocked_residuals, time_blocks
from ..fit._residuals import Packing
from ..fit._rowchunks import RowChunks
from ..fit._result import compute_quantities
from ._engine import jacobian_of
from ._criterion import GROSS_CHI2
from ._explanation import BASE_EFFECTS
from ._normal import normal_of, pinv_factor

MAX_STEPS = 8
TOL = 1e-6
NOISE_REFIT_TOL = 0.005


def _polish(prob, p: dict, free: list) -> FitResult:
    packing = Packing.of(p, free)
    fixed = {k: jnp.asarray(v, float) for k, v in p.items() if k not in packing.names}
    flat = np.asarray(packing.pack(p))
    lay, obs = prob.lay, prob.obs
    blocks = time_blocks(lay, obs, plans=False)  # long recordings: the model by blocks

    def res_of(f):
        return blocked_residuals(f, fixed, lay, obs, packing, blocks)  # None: at once

    r = res_of(flat)
    chi2 = float(r @ r)
    # the tolerances are on chi^2 in units of its noise: where the model misfits grossly
    # (chi2/dof in the thousands: a contact-dynamics track) they scale with chi2/dof, as
    # they would with the noise rescaled to the misfit; without this the polish never
    # met 1e-6 at chi^2 ~ 1e7 and ran all MAX_STEPS twice (~1 s CPU a step)
    tol = TOL * max(1.0, chi2 / max(prob.n_valid - len(flat), 1))
    converged, steps = False, 0
    for steps in range(1, MAX_STEPS + 1):
        # dense SVD step, or from chunked normal equations on a long recording
        step, predicted = gauss_newton_step(flat, fixed, packing, lay, obs, r)
        for scale in (1.0, 0.5, 0.25, 0.1):
            f2 = flat + scale * step
            r2 = res_of(f2)
            c2 = float(r2 @ r2)
            if np.isfinite(c2) and c2 <= chi2:
                break
        else:
            converged = predicted < 10 * tol  # no step lowers chi^2: at the minimum
            break
        gain = chi2 - c2
        flat, r, chi2 = f2, r2, c2
        if gain < tol and predicted < tol + 2 * gain + 1e-9 * chi2:
            converged = True
            break
    cov = covariance_of(flat, fixed, packing, lay, obs)
    fixed_np = {k: np.asarray(v) for k, v in fixed.items()}
    params = {**{k: np.asarray(v) for k, v in packing.unpack(jnp.asarray(flat), {}).items()},
              **fixed_np}
    params = {k: params[k] for k in p}  # the dict order of the problem's parameters
    q = compute_quantities(params, packing, flat, cov, lay, prob.rig.mass_kg, fixed_np,
                           prob.rig.drawbar_pull_N)
    return FitResult(problem=prob, params=params, packing=packing, flat=np.asarray(flat),
                     cov=cov, residuals=r, chi2=chi2, dof=prob.n_valid - len(flat),
                     converged=bool(converged), steps=steps, quantities=q)


def _extended(res, eng, accepted, theta):
    """(problem, parameters, free names) of `res`'s model plus the `accepted` effects at
    engine vector `theta`."""
    prob = res.problem
    effects = tuple(res.effects) + tuple(accepted)
    p_all = eng.params(theta)
    prob_f, p = prob.with_effects(effects, p_all)
    p = {k: np.asarray(p_all[k]) if k in p_all else np.asarray(v) for k, v in p.items()}
    free = free_parameters(prob_f.lay)
    if "body_bounce" in effects and prob.lay.n_body < 2:
        free = [k for k in free if k != "bounce_B"]  # MODEL.md §3: B = 0, one body marker
    return prob_f, p, free


def final_fit(res, eng, accepted, theta) -> FitResult:
    """FitResult of `res`'s model plus the `accepted` effects, from engine vector `theta`.

    The noise per role is then re-estimated from the final residuals (as fit() does for the
    base model) and the fit polished again when it moved by more than 0.5 %.
    """
    prob = res.problem
    prob_f, p, free = _extended(res, eng, accepted, theta)
    if getattr(res, "constraints", None) is not None:
        # a fit under fitlug.Parameters: its held elements, bounds and priors stay (the
        # constrained solver, not the undamped polish, which would free them again)
        from ..fit import fit_problem

        spec = res.constraints
        final = fit_problem(prob_f, p, free=free, params=spec, require_convergence=False)
        if prob.noise_source in ("differences", "residual differences"):
            new = residual_noise(final)
            if all(np.isfinite(v) and v > 0 for v in new.values()):
                final = fit_problem(reweighted(final.problem, new), final.params, free=free,
                                    params=spec, require_convergence=False)
        return final
    final = _polish(prob_f, p, free)
    renoise = prob.noise_source in ("differences", "residual differences")
    if renoise:
        new = residual_noise(final)
        old = final.problem.noise
        if all(np.isfinite(v) and v > 0 for v in new.values()) and any(
                abs(new[k] / old[k] - 1.0) > NOISE_REFIT_TOL for k in new):
            final = _polish(reweighted(final.problem, new), final.params, free)
    if set(accepted) & set(BASE_EFFECTS) and (prob.init_info.get("glitches") or []) \
            and final.chi2_per_dof <= GROSS_CHI2:
        # a base model that lacked a part of its own (markers on the pitch line) misfits
        # tip markers by millimetres where the lugs lift off, and its glitch rule took real
        # samples for glitches (8 on a tip-marker recording); the rounds again under the
        # final model give them back. Not where the final model does not describe the path
        # (an engine's recording at chi2/dof 2 000): the rule flags the misfit's structure
        # there (35-42 samples, a different set each round), and the rounds' refits crawled
        # 312, 124 and 50 steps (26 s), their end set by which samples the rule flagged
        from ..fit._fit import remove_glitches

        final = remove_glitches(final, renoise=renoise, free=free, require_convergence=False)
    return final


def polished_theta(res, eng, accepted, theta) -> np.ndarray:
    """Engine vector of `res`'s model plus the `accepted` effects fitted to the end with the
    exact Jacobian (the project's Levenberg-Marquardt, fitlug.fit.fit_problem, the noise
    per role held at the base fit's): for a step of the search whose fit stopped before its
    minimum. The engine's Jacobian leaves out an added effect's change of the base columns;
    near the friction limit lug_sliding changes the speed spline's slip columns several
    times over and the search's fit crawls (issue 32), leaving a misfit that later rounds
    would take for another effect. Undamped Gauss-Newton (:func:`_polish`) does not serve
    there: from F0/F_max = 0.76 with mu 20 % short, no fraction of its first step lowers
    chi^2."""
    prob_f, p, free = _extended(res, eng, accepted, theta)
    from ..fit import fit_problem

    out = fit_problem(prob_f, p, free=free, require_convergence=False,
                      params=getattr(res, "constraints", None))
    return eng.with_values(theta, {k: v for k, v in out.params.items() if k in eng.slices})


# ---------------------------------------------------------------------------------------
# Gauss-Newton steps and covariances of a fixed-effect-set problem (the final polish):
# dense on short recordings, from the chunked normal equations on long ones.
# ---------------------------------------------------------------------------------------
def gauss_newton_step(flat, fixed, packing, lay, obs, r) -> tuple:
    """(undamped Gauss-Newton step, its predicted chi^2 decrease) at `flat`, residuals r:
    the minimum-norm step of the column-scaled Jacobian (singular values below 1e-12 of
    the largest dropped), or of its chunked normal equations on a long recording."""
    J = jacobian_of(flat, fixed, packing, lay, obs)
    if isinstance(J, RowChunks):
        A, g = normal_of(J, np.asarray(r))
        M = pinv_factor(A, 1e-14)
        q = M.T @ g
        return -(M @ q), float(q @ q)
    d = np.sqrt(np.sum(J * J, 0))
    d = np.where(d > 0, d, 1.0)
    Js = J / d
    U, s, Vt = np.linalg.svd(Js, full_matrices=False)
    keep = s > 1e-12 * s.max()
    ur = U[:, keep].T @ r
    step = -(Vt[keep].T @ (ur / s[keep])) / d
    return step, float(ur @ ur)


def covariance_of(flat, fixed, packing, lay, obs) -> np.ndarray:
    """fitlug.fit.covariance of the problem's Jacobian (from J^T J on long recordings)."""
    from ..fit._covariance import covariance, covariance_normal
    J = jacobian_of(flat, fixed, packing, lay, obs)
    if isinstance(J, RowChunks):
        return covariance_normal(normal_of(J)[0])
    return covariance(J)


def withdrawn(res, final, accepted, rounds) -> bool:
    """Whether the accepted entries' exact fit `final` stopped unconverged and worse than
    the base fit `res` (chi^2/dof): the search took them on a misfit in other units (an
    engine's rubber belt through heavy occlusions: lug_sliding at s_K 1e-11, the final fit
    at chi^2/dof 75 000 for the base's 8 000). They are then withdrawn, not claimed: the
    rounds that accepted them say so instead ('withdrawn': the id and why)."""
    if final.converged or final.chi2_per_dof <= res.chi2_per_dof:
        return False
    for rd in rounds:
        if rd.get("accepted") in accepted:
            rd["withdrawn"] = (f"{rd.pop('accepted')}: the final fit with it stopped at "
                               f"chi2/dof {final.chi2_per_dof:.0f}, above the base "
                               f"model's {res.chi2_per_dof:.0f}")
    return True
