import jax.numpy as jnp

from ._base import Effect


class CameraTilt(Effect):
    """Camera rolled against the ground: every point rotated counter-clockwise by theta."""

    id = "camera_tilt"
    defaults = {"tilt_theta": 0.0}
    scales = {"tilt_theta": 1e-4}
    meaning = ("The camera is rolled against the ground, so the body markers climb or fall "
               "linearly with x.")
    signature = "y:body:trend"
    order = 2

    @classmethod
    def image(cls, p, x, y, is_lug):
        c, s = jnp.cos(p["tilt_theta"]), jnp.sin(p["tilt_theta"])
        return c * x - s * y, s * x + c * y

    @classmethod
    def report(cls, p):
        return {"theta_rad": float(p["tilt_theta"])}
