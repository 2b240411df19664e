"""`fit-lug calibrate`: board images -> calib.json (intrinsics, and the scale when asked)."""

from __future__ import annotations

import argparse
import glob
import os

import numpy as np

from .._errors import InputError
from ._common import stage

_GLOB_CHARS = set("*?[")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Calibrate the camera from images of a chessboard or ChArUco board and write "
        "calib.json (OpenCV conventions). With --scale-points or --scale-image the scale "
        "of the plane of motion (mm per pixel) is stored too.")
    parser.add_argument("images", nargs="+", metavar="IMAGES",
                        help="board images: files, glob patterns or folders")
    parser.add_argument("--board", required=True,
                        help="chessboard:COLSxROWS (inner corners, e.g. chessboard:9x6) or "
                             "charuco:XxY (squares, e.g. charuco:5x7)")
    parser.add_argument("--square", type=float, required=True, metavar="MM",
                        help="side of a board square, mm")
    parser.add_argument("--marker", type=float, metavar="MM",
                        help="ChArUco marker side, mm")
    parser.add_argument("--dict", dest="dictionary", default="DICT_6X6_250",
                        help="ChArUco dictionary (default DICT_6X6_250)")
    parser.add_argument("--fix-aspect", action="store_true",
                        help="fix fx/fy = 1 (cv2.CALIB_FIX_ASPECT_RATIO)")
    parser.add_argument("--subpix-window", type=int, metavar="PX",
                        help="chessboard corner refinement half-window, px (default: fitted "
                             "to the squares; OpenCV's sample uses 11)")
    scale = parser.add_mutually_exclusive_group()
    scale.add_argument("--scale-points", metavar="X1,Y1,X2,Y2,MM",
                       help="two image points (px, in the calibrated camera's images) a known "
                            "distance MM apart in the plane of motion")
    scale.add_argument("--scale-image", metavar="IMG",
                       help="an image of the same board lying in the plane of motion")
    parser.add_argument("-o", "--output", default="calib.json", help="output (calib.json)")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar or summary")


def expand_images(patterns: list[str]) -> list[str]:
    """Image files named by paths, glob patterns or folders, in order, without repeats."""
    from ..vision.read._source import IMAGE_SUFFIXES, _natural_key

    files: list[str] = []
    for pattern in patterns:
        if os.path.isdir(pattern):
            names = [n for n in os.listdir(pattern)
                     if n.lower().endswith(IMAGE_SUFFIXES) and not n.startswith(".")]
            found = [os.path.join(pattern, n) for n in sorted(names, key=_natural_key)]
            if not found:
                raise InputError(pattern, "the folder holds no images (" +
                                 ", ".join(IMAGE_SUFFIXES) + ")")
        elif _GLOB_CHARS & set(pattern):
            found = sorted(glob.glob(pattern), key=_natural_key)
            if not found:
                raise InputError(pattern, "the pattern matches no file")
        elif os.path.isfile(pattern):
            found = [pattern]
        else:
            raise InputError(pattern, "no such file or folder")
        files += [f for f in found if f not in files]
    return files


def _parse_scale_points(text: str):
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 5 or not np.isfinite(values).all():
        raise InputError("--scale-points", f"expected X1,Y1,X2,Y2,MM (five numbers), got {text!r}")
    return values[:2], values[2:4], values[4]


def _summary(cal, n_images: int) -> str:
    k, d = cal.camera_matrix, cal.dist_coeffs
    std = cal.std or {}
    name = os.path.basename
    errors = [v["rms_px"] for v in cal.per_view]
    lines = [
        f"calibrated from {len(cal.per_view)} of {n_images} images ({cal.board}), "
        f"{cal.image_size[0]}x{cal.image_size[1]} px",
        f"  f  = {k[0, 0]:.2f}, {k[1, 1]:.2f} px  (+- {std.get('fx', np.nan):.2f}, "
        f"{std.get('fy', np.nan):.2f})",
        f"  c  = {k[0, 2]:.2f}, {k[1, 2]:.2f} px  (+- {std.get('cx', np.nan):.2f}, "
        f"{std.get('cy', np.nan):.2f})",
        "  distortion (k1 k2 p1 p2 k3) = " + " ".join(f"{v:.5g}" for v in d),
        f"  RMS reprojection error {cal.rms_px:.3f} px (views {min(errors):.3f} .. "
        f"{max(errors):.3f} px)",
    ]
    outliers = [v for v in cal.per_view if v["outlier"]]
    if outliers:
        lines.append("  outlier views (RMS > 3x the median; consider removing them): " +
                     ", ".join(f"{name(v['image'])} ({v['rms_px']:.2f} px)" for v in outliers))
    if cal.rejected:
        lines.append("  no board found in: " +
                     ", ".join(f"{name(r['image'])} ({r['reason']})" for r in cal.rejected))
    if cal.mm_per_px is not None:
        lines.append(f"  scale {cal.mm_per_px:.6g} mm/px ({cal.scale['method']})")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    import cv2

    from ..vision.calibrate._calib_board import parse_board
    from ..vision.calibrate._calib_io import save_calibration
    from ..vision.calibrate._calibrate import calibrate, scale_from_board, scale_from_points

    try:
        board = parse_board(args.board, args.square, args.marker, args.dictionary)
    except ValueError as exc:
        raise InputError("--board", str(exc)) from None
    images = expand_images(args.images)
    flags = cv2.CALIB_FIX_ASPECT_RATIO if args.fix_aspect else 0
    stage(args, "calibrate", f"{len(images)} images; looking for the board "
                             f"({board.describe()}) in each (seconds an image)")

    def on_image(k, n, name, reason):
        stage(args, "calibrate", f"{k + 1}/{n} {os.path.basename(name)}: "
                                 + ("board found" if reason is None else reason))

    cal = calibrate(images, board, square_mm=args.square, flags=flags,
                    subpix_window=args.subpix_window, progress=False, on_image=on_image)
    if args.scale_points:
        p1, p2, mm = _parse_scale_points(args.scale_points)
        try:
            cal.mm_per_px = scale_from_points(p1, p2, mm, cal)
        except ValueError as exc:
            raise InputError("--scale-points", str(exc)) from None
        cal.scale = {"method": "points", "p1_px": p1, "p2_px": p2, "distance_mm": mm}
    elif args.scale_image:
        cal.mm_per_px = scale_from_board(args.scale_image, board, args.square, cal)
        cal.scale = {"method": "board", "image": args.scale_image}
    save_calibration(args.output, cal)
    if not args.quiet:
        print(_summary(cal, len(images)))
        print(f"wrote {args.output}")
    return 0
