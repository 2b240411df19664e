"""Image map: every observed point q -> q + w(q), a smooth low-order warp of the image
(MODEL.md §5; lens_distortion, camera_tilt and marker_depth are its catalog cases). w's two
components are polynomials of degree 1-3 in the image position, scaled to the points'
extent; the criterion counts only the directions the fit's own parameters do not already
hold (a translation is the offsets, a scale the wheels' size), and picks the degree.
"""

from __future__ import annotations

import numpy as np

from ._base import Choice, Everywhere, best_size, names

DEGREES = (1, 2, 3)


def _monomials(u, v, d):
    """(len(u), m) monomials u^i v^j with 1 <= i + j <= d."""
    return np.stack([u ** i * v ** (k - i) for k in range(1, d + 1) for i in range(k + 1)], 1)


class ImageMap(Everywhere):
    """A smooth warp of every point of the image (the same for lugs and body)."""

    name = "image map"

    @classmethod
    def fit(cls, ctx, proj, parts):
        if not cls.enough(ctx):
            return None
        sel = ctx.valid
        qx, qy = np.nan_to_num(ctx.qx), np.nan_to_num(ctx.qy)
        cx, cy = float(np.mean(qx[sel])), float(np.mean(qy[sel]))
        h = float(max(np.ptp(qx[sel]), np.ptp(qy[sel]))) / 2 or 1.0

        def cols(d):
            P = _monomials((qx - cx) / h, (qy - cy) / h, d)
            m = P.shape[1]
            B = np.zeros((len(ctx.r), 2 * m))
            for ax in (0, 1):
                on = sel & (ctx.axis == ax)
                B[on, ax * m:(ax + 1) * m] = ctx.w[on, None] * P[on]
            return B

        found = best_size(proj, [(d, cols(d), 0) for d in DEGREES], rank=True)
        if found is None:
            return None
        d, fitted = found
        m = fitted.B.shape[1] // 2  # monomials per component
        lo_x, hi_x = float(np.min(qx[sel])), float(np.max(qx[sel]))
        lo_y, hi_y = float(np.min(qy[sel])), float(np.max(qy[sel]))
        xs = np.linspace(lo_x, hi_x, 81)
        gx, gy = np.meshgrid(np.linspace(lo_x, hi_x, 41), np.linspace(lo_y, hi_y, 21))

        def warp(x, y, c):
            P = _monomials((np.asarray(x) - cx) / h, (np.asarray(y) - cy) / h, d)
            return P @ c[:m], P @ c[m:]

        def shape(x, c):  # the warp's size along the image's middle row
            wx, wy = warp(x, np.full(len(np.asarray(x)), cy), c)
            return np.hypot(wx, wy)

        def describe(c):
            wx, wy = warp(gx.ravel(), gy.ravel(), c)
            mag = np.hypot(wx, wy)
            k = int(np.argmax(mag))
            # d w / d (x, y) at the centre (the first monomials are v, then u)
            lin = np.array([[c[1], c[0]], [c[m + 1], c[m]]]) / h
            params = {"degree": d, "max_displacement_mm": float(mag[k]),
                      "at_mm": [float(gx.ravel()[k]), float(gy.ravel()[k])],
                      "rms_displacement_mm": float(np.sqrt(np.mean(mag ** 2))),
                      "centre_mm": [cx, cy], "scale_mm": h,
                      "linear_per_mm": lin.tolist(),
                      "coefficients_x": [float(v) for v in c[:m]],
                      "coefficients_y": [float(v) for v in c[m:]]}
            kind = {1: "an affine warp (a scale that differs between x and y, or a shear)",
                    2: "a keystone (quadratic) warp", 3: "a cubic warp"}[d]
            why = {1: "the pixels are not square or the mm per px differs in x and y",
                   2: "the camera does not face the track squarely",
                   3: "the lens distorts beyond its radial term"}[d]
            text = (f"every point of the image is displaced by up to {mag[k]:.2g} mm in "
                    f"{kind}: {why}")
            return params, text

        return Choice(cls.name, "q", fitted, names(ctx, sel), None, None, None, shape, xs,
                      "mm", "mm (image x along the middle row)", describe,
                      label=f"polynomial warp of degree {d}", rows=sel,
                      row_coord=qx, row_coord_name="image x of the point (mm)",
                      extra={"rank": True},
                      ambiguity=("a recording of a calibration target where the robot "
                                 "drives would tell the camera's warp from the track's "
                                 "motion"))
