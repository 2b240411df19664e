"""The extension points of the track model: one subclass of :class:`Effect` per catalog entry.

An effect is identity when its parameters take their `defaults`, so the same forward model
serves the base fit and every extension. Hooks a subclass may override (all optional):

- ``time_map(p, t)``: true sample times from the stamps (frame_drop);
- ``speed(p, psi, ctx) -> (m, dm_dpsi)``: additive relative speed modulation v -> v (1 + m);
- ``slip(p, s_lin) -> s``: replaces the linear slip law;
- ``top_dy(p, xi, ctx)`` / ``bottom_dy(p, u, ctx)``: extra path_y on the top / bottom run;
- ``body_dy(p, psi, cx, ctx)``: extra body-marker y;
- ``image(p, x, y, is_lug) -> (x, y)``: image effect, applied in `IMAGE_ORDER`.
"""

from __future__ import annotations

from typing import ClassVar, NamedTuple

import jax.numpy as jnp


class Ctx(NamedTuple):
    """Geometry every hook may need (scalars, mm)."""

    R: jnp.ndarray
    D: jnp.ndarray
    e: jnp.ndarray
    P: jnp.ndarray  # belt length
    pitch: jnp.ndarray  # lug pitch P / N


class Effect:
    """One catalog entry of MODEL.md §3."""

    id: ClassVar[str]
    #: parameter name -> identity value
    defaults: ClassVar[dict[str, float]]
    #: parameter name -> typical magnitude (for scaling the fit and sampling starts)
    scales: ClassVar[dict[str, float]]
    #: parameters held fixed when the effect is fitted (gauge or discrete choices)
    fixed_in_fit: ClassVar[tuple[str, ...]] = ()
    #: one sentence of physics for the report
    meaning: ClassVar[str] = ""
    #: what the effect acts on, used to match located mismatches (role, axis)
    signature: ClassVar[str] = ""

    time_map = None
    speed = None
    slip = None
    top_dy = None
    bottom_dy = None
    body_dy = None
    image = None

    @classmethod
    def n_free(cls, n_body: int) -> int:
        return len(cls.defaults) - len(cls.fixed_in_fit)

    @classmethod
    def report(cls, p: dict) -> dict:
        """Parameters as reported in fit.json (physical names and units)."""
        return {k: float(p[k]) for k in cls.defaults}
