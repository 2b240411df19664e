"""A fit whose slip slope beta ends on its lower bound, with residuals that are its own.

The solvers keep beta >= 0 (k > 0) by a stiff one-sided penalty
(:func:`fitlug.fit._lsq.bound_residuals`) and the output projects beta onto 0
(:func:`fitlug.fit._lsq._onto_range`), keeping the solver's residuals. On a cruise that
leaves beta free the solver ends a hair below 0 and nothing moves. At a gross misfit the
data's pull balances the penalty far below 0: an engine recording driving through a 400-mm
window through a tracker's faults ended at chi^2 1.76e7 with beta < 0, and the projected
parameters gave 1.06e8; the explanation (which starts its searches from the parameters),
the straight runs' belt clock and the report all evaluated a model six times worse than
the fit said. There the fit is taken again with beta held at 0, the other parameters find
the constrained minimum, and the output keeps beta in its packing (a free parameter on its
bound: the covariance and the posterior see it as before) with the residuals and Jacobian
of the point it reports.

A refit of the same recording from such a fit (:func:`fitlug.fit.fit`'s lug-count check,
glitch rounds and noise refit) starts where the fit ended: :func:`refit_on_bound` fits with
beta held at 0 and keeps that fit where the data still pull beta below its bound there
(the Karush-Kuhn-Tucker condition of the bound), instead of walking the free solver to the
same place again (an engine chain round 15 mm wheels: three walks of 300 steps, 3.7 s
each, every one thrown away for the held refit that followed it). The first fit, whose
first stage holds beta at 0 from the data-derived start (fitlug.fit._fit), keeps that stage
where the same condition holds (:func:`bound_holds`).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ._lsq import LsqOutput, bound_residuals, least_squares


def held_on_bound(out: LsqOutput, lay, obs, free, *, max_steps: int, tol: float,
                  finish=None) -> LsqOutput:
    """`out`, or the fit again with beta held at 0 where the projection onto beta >= 0 cost
    more than `tol` of chi^2 (estimated from the penalty the solver balanced: 2 pen^2).
    `finish(out, free)` completes an unconverged held fit as the caller completes its own
    (polish, stationarity at a gross misfit). The output has `out`'s packing; converged is
    the held fit's."""
    if out.beta_solver is None or out.beta_solver >= 0.0:  # beta not fitted, or in range
        return out
    # the lower bound's penalty row (the last) at the solver's point, as the solver saw it
    pen = float(np.ravel(bound_residuals({"beta": jnp.asarray(out.beta_solver, float),
                                          "s0": jnp.asarray(out.params["s0"], float)}))[-1])
    if not (np.all(np.isfinite(out.r)) and 2.0 * pen * pen > tol):
        return out
    rest = [k for k in free if k != "beta"]
    held = least_squares(out.params, rest, lay, obs, max_steps=max_steps)
    if not held.converged and finish is not None and np.all(np.isfinite(held.r)):
        held = finish(held, rest)
    if not np.all(np.isfinite(held.r)):
        return out
    return _in_packing(held, out, lay, obs)


def on_lower_bound(params: dict, free) -> bool:
    """Whether `params` (a fit's) hold the slip slope beta on its lower bound, 0, with the
    slip law fitted (s0 and beta among `free`)."""
    return ("beta" in free and "s0" in free and "beta" in params
            and bool(np.all(np.ravel(np.asarray(params["beta"], float)) == 0.0)))


def refit_on_bound(p0: dict, free, lay, obs, *, max_steps: int) -> LsqOutput | None:
    """The fit from `p0` (beta on its lower bound, :func:`on_lower_bound`) with beta held
    there, where it converges and the data pull beta below the bound at its optimum:
    d chi^2 / d beta >= 0 (from its own residuals and Jacobian; the bound's penalty is zero
    and flat at beta = 0), so that no step into the range lowers chi^2 and the held point
    is the constrained minimum the free solver and :func:`held_on_bound` would reach. The
    output has beta in its packing (a free parameter on its bound). Otherwise None: the
    caller fits with beta free."""
    held = least_squares(p0, free, lay, obs, max_steps=max_steps, hold=("beta",))
    return held._replace(beta_solver=0.0) if bound_holds(held) else None


def bound_holds(held: LsqOutput) -> bool:
    """Whether `held` (a fit with beta held at 0 in its packing) converged to a point where
    d chi^2 / d beta >= 0: the constrained minimum on the bound (see :func:`refit_on_bound`)."""
    if not (held.converged and held.J is not None and np.all(np.isfinite(held.r))):
        return False
    j = held.packing.slices()["beta"].start
    grad = 2.0 * float(np.asarray(held.J)[:, j] @ np.asarray(held.r))
    return grad >= 0.0


def _in_packing(held: LsqOutput, out: LsqOutput, lay, obs) -> LsqOutput:
    """`held` (beta fixed at 0) expressed in `out`'s packing (beta free): the Jacobian (or,
    for the chunked solver, J^T J) gains beta's column at the held point."""
    packing = out.packing
    params = {k: np.asarray(v) for k, v in held.params.items()}
    flat = np.asarray(packing.pack({k: jnp.asarray(v) for k, v in params.items()}), float)
    fixed = {k: jnp.asarray(v, float) for k, v in params.items() if k not in packing.names}
    J = normal = None
    if out.J is not None:
        from ._covariance import _residuals_jacobian

        _, J = _residuals_jacobian(jnp.asarray(flat), fixed, lay, obs, packing)
        J = np.asarray(J)
    else:
        from ._chunks import chunk_plan
        from ._normal import normal_blocks

        normal = normal_blocks(flat, fixed, lay, obs, packing, chunk_plan(lay))[0]
    return LsqOutput(params=params, flat=flat, J=J, r=np.asarray(held.r),
                     converged=bool(held.converged), steps=out.steps + held.steps,
                     packing=packing, normal=normal, beta_solver=0.0)
