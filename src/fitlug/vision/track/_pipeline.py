"""From a video to trajectories: track the markers, map pixels to ground millimetres.

`track(source)` follows the markers of a video file, frame folder, .cine file, a
`FrameSource` or an array of frames (F, H, W); `to_recording(result, calibration)` maps the
pixel tracks to the ground frame of MODEL.md (x along travel, y up, mm) as a
`fitlug.io.Recording` ready for `write_trajectories`.
"""

from __future__ import annotations

import os
from typing import Iterable

import numpy as np

from ..._errors import InputError
from ...io._calibration import Calibration
from ._track import TrackerConfig, TrackResult, track_frames


def _array_frames(frames: np.ndarray, fps: float):
    for i in range(frames.shape[0]):
        yield i, i / fps, frames[i]


def track(source, *, fps: float | None = None, config: TrackerConfig | None = None,
          frames=None, progress: bool = False) -> TrackResult:
    """Track the COG and QS markers of a recording.

    source: a path (video file, folder of images, .cine; see `open_source`), a FrameSource,
    an array of frames (F, H, W), or an iterable of (frame_number, time_s, image).
    fps: frame rate, Hz (required where the source does not say it); frames: which file
    frames to use (`open_source`'s selection); progress: a progress bar on stderr.

    Raises InputError for an unreadable source, an unknown frame rate, or a recording in
    which no marker was found.
    """
    name = "<frames>"
    if isinstance(source, (str, os.PathLike)):
        from ..read._source import open_source

        name = os.fspath(source)
        with open_source(source, fps=fps, frames=frames) as src:
            result = track_frames(iter(src), config=config, total=len(src), progress=progress)
    elif isinstance(source, np.ndarray):
        if source.ndim != 3:
            raise InputError(None, f"an array of frames must have shape (F, H, W), got "
                                   f"{source.shape}")
        if fps is None or not np.isfinite(fps) or fps <= 0:
            raise InputError(None, "fps (frames per second) is needed for an array of frames")
        result = track_frames(_array_frames(source, float(fps)), config=config,
                              total=source.shape[0], progress=progress)
    elif hasattr(source, "indices") and hasattr(source, "fps"):  # a FrameSource
        name = getattr(source, "path", name)
        result = track_frames(iter(source), config=config, total=len(source), progress=progress)
    else:
        result = track_frames(source, config=config, progress=progress)
    if not result.markers:
        raise InputError(name, "no COG or QS marker was found in the recording (markers are "
                         "bright discs >= 8 px across or 2x2 checkers)")
    return result


def scale_calibration(mm_per_px: float, image_size: tuple[int, int]) -> Calibration:
    """A calibration that is only a scale: x_mm = S x_px, y_mm = S (H - y_px)."""
    return Calibration.from_scale(mm_per_px, image_size)


def origin_of(calibration: Calibration) -> np.ndarray:
    """The ground point (mm) at the image's bottom-left corner: calib.json's
    scale.origin_mm when given (rendered videos carry it), else (0, 0)."""
    scale = calibration.scale or {}
    origin = scale.get("origin_mm") if isinstance(scale, dict) else None
    if origin is None:
        return np.zeros(2)
    arr = np.asarray(origin, dtype=np.float64).ravel()
    if arr.shape != (2,) or not np.isfinite(arr).all():
        raise InputError(calibration.source, f"scale.origin_mm must be two numbers, got {origin!r}",
                         place="scale.origin_mm")
    return arr


def to_recording(result: TrackResult, calibration: Calibration, *, origin_mm=None,
                 meta: dict | None = None):
    """The tracks as a `fitlug.io.Recording` in ground-frame mm.

    Pixels are undistorted and scaled by `calibration` (`Calibration.pixels_to_mm`: y up,
    origin at the image's bottom-left corner), then shifted by origin_mm (default:
    `origin_of(calibration)`). Every (frame, marker) pair is a sample; gaps are NaN.
    """
    from ...io import Recording

    f, m = result.xy_px.shape[:2]
    origin = origin_of(calibration) if origin_mm is None else np.asarray(origin_mm, float)
    mm = calibration.pixels_to_mm(result.xy_px.reshape(-1, 2)).reshape(f, m, 2) + origin
    order = np.arange(f * m).reshape(f, m).T.ravel()  # marker by marker, in time order
    rows, cols = np.divmod(order, m)
    info = {"source": "fitlug track", "units": "mm"}
    if result.times.size > 1:
        step = float(np.median(np.diff(result.times)))
        if step > 0:
            info["fps"] = f"{1.0 / step:.10g}"
    info.update(meta or {})
    return Recording(markers=tuple(result.markers), roles=tuple(result.roles),
                     t=result.times[rows], marker_index=cols.astype(np.int64),
                     x=mm[rows, cols, 0], y=mm[rows, cols, 1], frame=result.frames[rows],
                     x_px=result.xy_px[rows, cols, 0], y_px=result.xy_px[rows, cols, 1],
                     quality=result.quality[rows, cols], meta=info)


def iter_overlay_frames(source, result: TrackResult, *, fps=None) -> Iterable:
    """(frame number, image) of the tracked frames of `source`, for overlay videos."""
    from ..read._source import open_source

    wanted = set(int(v) for v in result.frames)
    with open_source(source, fps=fps) as src:
        for number, _, image in src:
            if number in wanted:
                yield number, image
