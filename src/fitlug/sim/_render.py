"""Render marker positions as camera frames, with exact pixel coverage (for tests and demos).

The scene: a uniform background; each lug marker (role `lug`) is a COG marker, a bright
disc on a darker disc (the lug); each body marker (role `body`) is a QS marker, an
axis-aligned 2x2 checker. Shapes are drawn with their exact area coverage of every pixel
(closed form, `_coverage`), motion blur averages the coverage over sub-frame positions
across the exposure, then come the lighting gradient and vignetting (a gain on the whole
scene), Gaussian sensor noise and rounding to 8 bits.

Geometry: a ground-frame point (mm) is shifted by `origin_mm` (the ground point that sits
at the image's bottom-left corner) and mapped to pixels by the camera's
`Calibration.mm_to_pixels` (scale, y flip, lens distortion). Markers are drawn at their
distorted centres with their undistorted shape (the distortion across one marker is far
below the noise). The true position of a marker in a frame is the mean of its distorted
sub-frame centres: the centre of what was drawn.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..io._calibration import Calibration
from ._coverage import disc_coverage, interval_overlap

KINDS = {"lug": "cog", "body": "qs"}


@dataclass(frozen=True)
class RenderOptions:
    """How markers and the camera's imperfections are drawn.

    Sizes in mm on the plane of motion; grey levels before the gain (0..255).
    gradient: fractional change of the illumination from the left to the right edge and
        from the top to the bottom edge; vignetting: fractional loss in the corners.
    noise_sigma: standard deviation of the sensor noise, grey levels (before rounding).
    exposure_s: exposure time (motion blur); n_sub: positions averaged across it.
    occluders: rectangles (x0, y0, x1, y1) in px drawn over the markers at `occluder_level`.
    marker_scale, marker_contrast: factors per marker, in the order the markers are drawn
        (markers past the tuple's end: 1) on its size (a COG's discs, a QS's square) and on
        its light part's level above its dark part (a COG's bright disc over its lug, a QS's
        light quarters over its dark ones): markers of different sizes, dim markers.
    """

    cog_diameter_mm: float = 6.0
    lug_diameter_mm: float = 12.0
    qs_size_mm: float = 10.0
    background: float = 70.0
    lug_level: float = 25.0
    cog_level: float = 215.0
    qs_dark: float = 25.0
    qs_light: float = 215.0
    gradient: tuple[float, float] = (0.3, 0.15)
    vignetting: float = 0.1
    noise_sigma: float = 2.0
    exposure_s: float = 0.002
    n_sub: int = 7
    occluders: tuple = ()
    occluder_level: float = 40.0
    marker_scale: tuple = ()
    marker_contrast: tuple = ()

    def replace(self, **changes) -> "RenderOptions":
        return dataclasses.replace(self, **changes)


def default_camera(mm_per_px: float = 0.39, image_size: tuple[int, int] = (1632, 1200), *,
                   focal_px: float = 2000.0,
                   dist_coeffs=(-0.02, 0.0, 0.0, 0.0, 0.0)) -> Calibration:
    """A camera looking square-on at the plane of motion with a mild barrel distortion.

    image_size: (width, height) px; the principal point is the image centre.
    """
    w, h = int(image_size[0]), int(image_size[1])
    if dist_coeffs is None:
        return Calibration.from_scale(mm_per_px, (w, h))
    k = np.array([[focal_px, 0.0, (w - 1) / 2], [0.0, focal_px, (h - 1) / 2], [0, 0, 1.0]])
    return Calibration(k, np.asarray(dist_coeffs, dtype=np.float64), (w, h), rms_px=0.0,
                       mm_per_px=float(mm_per_px), scale={"method": "rendered"})


def auto_origin(xy_mm: np.ndarray, camera: Calibration) -> tuple[float, float]:
    """Ground point (mm, whole mm) for the image's bottom-left corner that centres the markers."""
    pts = np.asarray(xy_mm, dtype=np.float64).reshape(-1, 2)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if pts.size == 0:
        return (0.0, 0.0)
    centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    w, h = camera.image_size
    half = 0.5 * camera.mm_per_px * np.array([w, h], dtype=np.float64)
    return tuple(float(v) for v in np.round(centre - half))


def ground_to_pixels(camera: Calibration, xy_mm, origin_mm=(0.0, 0.0)) -> np.ndarray:
    """Distorted image position (..., 2) px of ground-frame points (..., 2) mm."""
    xy = np.asarray(xy_mm, dtype=np.float64) - np.asarray(origin_mm, dtype=np.float64)
    return camera.mm_to_pixels(xy)


def subframe_positions(t: np.ndarray, xy: np.ndarray, exposure_s: float, n_sub: int) -> np.ndarray:
    """Positions (F, n_sub, M, 2) across each frame's exposure, centred on the frame time.

    xy: (F, M, 2) positions at the frame times t (F,); velocities from finite differences
    (one-sided at the ends and next to gaps).
    """
    f = xy.shape[0]
    if f < 2 or exposure_s <= 0 or n_sub <= 1:
        return np.repeat(xy[:, None], max(n_sub, 1), axis=1)
    dt = np.diff(t)[:, None, None]
    d = np.diff(xy, axis=0) / dt  # (F-1, M, 2): forward differences
    fwd = np.concatenate([d, np.full_like(d[:1], np.nan)])
    bwd = np.concatenate([np.full_like(d[:1], np.nan), d])
    vel = np.where(np.isfinite(fwd) & np.isfinite(bwd), 0.5 * (fwd + bwd),
                   np.where(np.isfinite(fwd), fwd, bwd))
    vel = np.where(np.isfinite(vel), vel, 0.0)
    tau = exposure_s * ((np.arange(n_sub) + 0.5) / n_sub - 0.5)
    return xy[:, None] + vel[:, None] * tau[None, :, None, None]


