import math

import jax.numpy as jnp

from ._base import Ctx, Effect


class BodyBounce(Effect):
    """Body heave and pitch as lugs pass: y_body += (A + B c_xj) sin(2 pi psi / p + phi)."""

    id = "body_bounce"
    defaults = {"bounce_A": 0.0, "bounce_B": 0.0, "bounce_phi": 0.0}
    scales = {"bounce_A": 1e-3, "bounce_B": 1e-5, "bounce_phi": 0.1}
    meaning = ("The body heaves and pitches once per lug as the lugs roll under the wheels, "
               "so the body markers' y oscillates at the lug-passing frequency.")
    signature = "y:body:lug_freq"

    @classmethod
    def n_free(cls, n_body):
        return 3 if n_body >= 2 else 2

    @classmethod
    def body_dy(cls, p, psi, cx, ctx: Ctx):
        return (p["bounce_A"] + p["bounce_B"] * cx) * jnp.sin(2 * jnp.pi * psi / ctx.pitch
                                                               + p["bounce_phi"])

    @classmethod
    def report(cls, p):
        A, B, phi = float(p["bounce_A"]), float(p["bounce_B"]), float(p["bounce_phi"])
        if A < 0:  # same curve, canonical sign
            A, B, phi = -A, -B, phi + math.pi
        return {"A_mm": A, "B_per_mm": B, "phi_rad": math.remainder(phi, 2 * math.pi)}
