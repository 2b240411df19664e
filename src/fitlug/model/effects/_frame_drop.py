import jax.numpy as jnp

from ._base import Effect


class FrameDrop(Effect):
    """A lost frame: the true time is t + dt for stamps t >= t*.

    t* is a discrete choice (the first frame stamped too early); fits locate it from the
    residual jump and hold it fixed, but it still counts as a parameter in the BIC.
    """

    id = "frame_drop"
    defaults = {"drop_dt": 0.0, "drop_tstar": 1e9}
    scales = {"drop_dt": 1e-3, "drop_tstar": 1.0}
    fixed_in_fit = ("drop_tstar",)
    meaning = ("The recorder lost a frame, so every time stamp after it is too early and all "
               "markers jump at one instant by about v dt.")
    signature = "x:all:jump"

    @classmethod
    def n_free(cls, n_body):
        return 2  # dt and the (discrete) t*

    @classmethod
    def time_map(cls, p, t):
        return t + jnp.where(t >= p["drop_tstar"], p["drop_dt"], 0.0)

    @classmethod
    def report(cls, p):
        return {"dt_s": float(p["drop_dt"]), "t_star_s": float(p["drop_tstar"])}
