"""`fit-lug noise SOURCE`: tracker noise per marker type on a stationary recording."""

from __future__ import annotations

import argparse
import os

from ._common import progress_enabled


MIN_FRAMES = 10  # fitlug.vision.noise_from_tracks: samples a marker needs


def _frames_arg(text: str) -> int:
    """--frames: 0 (all) or at least MIN_FRAMES, refused at parsing otherwise."""
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if n != 0 and n < MIN_FRAMES:
        raise argparse.ArgumentTypeError(f"{text}: too few frames, the noise needs at least "
                                         f"{MIN_FRAMES} (0: all)")
    return n


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Track the markers of a recording of a stationary robot and print the standard "
        "deviation of their positions per marker type (and per marker), in px and, with a "
        "scale, in mm. The reference rig used 100 frames.")
    parser.add_argument("source", metavar="SOURCE", help="video file, folder of frames or .cine")
    parser.add_argument("--fps", type=float, help="frame rate, Hz (not needed for the noise)")
    parser.add_argument("--frames", type=_frames_arg, default=100, metavar="N",
                        help=f"use the first N frames, at least {MIN_FRAMES} "
                             "(default 100; 0: all)")
    scale = parser.add_mutually_exclusive_group()
    scale.add_argument("--calib", metavar="CALIB_JSON", help="camera calibration, for mm")
    scale.add_argument("--mm-per-px", type=float, metavar="S", help="scale, for mm")
    scale.add_argument("--scale-points", metavar="X1,Y1,X2,Y2,MM",
                       help="two image points (px) a known distance MM apart, for mm")
    parser.add_argument("--kinds", default="cog,qs", help="marker types (default cog,qs)")
    parser.add_argument("--roles", metavar="KIND=ROLE,...", help="roles per marker type")
    parser.add_argument("--cog-radius", type=float, metavar="PX", help="COG disc radius, px")
    parser.add_argument("--qs-half", type=float, metavar="PX", help="half side of QS checkers, px")
    parser.add_argument("--json", metavar="PATH", help="also write the figures as JSON")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar")


def run(args) -> int:
    from ..io import write_json
    from ..vision import format_noise, noise_from_tracks, open_source, track
    from ._track import _config, calibration_from_args

    args.max_gap, args.redetect_every = 8, 200
    config = _config(args)
    frames = None if args.frames <= 0 else slice(0, args.frames)
    fps = args.fps
    if fps is None:
        fps = 1.0 if os.path.isdir(args.source) else None  # time plays no part in the noise
    with open_source(args.source, fps=fps, frames=frames) as src:
        if len(src) < MIN_FRAMES:  # before the tracker: "no marker found" would mislead
            from .._errors import InputError

            raise InputError(args.source, f"too few frames: {len(src)}, the noise needs at "
                                          f"least {MIN_FRAMES}")
        h, w = src.shape
        cal = None
        if args.calib or args.mm_per_px is not None or args.scale_points:
            cal = calibration_from_args(args, (w, h))
        result = track(src, config=config, progress=progress_enabled(args))
    noise = noise_from_tracks(result, cal)
    print(format_noise(noise))
    if args.json:
        write_json(args.json, {"frames": noise.frames, "per_role": noise.per_role,
                               "per_marker": noise.per_marker})
    return 0
