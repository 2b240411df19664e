"""Camera calibration from board images, and the scale of the plane of motion.

`calibrate` finds the board in every image, runs `cv2.calibrateCameraExtended` and
reports the RMS reprojection error over all corners and per view. A view is flagged as an
outlier when its RMS exceeds 3 x the median of the views: ordinary views of one board
spread by a factor of about 2 (0.16-0.38 px in OpenCV's sample), a misdetected or blurred
view stands well apart (OpenCV's sample left02 at 1.18 px with its oversized corner window).
"""

from __future__ import annotations

import os
import sys
from typing import Callable, Sequence

import numpy as np

from ..._errors import InputError
from ...io._calibration import Calibration
from ._calib_board import Board, detect_corners, parse_board

OUTLIER_FACTOR = 3.0
MIN_VIEWS = 3
# no board in the first this many images: stop (each search of a board-less image takes
# up to ~12 s at 2 megapixels: 40 of them were 8 silent minutes)
GIVE_UP_AFTER = 10


def _load_grey(image, name: str) -> np.ndarray:
    """8-bit grey image from a path or an array (16-bit scaled down, colour converted)."""
    import cv2

    if isinstance(image, (str, os.PathLike)):
        img = cv2.imread(os.fspath(image), cv2.IMREAD_UNCHANGED)
        if img is None:
            problem = "no such file" if not os.path.exists(image) else "cannot be read as an image"
            raise InputError(name, problem)
    else:
        img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] in (3, 4):
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    elif img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim != 2:
        raise InputError(name, f"not an image: shape {img.shape}")
    if img.dtype != np.uint8:
        # the detectors want 8 bits: stretch the used range, which keeps corner geometry
        f = img.astype(np.float64)
        if not np.isfinite(f).all():
            raise InputError(name, "the image contains NaN or infinite values")
        lo, hi = f.min(), f.max()
        img = np.zeros(f.shape, np.uint8) if hi <= lo else \
            np.round(255 * (f - lo) / (hi - lo)).astype(np.uint8)
    return img


def _name(image, index: int) -> str:
    return os.fspath(image) if isinstance(image, (str, os.PathLike)) else f"image[{index}]"


def _common_folder(images) -> str | None:
    """The one path that names all the images (for error messages), or None."""
    paths = [os.fspath(i) for i in images if isinstance(i, (str, os.PathLike))]
    if len(paths) != len(images):
        return None
    if len(paths) == 1:
        return paths[0]
    return os.path.commonpath([os.path.abspath(p) for p in paths]) or None


