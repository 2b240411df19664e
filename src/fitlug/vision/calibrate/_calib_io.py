"""calib.json: writing and reading a Calibration (OpenCV conventions: io/_calibration).

    {
      "format": "fitlug-calibration", "version": 1,
      "camera_matrix": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]],   (px; null: scale only)
      "dist_coeffs": [k1, k2, p1, p2, k3],                      (null: scale only)
      "image_size": [width, height],                            (px)
      "rms_px": 0.19,                                           (RMS reprojection error)
      "per_view": [{"image": "left01.jpg", "rms_px": 0.19, "outlier": false}, ...],
      "mm_per_px": 0.2134,                                      (null when unknown)
      "board": "chessboard:9x6, 25 mm squares", "flags": 2, "flag_names": [...],
      "std_px": {"fx": .., "fy": .., "cx": .., "cy": ..},
      "rejected": [{"image": .., "reason": ..}], "scale": {"method": "points", ...}
    }

`load_calibration` also reads OpenCV's own calibration YAML/XML (camera_matrix,
distortion_coefficients, image_width, image_height, avg_reprojection_error).
"""

from __future__ import annotations

import json
import math
import os

import numpy as np

from ..._errors import InputError
from ...io._atomic import write_text_atomic
from ...io._calibration import Calibration

_FLAG_NAMES = ("CALIB_USE_INTRINSIC_GUESS", "CALIB_FIX_ASPECT_RATIO",
               "CALIB_FIX_PRINCIPAL_POINT", "CALIB_ZERO_TANGENT_DIST", "CALIB_FIX_FOCAL_LENGTH",
               "CALIB_FIX_K1", "CALIB_FIX_K2", "CALIB_FIX_K3", "CALIB_FIX_K4", "CALIB_FIX_K5",
               "CALIB_FIX_K6", "CALIB_RATIONAL_MODEL", "CALIB_THIN_PRISM_MODEL",
               "CALIB_FIX_S1_S2_S3_S4", "CALIB_TILTED_MODEL", "CALIB_FIX_TAUX_TAUY")
_DIST_LENGTHS = (4, 5, 8, 12, 14)


def flag_names(flags: int) -> list[str]:
    """Names of the OpenCV calibration flags set in `flags`."""
    import cv2

    return [n for n in _FLAG_NAMES if hasattr(cv2, n) and flags & getattr(cv2, n)]


def _clean(x):
    # JSON has no NaN: an unknown number is written as null
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def calibration_to_dict(cal: Calibration) -> dict:
    return {
        "format": "fitlug-calibration",
        "version": 1,
        "camera_matrix": None if cal.camera_matrix is None else
        np.asarray(cal.camera_matrix, float).tolist(),
        "dist_coeffs": None if cal.dist_coeffs is None else
        np.asarray(cal.dist_coeffs, float).ravel().tolist(),
        "image_size": [int(cal.image_size[0]), int(cal.image_size[1])],
        "rms_px": _clean(None if cal.rms_px is None else float(cal.rms_px)),
        "per_view": [{"image": str(v["image"]), "rms_px": _clean(float(v["rms_px"])),
                      "outlier": bool(v["outlier"])} for v in cal.per_view],
        "mm_per_px": None if cal.mm_per_px is None else float(cal.mm_per_px),
        "board": cal.board,
        "flags": int(cal.flags),
        "flag_names": flag_names(int(cal.flags)) if cal.flags else [],
        "std_px": cal.std,
        "rejected": list(cal.rejected),
        "scale": cal.scale,
        "conventions": "OpenCV: pixel (0,0) = centre of the top-left pixel, y down; ground "
                       "mm: x = S*x_u, y = S*(height - y_u) after undistortion",
    }


def save_calibration(path: str | os.PathLike, cal: Calibration) -> None:
    """Write `cal` to `path` as calib.json, atomically (never half-written)."""
    write_text_atomic(path, _format(calibration_to_dict(cal)))


def _format(data: dict) -> str:
    # one key per line; numeric vectors and matrices on one line each, for people to read
    lines = []
    for key, value in data.items():
        numeric = isinstance(value, list) and all(
            isinstance(v, (int, float)) or (isinstance(v, list) and
                                            all(isinstance(x, (int, float)) for x in v))
            for v in value)
        if numeric:
            text = json.dumps(value, allow_nan=False)
        elif isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
            text = "[\n" + ",\n".join("    " + json.dumps(v, allow_nan=False)
                                       for v in value) + "\n  ]"
        else:
            text = json.dumps(value, allow_nan=False)
        lines.append(f"  {json.dumps(key)}: {text}")
    return "{\n" + ",\n".join(lines) + "\n}\n"


def _matrix(path, value, shape, key):
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise InputError(path, f"{key} must be numbers, got {value!r:.60}", place=key) from None
    if shape is not None and arr.shape != shape:
        raise InputError(path, f"{key} must have shape {shape}, got {arr.shape}", place=key)
    if not np.isfinite(arr).all():
        raise InputError(path, f"{key} contains NaN or infinite values", place=key)
    return arr


