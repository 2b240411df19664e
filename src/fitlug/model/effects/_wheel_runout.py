from ._base import Ctx
from ._speed_mod import SpeedModulation


class WheelRunout(SpeedModulation):
    """Eccentric drive wheel: v -> v (1 + eps sin(psi / R + phi))."""

    id = "wheel_runout"
    prefix = "runout"
    defaults = {"runout_a": 0.0, "runout_b": 0.0}
    scales = {"runout_a": 1e-3, "runout_b": 1e-3}
    meaning = ("The drive wheel is eccentric, so the speed varies once per wheel revolution "
               "and every marker's x oscillates at the wheel-revolution frequency.")
    signature = "x:all:wheel_freq"

    @classmethod
    def omega(cls, ctx: Ctx):
        return 1.0 / ctx.R
