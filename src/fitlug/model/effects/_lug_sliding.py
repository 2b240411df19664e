import jax.numpy as jnp

from ._base import Effect


def log_ratio(z):
    """-ln(1 - z) / z, smooth through z = 0 (the linear limit)."""
    zc = jnp.minimum(z, 1.0 - 1e-12)
    small = jnp.abs(zc) < 1e-4
    zs = jnp.where(small, 1.0, zc)
    return jnp.where(small, 1.0 + zc / 2 + zc * zc / 3, -jnp.log1p(-zs) / zs)


class LugSliding(Effect):
    """Janosi-Hanamoto slip: s = -s_K ln(1 - F/F_max), with s_K = 2 F_max / (k n L).

    Parametrised by mu = 1 / s_K (0 is the linear law): F/F_max = mu * s_lin, where
    s_lin = 2F/(k n L) is the linear law's slip, so s = s_lin * (-ln(1 - z)/z), z = mu s_lin.
    """

    id = "lug_sliding"
    defaults = {"slide_mu": 0.0}
    scales = {"slide_mu": 1.0}
    meaning = ("Lug tips slide at the friction limit, so the slip grows faster than linearly "
               "with the traction load (misfit in the acceleration and braking phases).")
    signature = "slip:accelerate+decelerate"

    @classmethod
    def slip(cls, p, s_lin):
        return s_lin * log_ratio(p["slide_mu"] * s_lin)

    @classmethod
    def report(cls, p):
        mu = float(p["slide_mu"])
        return {"s_K": (1.0 / mu) if mu > 0 else None, "inv_s_K": mu}
