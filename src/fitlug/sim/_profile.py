"""Smooth motor speed profiles: rest, accelerate, cruise, decelerate, rest."""

from __future__ import annotations

import numpy as np

_RAMPS = {
    # shape(x), shape'(x) on x in [0, 1]
    "cos": (lambda x: 0.5 * (1 - np.cos(np.pi * x)), lambda x: 0.5 * np.pi * np.sin(np.pi * x)),
    "smoothstep": (lambda x: x * x * (3 - 2 * x), lambda x: 6 * x * (1 - x)),
    "quintic": (lambda x: x ** 3 * (10 - 15 * x + 6 * x * x), lambda x: 30 * x * x * (1 - x) ** 2),
}


def speed_profile(t, *, v_cruise, duration, rest, ramp, shape="cos"):
    """Speed (mm/s) and acceleration (mm/s^2) at times t (s)."""
    if shape not in _RAMPS:
        raise ValueError(f"unknown ramp shape {shape!r}; use one of {', '.join(_RAMPS)}")
    f, df = _RAMPS[shape]
    t = np.asarray(t, float)
    x1 = np.clip((t - rest) / ramp, 0, 1)
    x2 = np.clip((t - (duration - rest - ramp)) / ramp, 0, 1)
    in1 = (t > rest) & (t < rest + ramp)
    in2 = (t > duration - rest - ramp) & (t < duration - rest)
    v = v_cruise * (f(x1) - f(x2))
    a = v_cruise / ramp * (np.where(in1, df(x1), 0.0) - np.where(in2, df(x2), 0.0))
    return v, a
