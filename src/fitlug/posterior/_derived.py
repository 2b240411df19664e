"""The physical quantities derived from the slip law: per sample, their gradients at the
optimum, and the summary (Estimate) of a sample.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .. import _jaxconfig  # noqa: F401
from ..fit._buckets import pad_model
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



#: draws per call of the derived quantities' program (the last block padded)
DRAW_BLOCK = 4096


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

    # the chain's length varies with the recording (and with the fit's last digits): its
    # draws go in blocks of DRAW_BLOCK, the last padded, so one compiled shape serves
    # every chain (a bucket of the length compiled anew when a chain crossed into another)
    m = len(flat_samples)
    n = -(-m // DRAW_BLOCK) * DRAW_BLOCK
    ths = np.concatenate([flat_samples, np.repeat(flat_samples[-1:], n - m, 0)])
    parts = [batch(jax.device_put(ths[i:i + DRAW_BLOCK]), *args) for i in range(0, n, DRAW_BLOCK)]
    out = {k: np.concatenate([np.asarray(q[k]) for q in parts])[:m] for k in parts[0]}
    out.update({k: np.asarray(flat_samples[:, i]) for i, k in enumerate(names)})
    return out


def _estimate(x: np.ndarray) -> Estimate:
    lo, med, hi = np.percentile(x, [2.5, 50.0, 97.5])
    return Estimate(float(med), float(np.std(x, ddof=1)), (float(lo), float(hi)))
