"""`fit-lug track SOURCE`: markers in a video -> trajectories.csv (ground-frame mm)."""

from __future__ import annotations

import argparse
import os

from .._errors import InputError
from ._common import progress_enabled, say


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Find the COG markers (bright discs -> role lug) and QS markers (2x2 checkers -> "
        "role body) of a video file, a folder of frames or a .cine file, follow them with "
        "subpixel precision and write trajectories.csv in ground-frame mm (x along travel, "
        "y up). Frames where a marker is hidden or out of view are gaps.")
    parser.add_argument("source", metavar="SOURCE", help="video file, folder of frames or .cine")
    parser.add_argument("--fps", type=float, help="frame rate, Hz (needed for frame folders)")
    scale = parser.add_mutually_exclusive_group()
    scale.add_argument("--calib", metavar="CALIB_JSON",
                       help="camera calibration (fit-lug calibrate): undistortion and scale")
    scale.add_argument("--mm-per-px", type=float, metavar="S", help="scale of the plane of motion")
    scale.add_argument("--scale-points", metavar="X1,Y1,X2,Y2,MM",
                       help="two image points (px) a known distance MM apart")
    parser.add_argument("--origin-mm", metavar="X,Y",
                        help="ground point at the image's bottom-left corner, mm (default: "
                             "calib.json's scale.origin_mm, else 0,0)")
    parser.add_argument("--roles", metavar="KIND=ROLE,...",
                        help="roles per marker type (default cog=lug,qs=body)")
    parser.add_argument("--kinds", default="cog,qs", help="marker types to track (default cog,qs)")
    parser.add_argument("--cog-radius", type=float, metavar="PX",
                        help="COG disc radius, px (default: measured)")
    parser.add_argument("--qs-half", type=float, metavar="PX",
                        help="half side of the QS checkers, px (default: measured)")
    parser.add_argument("--frames", metavar="START:STOP", help="track only these frames")
    parser.add_argument("--max-gap", type=int, default=8,
                        help="frames a lost marker is searched for before its track ends")
    parser.add_argument("--redetect-every", type=int, default=200,
                        help="frames between searches of the whole frame for new markers")
    parser.add_argument("-o", "--output", default="trajectories.csv",
                        help="output (trajectories.csv)")
    parser.add_argument("--overlay", metavar="PNG", help="also draw the tracked markers on a frame")
    parser.add_argument("--overlay-frame", type=int, metavar="N",
                        help="the frame for --overlay (default: the one with most markers)")
    parser.add_argument("--overlay-video", metavar="MP4", help="also write a video with the tracks")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar or summary")


def _numbers(text: str, n: int, option: str) -> list[float]:
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        vals = []
    if len(vals) != n or not all(v == v and abs(v) != float("inf") for v in vals):
        raise InputError(option, f"expected {n} comma-separated numbers, got {text!r}")
    return vals


def calibration_from_args(args, image_size):
    """The Calibration asked for by --calib, --mm-per-px or --scale-points."""
    from ..vision import load_calibration, scale_calibration, scale_from_points

    if args.calib:
        cal = load_calibration(args.calib)
        if tuple(cal.image_size) != tuple(image_size):
            raise InputError(args.calib, f"the calibration is for {cal.image_size[0]}x"
                             f"{cal.image_size[1]} px images, the video's are {image_size[0]}x"
                             f"{image_size[1]} px", place="image_size")
        if cal.mm_per_px is None:
            raise InputError(args.calib, "the calibration has no scale (mm_per_px): give "
                             "--scale-points to fit-lug calibrate", place="mm_per_px")
        return cal
    if args.mm_per_px is not None:
        if not args.mm_per_px > 0:
            raise InputError("--mm-per-px", f"must be positive, got {args.mm_per_px}")
        return scale_calibration(args.mm_per_px, image_size)
    if args.scale_points:
        x1, y1, x2, y2, mm = _numbers(args.scale_points, 5, "--scale-points")
        try:
            s = scale_from_points((x1, y1), (x2, y2), mm)
        except ValueError as exc:
            raise InputError("--scale-points", str(exc)) from None
        return scale_calibration(s, image_size)
    raise InputError(args.source, "pixels need a scale to become mm: give --calib, "
                     "--mm-per-px or --scale-points")


