"""The physical quantities derived from the slip law: per sample, their gradients at the
optimum, and the summary (Estimate) of a sample.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .. import _jaxconfig  # noqa: F401
from ..fit._buckets import pad_model
from ..model._buckets import bucket
from ..fit._result import Estimate, FitResult, derived

REPORTED = ("slip", "delta_l_mm", "stiffness_N_per_mm", "rolling_resistance", "k_over_m")


def _derived_gradients(res: FitResult, names, theta_hat) -> dict:
    """d quantity / d theta at theta_hat for the reported quantities."""
    prob = res.problem
    base = {k: jnp.asarray(v) for k, v in res.params.items()}

    def f(th):
        p = dict(base)
        for i, k in enumerate(names):
            p[k] = th[i]
        q = derived(p, prob.lay, prob.rig.mass_kg)
        return {k: q[k] for k in REPORTED if k in q}

    jac = jax.jacfwd(f)(jnp.asarray(theta_hat, float))
    return {k: np.asarray(v, float) for k, v in jac.items()}



def _derived_samples(res: FitResult, names, flat_samples: np.ndarray) -> dict:
    prob = res.problem
    base = {k: jax.device_put(np.asarray(v)) for k, v in res.params.items()}
    mass = prob.rig.mass_kg

    # the parameters and layout as arguments (on bucketed shapes), not constants of the
    # program: one compile serves every recording of a kind (issue 43, item 2)
    args = pad_model(base, prob.lay) or (base, prob.lay)

    @jax.jit
    def batch(ths, base, lay):
        def one(th):
            p = dict(base)
            for i, k in enumerate(names):
                p[k] = th[i]
            q = derived(p, lay, mass, prob.rig.drawbar_pull_N)
            return {k: q[k] for k in REPORTED if k in q}

        return jax.vmap(one)(ths)

    m = len(flat_samples)  # the chain's length varies: its draws padded to a bucket too
    ths = np.concatenate([flat_samples, np.repeat(flat_samples[-1:], bucket(m) - m, 0)])
    out = {k: np.asarray(v)[:m] for k, v in batch(jax.device_put(ths), *args).items()}
    out.update({k: np.asarray(flat_samples[:, i]) for i, k in enumerate(names)})
    return out


def _estimate(x: np.ndarray) -> Estimate:
    lo, med, hi = np.percentile(x, [2.5, 50.0, 97.5])
    return Estimate(float(med), float(np.std(x, ddof=1)), (float(lo), float(hi)))
