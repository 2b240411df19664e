"""The profile of chi^2 over the nuisance parameters at a given slip law, computed
independently of the posterior's step model (the truth its exact marginal is tested
against)."""

import jax
import jax.numpy as jnp
import numpy as np


def profile_chi2(res, names, theta, steps=20):
    """min over the nuisance parameters of chi^2 at theta: Gauss-Newton with the Jacobian
    of jax.jacfwd at every iterate, a column-scaled pseudo-inverse (a parameter that does
    not act stays put) and step halving (independent of the marginal's step model)."""
    from fitlug.fit._residuals import residuals

    prob, pk = res.problem, res.packing
    sl = pk.slices()
    idx = np.array([sl[k].start for k in names])
    rest = jnp.asarray(np.setdiff1d(np.arange(len(res.flat)), idx))
    fixed = {k: jnp.asarray(v) for k, v in res.params.items() if k not in pk.names}
    flat = jnp.asarray(res.flat).at[idx].set(theta)

    def fn(x):
        return residuals(pk.unpack(flat.at[rest].set(x), fixed), prob.lay, prob.obs)

    rj = jax.jit(lambda x: (fn(x), jax.jacfwd(fn)(x)))
    chi2 = jax.jit(lambda x: jnp.sum(fn(x) ** 2))
    x = flat[rest]
    r, J = rj(x)
    c = float(r @ r)
    for _ in range(steps):
        A, g = np.asarray(J.T @ J), np.asarray(J.T @ r)
        d = np.sqrt(np.diag(A))
        s = np.where(d > 0, 1.0 / np.where(d > 0, d, 1.0), 0.0)
        w, V = np.linalg.eigh(A * np.outer(s, s))
        inv = np.where(w > 1e-12 * w.max(), 1.0 / np.where(w > 0, w, 1.0), 0.0)
        step = s * (V @ (inv * (V.T @ (s * g))))
        for alpha in 0.5 ** np.arange(12):
            c_new = float(chi2(x - alpha * step))
            if c_new < c:
                break
        if not c_new < c - 1e-9:
            break
        x = x - alpha * step
        c = c_new
        r, J = rj(x)
    return c