def calibrate(images: Sequence, board: str | Board, *, square_mm: float,
              marker_mm: float | None = None, dictionary: str | None = None, flags: int = 0,
              subpix_window: int | None = None, progress: bool = False,
              on_image: Callable | None = None,
              give_up_after: int | None = GIVE_UP_AFTER) -> Calibration:
    """Calibrate the camera from images of a planar board.

    images: paths (or 2-D/colour arrays) of views of the board, all the same size.
    board: "chessboard:COLSxROWS" (inner corners) or "charuco:XxY" (squares), or a Board.
    square_mm: square side, mm; marker_mm, dictionary: ChArUco marker side (mm) and
        dictionary name (default DICT_6X6_250).
    flags: OpenCV calibration flags (e.g. cv2.CALIB_FIX_ASPECT_RATIO = 2).
    subpix_window: chessboard corner refinement half-window, px (default adaptive; 11
        reproduces OpenCV's calibration sample).
    progress: show a progress bar over the images (stderr, only on a terminal).
    on_image: called after each image as on_image(k, n, name, reason) with reason None
        when the board was found (a search takes up to ~12 s on a 2-megapixel image
        without a board: the CLI prints a line per image).
    give_up_after: stop with InputError when none of the first this many images shows
        the board (a wrong --board or images without it), rather than searching them all;
        None searches every image.

    Returns a Calibration with mm_per_px None (see scale_from_points / scale_from_board).
    Raises ValueError for a bad board spec, InputError naming the image for unreadable or
    mismatched images, when the board is found in fewer than 3 images, or in none of the
    first `give_up_after`.
    """
    import cv2
    from tqdm import tqdm

    board = parse_board(board, square_mm, marker_mm, dictionary)
    images = list(images)
    if not images:
        raise InputError(None, "no calibration images given")
    objs, pts, names, rejected = [], [], [], []
    size = None
    for k, image in enumerate(tqdm(images, desc="calibration images", unit="img", file=sys.stderr,
                                   disable=not (progress and sys.stderr.isatty()))):
        name = _name(image, k)
        grey = _load_grey(image, name)
        shape = (grey.shape[1], grey.shape[0])
        if size is None:
            size = shape
        elif shape != size:
            raise InputError(name, f"image is {shape[0]}x{shape[1]} px but the first one is "
                             f"{size[0]}x{size[1]}: calibrate one camera setting at a time")
        obj, img, reason = detect_corners(board, grey, subpix_window)
        if on_image is not None:
            on_image(k, len(images), name, None if obj is not None else reason)
        if obj is None:
            rejected.append({"image": name, "reason": reason})
            if (give_up_after and not objs and k + 1 == give_up_after
                    and len(images) > give_up_after):
                raise InputError(_common_folder(images), f"no board ({board.describe()}) in "
                                 f"the first {give_up_after} of {len(images)} images "
                                 f"({reason}); stopped early: check --board and that the "
                                 "images show the board")
            continue
        objs.append(obj)
        pts.append(img)
        names.append(name)
    if len(objs) < MIN_VIEWS:
        reasons: dict[str, list[str]] = {}
        for r in rejected:
            reasons.setdefault(r["reason"], []).append(os.path.basename(r["image"]))
        why = "; ".join(f"{', '.join(n)}: {reason}" for reason, n in reasons.items())
        raise InputError(_common_folder(images), f"the board ({board.describe()}) was found in "
                         f"{len(objs)} of {len(images)} images; need at least {MIN_VIEWS}" +
                         (f" ({why})" if why else ""))
    k0 = np.eye(3)  # fx = fy: the ratio CALIB_FIX_ASPECT_RATIO keeps
    rms, k, dist, _, _, std_in, _, per_view = cv2.calibrateCameraExtended(
        objs, pts, size, k0, None, flags=flags)
    per_view = np.asarray(per_view, float).ravel()
    limit = OUTLIER_FACTOR * float(np.median(per_view))
    std_in = np.asarray(std_in, float).ravel()
    std = {"fx": float(std_in[0]), "fy": float(std_in[1]), "cx": float(std_in[2]),
           "cy": float(std_in[3])}
    if flags & cv2.CALIB_FIX_ASPECT_RATIO:
        std["fx"] = std["fy"] * float(k[0, 0] / k[1, 1])  # fx is tied to fy
    return Calibration(
        camera_matrix=np.asarray(k, float), dist_coeffs=np.asarray(dist, float).ravel(),
        image_size=size, rms_px=float(rms),
        per_view=[{"image": n, "rms_px": float(e), "outlier": bool(e > limit)}
                  for n, e in zip(names, per_view)],
        board=board.describe(), flags=int(flags), std=std, rejected=rejected)


def _point(p, what: str) -> np.ndarray:
    arr = np.asarray(p, dtype=np.float64).ravel()
    if arr.shape != (2,) or not np.isfinite(arr).all():
        raise ValueError(f"{what} must be two finite numbers (x, y) in px, got {p!r}")
    return arr


def scale_from_points(p1_px, p2_px, distance_mm: float,
                      calibration: Calibration | None = None) -> float:
    """mm per px of the plane of motion from two image points `distance_mm` apart.

    With a calibration the points are undistorted first. Raises ValueError for
    non-finite points, coincident points or a non-positive distance.
    """
    a, b = _point(p1_px, "p1_px"), _point(p2_px, "p2_px")
    if not np.isfinite(distance_mm) or distance_mm <= 0:
        raise ValueError(f"distance_mm must be a positive distance, got {distance_mm!r}")
    if calibration is not None:
        a, b = calibration.undistort_px(np.stack([a, b]))
    d_px = float(np.hypot(*(b - a)))
    if d_px < 1.0:
        raise ValueError(f"the two points are {d_px:.3g} px apart: pick points far apart")
    return float(distance_mm) / d_px


def scale_from_board(image, board: str | Board, square_mm: float,
                     calibration: Calibration | None = None, *, marker_mm: float | None = None,
                     dictionary: str | None = None) -> float:
    """mm per px from a board lying in the plane of motion.

    The mean distance between neighbouring corners (along rows and columns), after
    undistortion when a calibration is given, is one square. Raises InputError when the
    board is not found in the image.
    """
    board = parse_board(board, square_mm, marker_mm, dictionary)
    name = _name(image, 0)
    grey = _load_grey(image, name)
    obj, img, ids = detect_corners(board, grey)
    if obj is None:
        raise InputError(name, f"scale image: {ids}")
    xy = img.reshape(-1, 2).astype(np.float64)
    if calibration is not None:
        xy = calibration.undistort_px(xy)
    cols, _ = board.corner_grid()
    where = {int(i): k for k, i in enumerate(ids)}
    gaps = []
    for i, k in where.items():
        right = where.get(i + 1) if (i + 1) % cols else None
        below = where.get(i + cols)
        for j in (right, below):
            if j is not None:
                gaps.append(np.hypot(*(xy[j] - xy[k])))
    return float(board.square_mm / np.mean(gaps))
