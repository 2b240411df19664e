from ._base import Effect


class LensDistortion(Effect):
    """Uncorrected radial distortion: q -> c + (q - c)(1 + k1 |q - c|^2)."""

    id = "lens_distortion"
    defaults = {"lens_k1": 0.0, "lens_cx": 0.0, "lens_cy": 0.0}
    scales = {"lens_k1": 1e-9, "lens_cx": 50.0, "lens_cy": 50.0}
    meaning = ("Radial lens distortion was left uncorrected, so positions are pushed along the "
               "radius from the image centre and straight runs bow.")
    signature = "xy:all:radial"
    order = 3

    @classmethod
    def image(cls, p, x, y, is_lug):
        dx, dy = x - p["lens_cx"], y - p["lens_cy"]
        f = 1.0 + p["lens_k1"] * (dx * dx + dy * dy)
        return p["lens_cx"] + dx * f, p["lens_cy"] + dy * f

    @classmethod
    def report(cls, p):
        return {"k1_per_mm2": float(p["lens_k1"]), "x_c_mm": float(p["lens_cx"]),
                "y_c_mm": float(p["lens_cy"])}
