"""Speed modulations locked to belt travel: shared by lug_ripple and wheel_runout."""

from __future__ import annotations

import math

import jax.numpy as jnp

from ._base import Ctx, Effect


class SpeedModulation(Effect):
    """v -> v (1 + eps sin(omega psi + phi)), parametrised as a sin + b cos (a = eps cos phi)."""

    prefix: str

    @classmethod
    def omega(cls, ctx: Ctx):
        raise NotImplementedError

    @classmethod
    def speed(cls, p, psi, ctx: Ctx):
        a, b = p[cls.prefix + "_a"], p[cls.prefix + "_b"]
        w = cls.omega(ctx)
        th = w * psi
        s, c = jnp.sin(th), jnp.cos(th)
        return a * s + b * c, w * (a * c - b * s)

    @classmethod
    def report(cls, p):
        a, b = float(p[cls.prefix + "_a"]), float(p[cls.prefix + "_b"])
        return {"epsilon": math.hypot(a, b), "phi_rad": math.atan2(b, a)}