def _patch_bounds(pts: np.ndarray, reach: float, w: int, h: int):
    x0 = int(np.floor(np.nanmin(pts[:, 0]) - reach)) - 1
    x1 = int(np.ceil(np.nanmax(pts[:, 0]) + reach)) + 2
    y0 = int(np.floor(np.nanmin(pts[:, 1]) - reach)) - 1
    y1 = int(np.ceil(np.nanmax(pts[:, 1]) + reach)) + 2
    return max(x0, 0), min(x1, w), max(y0, 0), min(y1, h)


def _draw_cog(canvas, pts, r_cog, r_lug, opt: RenderOptions) -> None:
    h, w = canvas.shape
    x0, x1, y0, y1 = _patch_bounds(pts, r_lug, w, h)
    if x1 <= x0 or y1 <= y0:
        return
    n = pts.shape[0]
    cov_l = disc_coverage(pts[:, 0], pts[:, 1], np.full(n, r_lug), np.full(n, x0), np.full(n, y0),
                          x1 - x0, y1 - y0).mean(axis=0)
    cov_b = disc_coverage(pts[:, 0], pts[:, 1], np.full(n, r_cog), np.full(n, x0), np.full(n, y0),
                          x1 - x0, y1 - y0).mean(axis=0)
    patch = canvas[y0:y1, x0:x1]
    patch[...] = patch * (1 - cov_l) + opt.lug_level * (cov_l - cov_b) + opt.cog_level * cov_b


def _draw_qs(canvas, pts, half, opt: RenderOptions) -> None:
    h, w = canvas.shape
    x0, x1, y0, y1 = _patch_bounds(pts, half * 1.0, w, h)
    if x1 <= x0 or y1 <= y0:
        return
    cx, cy = pts[:, 0], pts[:, 1]
    # 1-D overlaps of the pixels with the left/right and top/bottom halves of the square
    left = interval_overlap(cx - half, cx, x0, x1 - x0)
    right = interval_overlap(cx, cx + half, x0, x1 - x0)
    top = interval_overlap(cy - half, cy, y0, y1 - y0)
    bottom = interval_overlap(cy, cy + half, y0, y1 - y0)
    light = (top[:, :, None] * left[:, None, :] + bottom[:, :, None] * right[:, None, :]).mean(0)
    dark = (top[:, :, None] * right[:, None, :] + bottom[:, :, None] * left[:, None, :]).mean(0)
    patch = canvas[y0:y1, x0:x1]
    patch[...] = patch * (1 - light - dark) + opt.qs_light * light + opt.qs_dark * dark


def gain_field(image_size: tuple[int, int], opt: RenderOptions) -> np.ndarray:
    """Illumination gain (H, W) float32: linear gradient times a quadratic vignetting."""
    w, h = image_size
    x = np.linspace(-0.5, 0.5, w, dtype=np.float32)
    y = np.linspace(-0.5, 0.5, h, dtype=np.float32)
    g = 1 + opt.gradient[0] * x[None, :] + opt.gradient[1] * y[:, None]
    r2 = (x[None, :] ** 2 + y[:, None] ** 2) / 0.5
    return (g * (1 - opt.vignetting * r2)).astype(np.float32)


def render_frame(sub_px: np.ndarray, kinds, camera: Calibration, opt: RenderOptions,
                 rng: np.random.Generator, gain: np.ndarray | None = None,
                 dtype=np.uint8) -> np.ndarray:
    """One frame (H, W) uint8 of markers at sub-frame pixel positions.

    sub_px: (n_sub, M, 2) distorted pixel positions across the exposure (NaN: not drawn);
    kinds: 'cog' or 'qs' per marker. Markers are drawn in order (later ones on top).
    """
    w, h = camera.image_size
    s = camera.mm_per_px
    canvas = np.full((h, w), opt.background, dtype=np.float64)
    for m, kind in enumerate(kinds):
        pts = sub_px[:, m]
        pts = pts[np.isfinite(pts).all(axis=1)]
        if pts.size == 0:
            continue
        f = opt.marker_scale[m] / s if m < len(opt.marker_scale) else 1.0 / s
        o = opt
        if m < len(opt.marker_contrast):
            c = float(opt.marker_contrast[m])
            o = opt.replace(cog_level=opt.lug_level + c * (opt.cog_level - opt.lug_level),
                            qs_light=opt.qs_dark + c * (opt.qs_light - opt.qs_dark))
        if kind == "cog":
            _draw_cog(canvas, pts, 0.5 * opt.cog_diameter_mm * f, 0.5 * opt.lug_diameter_mm * f,
                      o)
        else:
            _draw_qs(canvas, pts, 0.5 * opt.qs_size_mm * f, o)
    for x0, y0, x1, y1 in opt.occluders:
        rows = slice(max(int(y0), 0), max(int(y1), 0))
        canvas[rows, max(int(x0), 0):max(int(x1), 0)] = opt.occluder_level
    img = canvas.astype(np.float32)
    img *= gain_field((w, h), opt) if gain is None else gain
    if opt.noise_sigma > 0:
        img += np.float32(opt.noise_sigma) * rng.standard_normal(img.shape, dtype=np.float32)
    info = np.iinfo(dtype)
    return np.clip(np.rint(img), info.min, info.max).astype(dtype)
