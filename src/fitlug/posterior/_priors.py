"""The priors of the slip law (flat otherwise).

Priors (flat otherwise): beta > 0 (k > 0), s0 >= 0 (C_rr >= 0), slide_mu >= 0 (a
positive friction limit F_max). The measurement noise per role is held at the fit's
estimate (from ~10^4 residuals: its own uncertainty changes interval widths by < 1 %).
"""

from __future__ import annotations

import jax.numpy as jnp

from .. import _jaxconfig  # noqa: F401
from ..model._physics import beta_max

_NONNEG = {"s0": "C_rr >= 0", "slide_mu": "F_max > 0"}
_POSITIVE = {"beta": "k > 0"}


def _log_prior(th, names):
    ok = jnp.ones(th.shape[:-1], bool)
    for i, k in enumerate(names):
        if k in _POSITIVE:
            ok &= th[..., i] > 0
        elif k in _NONNEG:
            ok &= th[..., i] >= 0
    if "s0" in names and "beta" in names:
        s0, beta = th[..., names.index("s0")], th[..., names.index("beta")]
        ok &= beta <= beta_max(s0)
    return jnp.where(ok, 0.0, -jnp.inf)
