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
    u_top = u - D - jnp.pi * R
    y_bottom = -e + (0.0 if bottom_dy is None else bottom_dy(jnp.clip(u, 0.0, D)))
    y_top = 2.0 * R + e + (0.0 if top_dy is None else top_dy(jnp.clip(u_top / D, 0.0, 1.0)))
    x, y = _runs_and_arcs(u, seg, R, D, R + e, R, y_bottom, y_top)
    if ctx.link is not None:  # a chain of rigid links (chain_polygon); a belt below 1 um
        xp, yp, _ = _polygon(u, seg, ctx, top_dy, bottom_dy)
        chain = jnp.abs(ctx.link) > 1e-3
        x, y = jnp.where(chain, xp, x), jnp.where(chain, yp, y)
    return x, y, seg


def _runs_and_arcs(u, seg, R, D, r, yc, y_bottom, y_top):
    """(x, y) at u (mod P) on segment seg: the runs at heights y_bottom and y_top, the arcs
    of radius r round wheel centres at (-+D/2, yc), the angle on an arc its belt travel / R."""
    phi_r = (u - D) / R
    phi_f = (u - 2.0 * D - jnp.pi * R) / R
    u_top = u - D - jnp.pi * R
    x = jnp.select([seg == 0, seg == 1, seg == 2],
                   [D / 2 - u, -D / 2 - r * jnp.sin(phi_r), -D / 2 + u_top],
                   D / 2 + r * jnp.sin(phi_f))
    y = jnp.select([seg == 0, seg == 1, seg == 2],
                   [y_bottom, yc - r * jnp.cos(phi_r), y_top],
                   yc + r * jnp.cos(phi_f))
    return x, y


def _hinge(u, R, Rh, D, P):
    """A hinge of a link chain at belt coordinate u (any real; taken mod P): the stadium of
    the pitch line with the hinges on circles of radius Rh round the wheels (R is the belt
    travel per wheel radian)."""
    u = jnp.mod(u, P)
    return _runs_and_arcs(u, segment_of(u, R, D), R, D, Rh, Rh, 0.0 * u, 2.0 * Rh + 0.0 * u)


def _polygon(u, seg, ctx: Ctx, top_dy, bottom_dy):
    """The marker of a link chain (MODEL.md §2, "Real tracks"): links of pitch c whose
    hinges sit on the wheels' hinge circle; the marker sits e out from its link's middle,
    square to the link. The belt travels R per wheel radian (P = 2D + 2 pi R as for the
    belt), so the hinge circle's radius is Rh = (c/2) / sin(c / 2R) > R; on the arcs a
    link's middle runs at Rh cos(c / 2R) from the wheel's centre, the chordal inset, and
    the marker turns with its link, not with the wheel's radius through it. Below a link
    pitch of 1 um the stadium (a belt) is drawn."""
    R, D, e, P = ctx.R, ctx.D, ctx.e, ctx.P
    c = jnp.clip(jnp.abs(ctx.link), 1e-3, 1.9 * R)
    Rh = (c / 2.0) / jnp.sin(c / (2.0 * R))
    xa, ya = _hinge(u - c / 2.0, R, Rh, D, P)
    xb, yb = _hinge(u + c / 2.0, R, Rh, D, P)
    dx, dy = xb - xa, yb - ya
    n = jnp.sqrt(dx * dx + dy * dy)
    dx, dy = dx / n, dy / n
    x = (xa + xb) / 2.0 - e * dy
    y = (ya + yb) / 2.0 + e * dx
    # the path corrections of the runs (belt_sag, ground_sinkage) as on the stadium
    u_top = u - D - jnp.pi * R
    if bottom_dy is not None:
        y = y + jnp.where(seg == 0, bottom_dy(jnp.clip(u, 0.0, D)), 0.0)
    if top_dy is not None:
        y = y + jnp.where(seg == 2, top_dy(jnp.clip(u_top / D, 0.0, 1.0)), 0.0)
    return x, y, seg