def calibration_from_dict(data: dict, path: str | None = None) -> Calibration:
    """Validate a calib.json dictionary. Raises InputError naming the key and the problem."""
    if not isinstance(data, dict):
        raise InputError(path, "calib.json must hold a JSON object")
    missing = [k for k in ("camera_matrix", "dist_coeffs", "image_size", "mm_per_px")
               if k not in data]
    if missing:
        raise InputError(path, "missing key(s) " + ", ".join(missing) +
                         " (use null for an unknown value)")
    size = _matrix(path, data["image_size"], (2,), "image_size")
    if (size <= 0).any() or (size != np.round(size)).any():
        raise InputError(path, f"image_size must be two positive integers [width, height], "
                         f"got {data['image_size']}", place="image_size")
    k = dist = None
    if data["camera_matrix"] is not None or data["dist_coeffs"] is not None:
        k = _matrix(path, data["camera_matrix"], (3, 3), "camera_matrix")
        if k[0, 0] <= 0 or k[1, 1] <= 0 or k[0, 1] != 0 or k[1, 0] != 0 or \
                not np.allclose(k[2], [0, 0, 1]):
            raise InputError(path, "camera_matrix must be [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] "
                             "with fx, fy > 0", place="camera_matrix")
        dist = _matrix(path, data["dist_coeffs"], None, "dist_coeffs").ravel()
        if dist.size not in _DIST_LENGTHS:
            raise InputError(path, f"dist_coeffs must have 4, 5, 8, 12 or 14 values, got "
                             f"{dist.size}", place="dist_coeffs")
    scale = data["mm_per_px"]
    if scale is not None:
        scale = float(_matrix(path, scale, (), "mm_per_px"))
        if scale <= 0:
            raise InputError(path, f"mm_per_px must be positive, got {scale}", place="mm_per_px")
    rms = data.get("rms_px")
    if rms is not None:
        rms = float(_matrix(path, rms, (), "rms_px"))
    per_view = data.get("per_view") or []
    if not isinstance(per_view, list) or not all(
            isinstance(v, dict) and {"image", "rms_px", "outlier"} <= v.keys() for v in per_view):
        raise InputError(path, "per_view must be a list of {image, rms_px, outlier}",
                         place="per_view")
    for v in per_view:
        if v["rms_px"] is not None:
            _matrix(path, v["rms_px"], (), "per_view rms_px")
    flags = data.get("flags") or 0
    if isinstance(flags, bool) or not isinstance(flags, int) or not 0 <= flags < 2 ** 31:
        raise InputError(path, f"flags must be an integer of OpenCV calibration flags, got "
                         f"{flags!r:.60}", place="flags")
    for key, kinds, what in (("rejected", (list,), "a list"),
                             ("scale", (dict,), "an object"),
                             ("std_px", (dict,), "an object"),
                             ("board", (str, dict), "a string or an object")):
        value = data.get(key)
        if value is not None and not isinstance(value, kinds):
            raise InputError(path, f"{key} must be {what} or null, got {value!r:.60}", place=key)
    return Calibration(k, dist, (int(size[0]), int(size[1])), rms_px=rms,
                       per_view=[dict(v) for v in per_view], mm_per_px=scale,
                       board=data.get("board"), flags=flags,
                       std=data.get("std_px"), rejected=list(data.get("rejected") or []),
                       scale=data.get("scale"), source=path)


def _load_opencv_storage(path: str) -> Calibration:
    import cv2

    fs = cv2.FileStorage(path, cv2.FILE_STORAGE_READ)
    try:
        if not fs.isOpened():
            raise InputError(path, "cannot be read as OpenCV YAML/XML")

        def node(name):
            n = fs.getNode(name)
            return None if n.empty() else n

        k, dist = node("camera_matrix"), node("distortion_coefficients")
        w, h = node("image_width"), node("image_height")
        if k is None or dist is None or w is None or h is None:
            raise InputError(path, "an OpenCV calibration file needs camera_matrix, "
                             "distortion_coefficients, image_width and image_height")
        err = node("avg_reprojection_error")
        data = {"camera_matrix": k.mat().tolist(), "dist_coeffs": dist.mat().ravel().tolist(),
                "image_size": [int(w.real()), int(h.real())], "mm_per_px": None,
                "rms_px": None if err is None else err.real(),
                "flags": int(node("flags").real()) if node("flags") is not None else 0}
    finally:
        fs.release()
    return calibration_from_dict(data, path)


def load_calibration(path: str | os.PathLike) -> Calibration:
    """Read calib.json (or OpenCV's calibration .yml/.yaml/.xml).

    Raises InputError naming the file for a missing or unreadable file, malformed JSON,
    missing keys, wrong shapes or non-finite numbers.
    """
    path = os.fspath(path)
    if path.lower().endswith((".yml", ".yaml", ".xml")):
        if not os.path.isfile(path):
            raise InputError(path, "no such file")
        return _load_opencv_storage(path)
    try:
        with open(path, "rb") as fh:
            raw = fh.read()
    except OSError as exc:
        raise InputError(path, f"cannot read: {exc.strerror or exc}") from None
    try:
        text = raw.decode("utf-8-sig")  # a BOM taken, as in the CSV reader
    except UnicodeDecodeError as exc:
        raise InputError(path, f"not UTF-8 text ({exc.reason})",
                         line=raw.count(b"\n", 0, exc.start) + 1) from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(path, f"not valid JSON: {exc.msg}", line=exc.lineno) from None
    except RecursionError:
        raise InputError(path, "not valid JSON: nested too deeply") from None
    return calibration_from_dict(data, path)
