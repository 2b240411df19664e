from ._base import Ctx, Effect


class BeltSag(Effect):
    """The slack top run sags: path_y -= 4 d xi (1 - xi), xi in [0, 1] along the run."""

    id = "belt_sag"
    defaults = {"sag_d": 0.0}
    scales = {"sag_d": 0.1}
    meaning = ("The slack top run of the belt sags between the wheels, so lug markers dip on "
               "the top run, most at mid-span.")
    signature = "y:lug:top"

    @classmethod
    def top_dy(cls, p, xi, ctx: Ctx):
        return -4.0 * p["sag_d"] * xi * (1.0 - xi)

    @classmethod
    def report(cls, p):
        return {"d_mm": float(p["sag_d"])}
