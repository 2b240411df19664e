"""Terms whose place moves with the fit, relinearised (Gauss-Newton on the extended model).

A family term is fitted as columns B next to the fit's Jacobian J, both taken at the fit
after the catalog (:mod:`._solve`). Where the term's place is a coordinate the fit's own
parameters set (a lug's segment and place u on the stadium, its ground x), one linear
step from a fit far off (lugs that splay on the arcs: the base fit's slip 133 sigma off,
its R and the phases pulled by the misfit) leaves the columns at the base fit's places:
samples near an arc's end on the wrong segment, the shape read at the wrong u. The step's
exact chi^2/dof was 5.3 for a predicted 1.0, Levenberg-Marquardt with the columns held
fixed stopped at 1.05 with the slip 9.7 sigma off (bench_discovery lug_splay seed 1003).
Here J, the context and the columns are rebuilt where the extended fit has moved and the
joint linear problem solved again, until chi^2 stops falling: 1.014, the slip 0.6 sigma.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from ...fit._residuals import residuals_host
from ._context import context
from ._extend import extended, params_at
from ._solve import Projector

MAX_STEPS = 5
#: stop when a step lowers chi^2 by less than this (absolute, chi^2 units)
MIN_GAIN = 0.5


def moved(res, flat):
    """FitResult `res` with its parameters at `flat` and its own model's residuals there."""
    p = params_at(res, flat)
    r = residuals_host({k: jnp.asarray(v) for k, v in p.items()}, res.problem.lay,
                       res.problem.obs)
    return dataclasses.replace(res, params=p, flat=np.asarray(flat, float), residuals=r,
                               chi2=float(r @ r))


def relinearised(res, kept, B_all, final, k_all, slip_h, rank: bool, drop=None):
    """Gauss-Newton steps on the model extended by the `kept` terms (their columns B_all
    at `res`, the extended fit `final` after the first step): each step rebuilds the
    Jacobian, the context and the columns of the terms that can (`Choice.columns`) where
    the parameters now are and solves the joint problem again; `drop` (bool rows): left
    out (glitches). Returns (final, joint :class:`._solve.Fitted` or None when no step
    was taken)."""
    from .._engine import jacobian_of

    packing = res.packing
    fixed = {k: v for k, v in res.params.items() if k not in packing.names}
    lay, obs = res.problem.lay, res.problem.obs
    joint = None

    def chi2(f, valid):
        return float(np.sum(np.asarray(f.residuals)[valid] ** 2))

    for _ in range(MAX_STEPS):
        here = moved(res, final.flat)
        J = np.asarray(jacobian_of(here.flat, fixed, packing, lay, obs))
        ctx = context(here, J)
        blocks, i = [], 0
        for t in kept:
            m = t.choice.fitted.B.shape[1]
            blocks.append(t.choice.columns(ctx) if t.choice.columns is not None
                          else B_all[:, i:i + m])
            i += m
        B = np.hstack(blocks)
        valid = ctx.valid if drop is None else ctx.valid & ~drop
        proj = Projector(ctx.J, ctx.r, valid)
        fitted = proj.fit(B, 0, rank=rank)
        new = extended(here, ctx, proj, B, fitted.c, fitted.cov, k_all, slip_h=slip_h)
        c_new, c_old = chi2(new, valid), chi2(final, valid)
        if not np.isfinite(c_new) or c_new > c_old - MIN_GAIN:
            if np.isfinite(c_new) and c_new < c_old:
                final, joint = new, fitted
            break
        final, joint = new, fitted
    return final, joint