def _config(args):
    from ..vision import TrackerConfig

    kinds = tuple(k.strip().lower() for k in args.kinds.split(",") if k.strip())
    bad = [k for k in kinds if k not in ("cog", "qs")]
    if bad or not kinds:
        raise InputError("--kinds", f"marker types are cog and qs, got {args.kinds!r}")
    roles = {"cog": "lug", "qs": "body"}
    if args.roles:
        for item in args.roles.split(","):
            kind, _, role = item.partition("=")
            kind, role = kind.strip().lower(), role.strip().lower()
            if kind not in roles or role not in ("lug", "body"):
                raise InputError("--roles", f"expected KIND=ROLE with KIND cog|qs and ROLE "
                                 f"lug|body, got {item!r}")
            roles[kind] = role
    for name in ("max_gap", "redetect_every"):
        if getattr(args, name) < 1:
            raise InputError("--" + name.replace("_", "-"), "must be at least 1")
    return TrackerConfig(kinds=kinds, roles=roles, cog_radius=args.cog_radius,
                         qs_half=args.qs_half, max_gap=args.max_gap,
                         redetect_every=args.redetect_every)


def _frames(text):
    if not text:
        return None
    start, sep, stop = text.partition(":")
    try:
        return slice(int(start) if start else None, int(stop) if stop else None) if sep \
            else slice(int(start), int(start) + 1)
    except ValueError:
        raise InputError("--frames", f"expected START:STOP frame numbers, got {text!r}") from None


def run(args) -> int:
    from ..io import write_trajectories
    from ..sim import overlay_png, overlay_video
    from ..vision import open_source, to_recording, track
    from ..vision.track._pipeline import iter_overlay_frames

    config = _config(args)
    selection = _frames(args.frames)
    with open_source(args.source, fps=args.fps, frames=selection) as src:
        h, w = src.shape
        fps = src.fps
        cal = calibration_from_args(args, (w, h))
        origin = None if args.origin_mm is None else _numbers(args.origin_mm, 2, "--origin-mm")
        result = track(src, config=config, progress=progress_enabled(args))
        rec = to_recording(result, cal, origin_mm=origin,
                           meta={"source": os.path.basename(os.path.normpath(args.source)),
                                 "fps": f"{fps:g}"})
        write_trajectories(args.output, rec)
        found = result.detection_rate
        say(args, f"wrote {args.output}: {len(result.markers)} markers "
                  f"({result.roles.count('body')} body, {result.roles.count('lug')} lug) over "
                  f"{result.frames.size} frames; samples found per marker "
                  f"{found.min():.0%}..{found.max():.0%} of its span")
        if args.overlay:
            row = None
            if args.overlay_frame is not None:
                hits = [i for i, f in enumerate(result.frames) if f == args.overlay_frame]
                if not hits:
                    raise InputError("--overlay-frame",
                                     f"frame {args.overlay_frame} was not tracked")
                row = hits[0]
            found_rows = result.xy_px[..., 0] == result.xy_px[..., 0]
            row = int(found_rows.sum(axis=1).argmax()) if row is None else row
            number = overlay_png(src.frame(int(result.frames[row])), result, args.overlay, row=row)
            say(args, f"wrote {args.overlay} (frame {number})")
    if args.overlay_video:
        n = overlay_video(iter_overlay_frames(args.source, result, fps=args.fps), result,
                          args.overlay_video, fps=min(fps, 30.0))
        say(args, f"wrote {args.overlay_video} ({n} frames)")
    return 0
