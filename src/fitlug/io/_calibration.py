"""A camera calibration and the mapping from image pixels to ground millimetres.

Conventions (OpenCV's): pixel coordinates x right, y down, the centre of the top-left
pixel at (0, 0); camera matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] in px; distortion
coefficients (k1, k2, p1, p2, k3[, k4, k5, k6, ...]).

Ground frame (trajectories.csv): the plane of motion, seen square-on, in mm, x along the
image's x, y UP. A pixel (x, y) is first undistorted to (x_u, y_u) (`cv2.undistortPoints`
with P = camera matrix, so it stays in pixels of the same camera) and then

    x_mm = S * x_u,    y_mm = S * (H - y_u)

with S = mm_per_px and H the image height: the origin is the image point (0, H), the
bottom-left corner of the image (to half a pixel). Without intrinsics (a scale only), the
undistortion step is skipped.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._errors import InputError


@dataclass
class Calibration:
    """Camera intrinsics (optional) plus the scale of the plane of motion (optional).

    camera_matrix: (3, 3) px or None; dist_coeffs: (5,) (or 4/8/12/14) or None;
    image_size: (width, height) px; rms_px: RMS reprojection error of the calibration;
    per_view: [{"image", "rms_px", "outlier"}]; mm_per_px: scale S of the plane of motion;
    board: description of the board; flags: OpenCV calibration flags; std: one-sigma of
    fx, fy, cx, cy (px); rejected: [{"image", "reason"}] views where no board was found;
    scale: how mm_per_px was found; source: the file it was loaded from (not saved).
    """

    camera_matrix: np.ndarray | None
    dist_coeffs: np.ndarray | None
    image_size: tuple[int, int]
    rms_px: float | None = None
    per_view: list[dict] = field(default_factory=list)
    mm_per_px: float | None = None
    board: str | None = None
    flags: int = 0
    std: dict | None = None
    rejected: list[dict] = field(default_factory=list)
    scale: dict | None = None
    source: str | None = None

    @classmethod
    def from_scale(cls, mm_per_px: float, image_size: tuple[int, int]) -> "Calibration":
        """A scale-only calibration (no lens model): pixels map to mm by S and the y flip."""
        if not np.isfinite(mm_per_px) or mm_per_px <= 0:
            raise ValueError(f"mm_per_px must be a positive number, got {mm_per_px!r}")
        return cls(None, None, (int(image_size[0]), int(image_size[1])),
                   mm_per_px=float(mm_per_px), scale={"method": "given"})

    @property
    def has_intrinsics(self) -> bool:
        return self.camera_matrix is not None

    def outlier_views(self) -> list[str]:
        return [v["image"] for v in self.per_view if v.get("outlier")]

    def undistort_px(self, xy_px) -> np.ndarray:
        """Undistorted pixel coordinates of (..., 2) points (NaN stays NaN). Identity without
        intrinsics."""
        xy = np.asarray(xy_px, dtype=np.float64)
        if xy.shape[-1:] != (2,):
            raise ValueError(f"points must have shape (..., 2), got {xy.shape}")
        if not self.has_intrinsics:
            return xy.copy()
        import cv2

        flat = xy.reshape(-1, 2)
        out = np.full_like(flat, np.nan)
        ok = np.isfinite(flat).all(axis=1)
        if ok.any():
            # the default 5 iterations leave ~5 mpx in the corners of a strong lens
            criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-12)
            und = cv2.undistortPoints(flat[ok].reshape(-1, 1, 2), self.camera_matrix,
                                      self.dist_coeffs, R=None, P=self.camera_matrix,
                                      criteria=criteria)
            out[ok] = und.reshape(-1, 2)
        return out.reshape(xy.shape)

    def distort_px(self, xy_u) -> np.ndarray:
        """Inverse of `undistort_px`: where an undistorted pixel point appears in the image."""
        xy = np.asarray(xy_u, dtype=np.float64)
        if not self.has_intrinsics:
            return xy.copy()
        import cv2

        k = self.camera_matrix
        flat = xy.reshape(-1, 2)
        out = np.full_like(flat, np.nan)
        ok = np.isfinite(flat).all(axis=1)
        if ok.any():
            rays = np.ones((int(ok.sum()), 3))
            rays[:, 0] = (flat[ok, 0] - k[0, 2]) / k[0, 0]
            rays[:, 1] = (flat[ok, 1] - k[1, 2]) / k[1, 1]
            img, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), k, self.dist_coeffs)
            out[ok] = img.reshape(-1, 2)
        return out.reshape(xy.shape)

    def _scale(self) -> float:
        if self.mm_per_px is None:
            raise InputError(self.source, "the calibration has no scale (mm_per_px): calibrate "
                             "with --scale-points or --scale-image", place="mm_per_px")
        return float(self.mm_per_px)

    def pixels_to_mm(self, xy_px) -> np.ndarray:
        """Ground-frame mm (..., 2) of image points (..., 2) px; NaN in, NaN out.

        Raises InputError when the calibration has no scale.
        """
        s = self._scale()
        u = self.undistort_px(xy_px)
        out = np.empty_like(u)
        out[..., 0] = s * u[..., 0]
        out[..., 1] = s * (self.image_size[1] - u[..., 1])
        return out

    def mm_to_pixels(self, xy_mm) -> np.ndarray:
        """Image points (..., 2) px of ground-frame points (..., 2) mm (inverse of pixels_to_mm)."""
        s = self._scale()
        xy = np.asarray(xy_mm, dtype=np.float64)
        if xy.shape[-1:] != (2,):
            raise ValueError(f"points must have shape (..., 2), got {xy.shape}")
        u = np.empty_like(xy)
        u[..., 0] = xy[..., 0] / s
        u[..., 1] = self.image_size[1] - xy[..., 1] / s
        return self.distort_px(u)
