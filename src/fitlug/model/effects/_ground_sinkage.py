import jax.numpy as jnp

from ._base import Ctx, Effect


class GroundSinkage(Effect):
    """Lugs sink into compliant ground: bottom-run path_y -= z_max (1 - exp(-u / u_s))."""

    id = "ground_sinkage"
    defaults = {"sink_z": 0.0, "sink_us": 30.0}
    scales = {"sink_z": 0.05, "sink_us": 10.0}
    meaning = ("The lugs sink into a compliant ground, so lug markers on the bottom run fall "
               "further the longer they are in contact.")
    signature = "y:lug:bottom"

    @classmethod
    def n_free(cls, n_body):
        return 2

    @classmethod
    def bottom_dy(cls, p, u, ctx: Ctx):
        us = jnp.abs(p["sink_us"]) + 1e-6
        return -p["sink_z"] * (1.0 - jnp.exp(-u / us))

    @classmethod
    def report(cls, p):
        return {"z_max_mm": float(p["sink_z"]), "u_s_mm": abs(float(p["sink_us"]))}
