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
    if out.J is not None:
        # beta held at 0 in the fit's own packing (its column masked): the program the fit
        # compiled, not a second one for the packing without beta (issue 43 item 2); the
        # output's J already holds beta's column at the held point
        p0 = {**out.params, "beta": np.zeros_like(np.asarray(out.params["beta"], float))}
        held = least_squares(p0, free, lay, obs, max_steps=max_steps, hold=("beta",))
        if not np.all(np.isfinite(held.r)):
            return out
        if held.converged or finish is None:
            return held._replace(steps=out.steps + held.steps, beta_solver=0.0)
        held = _without(held, "beta")  # finished in the packing without beta, as below
    else:
        held = least_squares(out.params, rest, lay, obs, max_steps=max_steps)
    if not held.converged and finish is not None and np.all(np.isfinite(held.r)):
        held = finish(held, rest)
    if not np.all(np.isfinite(held.r)):
        return out
    return _in_packing(held, out, lay, obs)


def _without(out: LsqOutput, name: str) -> LsqOutput:
    """`out` with the parameter `name` (held) out of its packing: its entries and its
    Jacobian's columns removed, its value kept among the parameters."""
    from ._residuals import Packing

    sl = out.packing.slices()[name]
    keep = np.r_[0:sl.start, sl.stop:len(out.flat)]
    packing = Packing.of(out.params, [k for k in out.packing.names if k != name])
    return out._replace(flat=np.asarray(out.flat)[keep], J=np.asarray(out.J)[:, keep],
                        packing=packing)


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
