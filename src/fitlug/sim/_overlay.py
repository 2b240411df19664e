"""Tracked markers drawn on the frames, to check the tracking by eye (PNG or video)."""

from __future__ import annotations

import os

import numpy as np

from ..io._atomic import atomic_path

_COLOURS = {"lug": (0, 200, 255), "body": (80, 255, 80)}  # BGR: orange-yellow, green


def _to_bgr(frame: np.ndarray) -> np.ndarray:
    import cv2

    img = np.asarray(frame, dtype=np.float64)
    finite = img[np.isfinite(img)]
    hi = float(finite.max()) if finite.size else 1.0
    scale = 255.0 / (4095.0 if hi > 255 and hi <= 4095 else 65535.0 if hi > 4095 else 255.0)
    grey = np.clip(np.nan_to_num(img) * scale, 0, 255).astype(np.uint8)
    return cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)


def draw_markers(frame: np.ndarray, xy_px: np.ndarray, labels, roles, *, trails=None,
                 radius: float = 12.0) -> np.ndarray:
    """A BGR copy of `frame` with a circle, a cross and the label at each marker.

    xy_px: (M, 2) positions (NaN: not drawn); labels, roles: (M,) strings; trails: optional
    (K, M, 2) recent positions drawn as lines. Returns (H, W, 3) uint8.
    """
    import cv2

    img = _to_bgr(frame)
    shift = 4  # sub-pixel drawing: coordinates in 1/16 px
    k = 1 << shift
    for m, (x, y) in enumerate(np.asarray(xy_px, dtype=np.float64)):
        if not (np.isfinite(x) and np.isfinite(y)):
            continue
        colour = _COLOURS.get(roles[m], (255, 255, 255))
        c = (int(round(x * k)), int(round(y * k)))
        cv2.circle(img, c, int(radius * k), colour, 1, cv2.LINE_AA, shift)
        for dx, dy in ((1, 0), (0, 1)):
            a = (int(round((x - 4 * dx) * k)), int(round((y - 4 * dy) * k)))
            b = (int(round((x + 4 * dx) * k)), int(round((y + 4 * dy) * k)))
            cv2.line(img, a, b, colour, 1, cv2.LINE_AA, shift)
        cv2.putText(img, str(labels[m]), (int(x + radius + 2), int(y - radius - 2)),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.45, colour, 1, cv2.LINE_AA)
        if trails is not None:
            pts = np.asarray(trails)[:, m]
            pts = pts[np.isfinite(pts).all(axis=1)]
            if len(pts) > 1:
                poly = np.rint(pts * k).astype(np.int32).reshape(-1, 1, 2)
                cv2.polylines(img, [poly], False, colour, 1, cv2.LINE_AA, shift)
    return img


def overlay_png(frame: np.ndarray, result, path: str | os.PathLike, *, row: int | None = None,
                trail: int = 30) -> int:
    """Write a PNG of `frame` with the markers of `result` (a TrackResult) at row `row` of
    its frames (default: the row with the most markers found), with their recent tracks;
    or with the markers of a `Detections` (one frame, labelled by kind and number).

    Returns the frame number drawn (-1 for Detections). The file is written atomically.
    """
    import cv2

    if hasattr(result, "kind"):  # Detections of one frame
        roles = ["lug" if k == "cog" else "body" for k in result.kind]
        labels = [f"{k}{i}" for i, k in enumerate(result.kind)]
        img = draw_markers(frame, result.xy, labels, roles)
        with atomic_path(path, suffix=".png") as tmp:
            if not cv2.imwrite(tmp, img):
                raise OSError(f"could not write {path}")
        return -1
    found = np.isfinite(result.xy_px[..., 0]).sum(axis=1)
    if row is None:
        row = int(np.argmax(found))
    trails = result.xy_px[max(0, row - trail):row + 1]
    img = draw_markers(frame, result.xy_px[row], result.markers, result.roles, trails=trails)
    with atomic_path(path, suffix=".png") as tmp:
        if not cv2.imwrite(tmp, img):
            raise OSError(f"could not write {path}")
    return int(result.frames[row])


def overlay_video(frames, result, path: str | os.PathLike, *, fps: float = 25.0,
                  trail: int = 30) -> int:
    """Write a video (MP4, codec mp4v) of (frame number, image) pairs with the tracked
    markers drawn; returns the number of frames written. Written atomically."""
    import cv2

    rows = {int(f): i for i, f in enumerate(result.frames)}
    n = 0
    with atomic_path(path, suffix=os.path.splitext(os.fspath(path))[1] or ".mp4") as tmp:
        writer = None
        try:
            for number, image in frames:
                i = rows.get(int(number))
                if i is None:
                    continue
                img = draw_markers(image, result.xy_px[i], result.markers, result.roles,
                                   trails=result.xy_px[max(0, i - trail):i + 1])
                if writer is None:
                    h, w = img.shape[:2]
                    writer = cv2.VideoWriter(tmp, cv2.VideoWriter_fourcc(*"mp4v"), fps, (w, h))
                    if not writer.isOpened():
                        raise OSError(f"could not open a video writer for {path}")
                writer.write(img)
                n += 1
        finally:
            if writer is not None:
                writer.release()
    return n
