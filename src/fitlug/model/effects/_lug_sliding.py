import jax.numpy as jnp

from ._base import Effect


#: where -ln(1 - z) is continued by its second-order Taylor polynomial (see log_ratio)
Z_SMOOTH = 0.999


def log_ratio(z):
    """-ln(1 - z) / z, smooth through z = 0 (the linear limit).

    Past the friction limit (z >= Z_SMOOTH, a traction within 0.1 % of F_max) -ln(1 - z) is
    continued by its Taylor polynomial of second order at Z_SMOOTH: finite and increasing,
    with a gradient. A law that sets F/F_max >= 1 anywhere has no physical reading, but a
    fit passes through such points: clipped at 1 - 1e-12 (before issue 32) the slip was
    flat there, the fit had no gradient back and stopped (near the limit, from a start
    whose accelerations overshoot the data's by 30 %, at chi^2/dof 1e3..1e6)."""
    z1 = Z_SMOOTH
    zs = jnp.where(jnp.abs(z) < 1e-4, 1.0, z)
    inside = -jnp.log1p(-jnp.where(zs > z1, z1, zs)) / zs
    d = z - z1
    past = (-jnp.log1p(-z1) + d / (1 - z1) + 0.5 * (d / (1 - z1)) ** 2) / zs
    big = jnp.where(z > z1, past, inside)
    return jnp.where(jnp.abs(z) < 1e-4, 1.0 + z / 2 + z * z / 3, big)


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
