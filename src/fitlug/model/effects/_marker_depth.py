import jax.numpy as jnp

from ._base import Effect


class MarkerDepth(Effect):
    """Lug markers in another plane: lug points q -> c + (1 + eps)(q - c).

    The centre c is a gauge choice (the offsets x_off, y_off absorb it), so fits hold it at 0.
    """

    id = "marker_depth"
    defaults = {"depth_eps": 0.0, "depth_cx": 0.0, "depth_cy": 0.0}
    scales = {"depth_eps": 1e-3, "depth_cx": 50.0, "depth_cy": 50.0}
    fixed_in_fit = ("depth_cx", "depth_cy")
    meaning = ("The lug markers lie in another plane than the body markers, so they are imaged "
               "at a slightly different scale and top-run and bottom-run speeds disagree with "
               "one body speed.")
    signature = "x:lug:top+bottom"
    order = 1

    @classmethod
    def image(cls, p, x, y, is_lug):
        g = jnp.where(is_lug, p["depth_eps"], 0.0)
        return x + g * (x - p["depth_cx"]), y + g * (y - p["depth_cy"])

    @classmethod
    def report(cls, p):
        return {"epsilon": float(p["depth_eps"])}
