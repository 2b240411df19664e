"""`fit-lug import FILE`: another tracker's export -> trajectories.csv (ground-frame mm).

The options that say how to read a foreign file (`add_source_options`) are shared with
`fit-lug FILE`, which converts on the way in (`recording_from_args`).
"""

from __future__ import annotations

import argparse

from .._errors import InputError
from ._common import say


def add_source_options(parser: argparse.ArgumentParser) -> None:
    """The options for reading a foreign format (fit-lug import, and fit-lug FILE)."""
    from ..io import FORMATS

    g = parser.add_argument_group("other trackers' files (format detected from the content)")
    g.add_argument("--format", choices=list(FORMATS), help="the file's format (default: detected)")
    g.add_argument("--fps", type=float, help="frame rate, Hz (for files without time stamps)")
    scale = g.add_mutually_exclusive_group()
    scale.add_argument("--mm-per-px", type=float, metavar="S",
                       help="scale of the plane of motion, for positions in pixels (y up)")
    scale.add_argument("--calib", metavar="CALIB_JSON",
                       help="camera calibration (fit-lug calibrate) for positions in pixels")
    g.add_argument("--body", metavar="NAME,...",
                   help="the body markers (every other marker is a lug)")
    g.add_argument("--length-unit", metavar="U",
                   help="world unit where the file does not say it (Tracker's exported text, "
                        "Kinovea): px, mm, cm, m, in")
    g.add_argument("--y-origin", choices=("top", "bottom"),
                   help="DLTdv X/Y files: pixel origin top-left (DLTdv8) or bottom-left (DLTdv7); "
                        "Argus files are bottom-left unless told; Kinovea in px: top for its "
                        "image-space export (default: its world space, y up)")
    g.add_argument("--camera", type=int, metavar="J",
                   help="DLTdv and Argus xypts files: which camera's columns (default the first)")
    g.add_argument("--likelihood", type=float, metavar="P",
                   help="DeepLabCut: samples below this likelihood are missing (default 0.6)")


def _calibration(args, tracks):
    """(pixels_to_mm, image height) from --calib or --mm-per-px, through the vision code of
    `fit-lug track`; (None, None) without either."""
    from ..vision import load_calibration, origin_of, scale_calibration

    if args.calib:
        cal = load_calibration(args.calib)
        if tracks.image_size and tuple(cal.image_size) != tuple(tracks.image_size):
            raise InputError(args.calib, f"the calibration is for {cal.image_size[0]}x"
                             f"{cal.image_size[1]} px images, the file's video is "
                             f"{tracks.image_size[0]}x{tracks.image_size[1]} px",
                             place="image_size")
    elif args.mm_per_px is not None:
        if not args.mm_per_px > 0 or args.mm_per_px == float("inf"):
            raise InputError("--mm-per-px", f"must be positive, got {args.mm_per_px}")
        cal = scale_calibration(args.mm_per_px, tracks.image_size or (0, 0))
    else:
        return None, None
    origin = origin_of(cal)
    return (lambda xy: cal.pixels_to_mm(xy) + origin), float(cal.image_size[1])


def recording_from_args(path: str, args, rig):
    """The Recording of `path` in any known format, read with the options of
    `add_source_options` (a canonical trajectories.csv is read as before)."""
    from ..io import read_trajectories, read_tracks, tracks_to_recording
    from ..io._formats import read_canonical, sniff

    fmt = getattr(args, "format", None)
    if fmt is None:
        fmt, sure = sniff(path)
        if not sure:
            return read_canonical(path, rig)
    if fmt == "fitlug":
        return read_trajectories(path, rig=rig)
    tracks = read_tracks(path, fmt, length_unit=args.length_unit, y_origin=args.y_origin,
                         likelihood=args.likelihood, fps=args.fps,
                         camera=getattr(args, "camera", None))
    to_mm, height = _calibration(args, tracks)
    body = [b.strip() for b in args.body.split(",") if b.strip()] if args.body else None
    return tracks_to_recording(tracks, pixels_to_mm=to_mm, image_height=height, fps=args.fps,
                               rig=rig, body=body)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Convert another tracker's export (OSP Tracker .trk/.trz/text, DLTdv and Argus "
        "xypts.csv, "
        "Kinovea CSV/TXT, DeepLabCut CSV/.h5, trackpy CSV) into trajectories.csv in "
        "ground-frame mm (x along travel, y up). The format is detected from the content.")
    parser.add_argument("file", metavar="FILE", help="the other program's export")
    parser.add_argument("-o", "--output", default="trajectories.csv",
                        help="output (default trajectories.csv)")
    parser.add_argument("--rig", help="rig.toml: roles from [markers], fps from [camera]")
    add_source_options(parser)
    parser.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")


def run(args) -> int:
    from ..io import read_rig, write_trajectories

    rig = read_rig(args.rig) if args.rig else None
    rec = recording_from_args(args.file, args, rig)
    write_trajectories(args.output, rec)
    n_valid = int(rec.valid.sum())
    say(args, f"wrote {args.output}: {rec.n_markers} markers ({rec.roles.count('body')} body, "
              f"{rec.roles.count('lug')} lug), {rec.times().size} frames, {n_valid} samples "
              f"found; source: {rec.meta.get('source', args.file)}")
    return 0
