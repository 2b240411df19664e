"""The stadium path of a lug marker relative to the body (MODEL.md §2 table)."""

from __future__ import annotations

import jax.numpy as jnp

from .effects import Ctx


def belt_length(R, D):
    """P = 2D + 2 pi R, mm."""
    return 2.0 * D + 2.0 * jnp.pi * R


def segment_of(u, R, D):
    """0 bottom run, 1 rear arc, 2 top run, 3 front arc, for u = sigma mod P."""
    b1, b2, b3 = D, D + jnp.pi * R, 2.0 * D + jnp.pi * R
    return jnp.where(u < b1, 0, jnp.where(u < b2, 1, jnp.where(u < b3, 2, 3)))


def stadium(sigma, ctx: Ctx, top_dy=None, bottom_dy=None):
    """(path_x, path_y) of belt coordinate `sigma` (any shape), mm.

    `top_dy(xi)` and `bottom_dy(u)` add to path_y on the top and bottom runs (belt_sag,
    ground_sinkage); xi in [0, 1] along the top run, u counted from the bottom run's start.
    """
    R, D, e, P = ctx.R, ctx.D, ctx.e, ctx.P
    u = jnp.mod(sigma, P)
    seg = segment_of(u, R, D)
    re = R + e
    phi_r = (u - D) / R
    phi_f = (u - 2.0 * D - jnp.pi * R) / R
    u_top = u - D - jnp.pi * R
    x = jnp.select([seg == 0, seg == 1, seg == 2],
                   [D / 2 - u, -D / 2 - re * jnp.sin(phi_r), -D / 2 + u_top],
                   D / 2 + re * jnp.sin(phi_f))
    y_bottom = -e + (0.0 if bottom_dy is None else bottom_dy(jnp.clip(u, 0.0, D)))
    y_top = 2.0 * R + e + (0.0 if top_dy is None else top_dy(jnp.clip(u_top / D, 0.0, 1.0)))
    y = jnp.select([seg == 0, seg == 1, seg == 2],
                   [y_bottom, R - re * jnp.cos(phi_r), y_top],
                   R + re * jnp.cos(phi_f))
    return x, y, seg
