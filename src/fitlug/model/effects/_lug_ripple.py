import math

from ._base import Ctx
from ._speed_mod import SpeedModulation


class LugRipple(SpeedModulation):
    """Polygon effect: speed ripple as lugs engage, v -> v (1 + eps sin(2 pi psi / p + phi))."""

    id = "lug_ripple"
    prefix = "ripple"
    defaults = {"ripple_a": 0.0, "ripple_b": 0.0}
    scales = {"ripple_a": 1e-3, "ripple_b": 1e-3}
    meaning = ("The speed pulses once per lug as each lug engages the ground (polygon effect), "
               "so every marker's x oscillates at the lug-passing frequency.")
    signature = "x:all:lug_freq"

    @classmethod
    def omega(cls, ctx: Ctx):
        return 2 * math.pi / ctx.pitch
