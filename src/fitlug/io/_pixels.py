"""Pixels to ground mm by a scale alone (no lens model), as `fit-lug track` maps them.

    x_mm = S * x_px,    y_mm = S * (H - y_px)

with S = mm_per_px and H the image height (the image's y axis points down, the ground
frame's up). This is the scale-only case of `fitlug.vision.Calibration` (same arithmetic),
kept here so that io, which vision writes through, never imports vision.
"""

from __future__ import annotations

from typing import Callable

import numpy as np


def scale_pixels_to_mm(mm_per_px: float, image_height: int = 0) -> Callable:
    """The mapping (..., 2) image points px -> (..., 2) ground mm for a scale `mm_per_px`
    (mm per pixel) and an image `image_height` (px); NaN in, NaN out.

    Raises:
        ValueError: `mm_per_px` not a positive number; (from the mapping) points whose last
            axis is not 2.
    """
    if not np.isfinite(mm_per_px) or mm_per_px <= 0:
        raise ValueError(f"mm_per_px must be a positive number, got {mm_per_px!r}")
    s, height = float(mm_per_px), int(image_height)

    def pixels_to_mm(xy_px) -> np.ndarray:
        u = np.asarray(xy_px, dtype=np.float64)
        if u.shape[-1:] != (2,):
            raise ValueError(f"points must have shape (..., 2), got {u.shape}")
        out = np.empty_like(u)
        out[..., 0] = s * u[..., 0]
        out[..., 1] = s * (height - u[..., 1])
        return out

    return pixels_to_mm
