"""The extension points of the track model: one subclass of :class:`Effect` per catalog entry.

An effect is identity when its parameters take their `defaults`, so the same forward model
serves the base fit and every extension. Hooks a subclass may override (all optional):

- ``time_map(p, t)``: true sample times from the stamps (frame_drop);
- ``speed(p, psi, ctx) -> (m, dm_dpsi)``: additive relative speed modulation v -> v (1 + m);
- ``slip(p, s_lin) -> s``: replaces the linear slip law;
- ``top_dy(p, xi, ctx)`` / ``bottom_dy(p, u, ctx)``: extra path_y on the top / bottom run;
- ``body_dy(p, psi, cx, ctx)``: extra body-marker y;
- ``image(p, x, y, is_lug) -> (x, y)``: image effect, applied in `IMAGE_ORDER`;
- ``lug_lag(p, sigma, psi, X, t, nodes, grid, ctx)``: how far (mm) a lug marker trails its
  pitch-line point along the belt (lug_shear);
- ``memory(p)``: the slip's memory length as a fraction of L (lug_memory);
- ``link(p)``: the link pitch (mm) of a chain of rigid links (chain_polygon).
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
    link: jnp.ndarray | None = None  # link pitch of a chain (chain_polygon); None: a belt


class Effect:
    """The base class of an effect: one piece of physics the base model leaves out
    (MODEL.md §3), fitlug's own and plugins alike (docs/add-effect.md).

    A subclass sets the class attributes below and overrides one or more hooks; every
    hook is a classmethod, a JAX function of the parameter dict ``p`` (float64 arrays,
    mm, s, rad), vectorised over samples. The effect must be identity at its `defaults`.
    Register a plugin with :func:`fitlug.register_effect` or the entry-point group
    ``fitlug.effects``.

    Hooks (all optional, at least one):
        time_map(p, t): true sample times (s) from the stamps.
        speed(p, psi, ctx): (m, dm/dpsi), a relative speed modulation v -> v (1 + m)
            locked to belt travel psi (mm).
        slip(p, s_lin): the slip law replacing the linear one.
        top_dy(p, xi, ctx) / bottom_dy(p, u, ctx): extra path y (mm) on the top run
            (xi in [0, 1] along it) / on the bottom run (u, mm along it).
        body_dy(p, psi, cx, ctx): extra y (mm) of a body marker at x offset cx.
        image(p, x, y, is_lug): (x, y) after an image map, applied by the class
            attribute ``order`` (plugins default to after fitlug's own).
        lug_lag(p, sigma, psi, X, t, nodes, grid, ctx): how far (mm) lug samples at belt
            coordinate sigma (body position X, time t) trail their pitch-line point along
            the belt; `nodes` = (X, psi, dX/dt, dpsi/dt) of the integration on `grid`.
        memory(p): the length, as a fraction of L, over which the slip remembers the
            load (the belt travel then solves the lug brush's relation; lug_memory).
        link(p): the link pitch (mm) of a track built of rigid links, whose markers
            then follow the chain's polygon round the wheels (chain_polygon).

    Attributes:
        id: the name in fit.json, the report, ``effects=`` and ``--effect``.
        defaults: parameter name -> identity value (names unique over the whole model).
        scales: parameter name -> typical size (fit scaling, sampler starts).
        fixed_in_fit: parameters held fixed when the effect is fitted.
        meaning: one sentence of physics for the report.
        signature: what it acts on, "axis:role:where" (e.g. "y:lug:top"), matched to
            located mismatches by the explanation.
    """

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
    #: whether the explanation searches for the effect on every recording (False: a model
    #: part a user fits by name, ``effects=[id]``, that the explanation does not try)
    searched: ClassVar[bool] = True

    time_map = None
    speed = None
    slip = None
    top_dy = None
    bottom_dy = None
    body_dy = None
    image = None
    lug_lag = None
    memory = None
    link = None

    @classmethod
    def n_free(cls, n_body: int) -> int:
        return len(cls.defaults) - len(cls.fixed_in_fit)

    @classmethod
    def report(cls, p: dict) -> dict:
        """Parameters as reported in fit.json (physical names and units)."""
        return {k: float(p[k]) for k in cls.defaults}
