"""One path in: detect a file's format from its content and read it as a `Recording`.

The content decides, never the extension alone (`.trk` is also TrackVis's tractography
format, `.csv` is everything). `detect_format` looks at the first bytes and lines;
`read_tracks` reads a foreign format as `Tracks`; `read_any` gives a `Recording` for any
known format, the canonical trajectories.csv included.
"""

from __future__ import annotations

import csv
import io
import os
import zipfile
from typing import TYPE_CHECKING, Callable

from .._errors import InputError
from ._files import read_bytes
from ._imported import Tracks
from ._recording import tracks_to_recording

if TYPE_CHECKING:
    from ._recording import Recording
    from ._rig import Rig

# format id -> what it is (the error for an unknown file lists these)
FORMATS = {
    "fitlug": "trajectories.csv, long or wide form (DATA.md)",
    "tracker": "OSP Tracker .trk (XML)",
    "tracker-trz": "OSP Tracker .trz (zip with the .trk)",
    "tracker-text": "OSP Tracker Export Data text",
    "dltdv": "DLTdv *xypts.csv",
    "argus": "Argus *xypts.csv (Track 1_cam_1_x, ...)",
    "kinovea-csv": "Kinovea trajectory CSV",
    "kinovea-txt": "Kinovea trajectory TXT",
    "deeplabcut": "DeepLabCut CSV",
    "deeplabcut-h5": "DeepLabCut .h5",
    "trackpy": "trackpy CSV (frame, particle, x, y)",
}
_HDF5 = b"\x89HDF\r\n\x1a\n"


def _unknown(path: str, why: str) -> InputError:
    known = "; ".join(FORMATS.values())
    return InputError(path, f"unknown format ({why}); known formats: {known}")


def _first_lines(head: bytes, n: int = 6) -> list[str]:
    try:
        text = head.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        text = head[:exc.start].decode("utf-8-sig", "ignore") if exc.start > 64 \
            else head.decode("latin-1")
    return [ln for ln in text.splitlines() if ln.strip()][:n]


def _cells(line: str) -> list[str]:
    delim = max((",", ";", "\t"), key=line.count)
    return [c.strip().strip('"') for c in next(csv.reader(io.StringIO(line), delimiter=delim))]


def detect_format(path: str | os.PathLike) -> str:
    """The format id (a key of `FORMATS`) of a file, from its content.

    Raises:
        InputError: a missing file, or one of no known format (the message lists them).
    """
    fmt, sure = sniff(path)
    if not sure:
        raise _unknown(os.fspath(path), "its header matches none")
    return fmt


def sniff(path: str | os.PathLike) -> tuple[str, bool]:
    """(format id, sure): a text file of no known format is ('fitlug', False), so that
    `read_trajectories` can name what is wrong with it as a trajectories.csv."""
    from ._fmt_dltdv import looks_like_dltdv
    from ._fmt_tracker import is_tracker_xml, looks_like_tracker_text
    from ._fmt_trackpy import looks_like_trackpy

    path = os.fspath(path)
    head = read_bytes(path, size=65536)
    if not head.strip():
        return "fitlug", False
    if head.startswith(b"\x1f\x8b"):  # gzip: read_trajectories decompresses a trajectories.csv
        fmt, sure = _sniff_gzip(path)
        if fmt == "fitlug":
            return fmt, sure
        what = "file compressed twice" if fmt == "gzip" else f"{fmt} file"
        raise _unknown(path, f"a gzip-compressed {what}: decompress it first (gunzip)")
    if head.startswith(_HDF5):
        return "deeplabcut-h5", True
    if head.startswith(b"PK\x03\x04"):
        try:
            with zipfile.ZipFile(path) as zf:
                trk = [n for n in zf.namelist() if n.lower().endswith(".trk")]
                if trk and is_tracker_xml(zf.read(trk[0])[:65536]):
                    return "tracker-trz", True
        except zipfile.BadZipFile:
            pass
        raise _unknown(path, "a zip file without a Tracker .trk inside")
    if head.startswith(b"TRACK"):
        raise _unknown(path, "a TrackVis tractography .trk, not an OSP Tracker file")
    lines = _first_lines(head)
    first = lines[0].lstrip("\ufeff").strip()
    if first.startswith("<"):
        if is_tracker_xml(head):
            return "tracker", True
        raise _unknown(path, "XML that is not an OSP Tracker TrackerPanel")
    if first.startswith("#Kinovea Trajectory data export"):
        return "kinovea-txt", True
    if first.startswith('"Time"'):
        return "kinovea-csv", True
    if _cells(first)[0] == "scorer":
        return "deeplabcut", True
    if looks_like_tracker_text(lines):
        return "tracker-text", True
    body = [ln for ln in lines if not ln.lstrip().startswith("#")]
    header = _cells(body[0]) if body else []
    xypts = looks_like_dltdv(header)
    if xypts:
        return xypts, True
    if looks_like_trackpy(header):
        return "trackpy", True
    if "time_s" in header or any(h.lower().endswith(("_x_mm", "_y_mm")) for h in header):
        return "fitlug", True
    return "fitlug", False


def read_tracks(path: str | os.PathLike, format: str | None = None, *,
                length_unit: str | None = None, y_origin: str | None = None,
                likelihood: float | None = None, fps: float | None = None,
                camera: int | None = None) -> Tracks:
    """Read another tracker's export as `Tracks` (positions in px and/or world mm).

    Args:
        path: the file.
        format: a key of `FORMATS` (default: detected from the content).
        length_unit: the world unit where the file does not write it (Tracker's exported
            text, Kinovea: 'px', 'mm', 'cm', 'm', ...) or to override Tracker's.
        y_origin: DLTdv X/Y files: 'top' (DLTdv8) or 'bottom' (DLTdv7); Argus files are
            'bottom' unless given; Kinovea in px: 'top' for its image-space export (the
            default is its world space, y up).
        camera: DLTdv and Argus: which camera's columns (1, 2, ...; default the first).
        likelihood: DeepLabCut: samples below it are missing (default 0.6, DLC's pcutoff).
        fps: Kinovea: tells a time column in ms, µs or frames from one in s.

    Raises:
        InputError: an unknown format, or a file that breaks its format (file, place,
            problem).
    """
    from . import _fmt_dlc, _fmt_dltdv, _fmt_kinovea, _fmt_tracker, _fmt_trackpy

    path = os.fspath(path)
    fmt = format or detect_format(path)
    lik = _fmt_dlc.DEFAULT_LIKELIHOOD if likelihood is None else likelihood
    readers: dict[str, Callable[[], Tracks]] = {
        "tracker": lambda: _fmt_tracker.read_trk(path, length_unit),
        "tracker-trz": lambda: _fmt_tracker.read_trz(path, length_unit),
        "tracker-text": lambda: _fmt_tracker.read_tracker_text(path, length_unit),
        "dltdv": lambda: _fmt_dltdv.read_dltdv(path, y_origin, camera),
        "argus": lambda: _fmt_dltdv.read_dltdv(path, y_origin, camera),
        "kinovea-csv": lambda: _fmt_kinovea.read_kinovea_csv(path, length_unit, fps,
                                                                  y_origin),
        "kinovea-txt": lambda: _fmt_kinovea.read_kinovea_txt(path, length_unit, fps,
                                                                  y_origin),
        "deeplabcut": lambda: _fmt_dlc.read_dlc_csv(path, lik),
        "deeplabcut-h5": lambda: _fmt_dlc.read_dlc_h5(path, lik),
        "trackpy": lambda: _fmt_trackpy.read_trackpy_csv(path),
    }
    if fmt == "fitlug":
        raise InputError(path, "is already a trajectories.csv: read it with read_trajectories")
    if fmt not in readers:
        raise InputError("--format", f"unknown format {fmt!r}; known: {', '.join(FORMATS)}")
    return readers[fmt]()


def read_any(path: str | os.PathLike, *, format: str | None = None, rig: "Rig | None" = None,
             fps: float | None = None, pixels_to_mm: Callable | None = None,
             image_height: float | None = None, body=None, lug=None,
             length_unit: str | None = None, y_origin: str | None = None,
             likelihood: float | None = None, camera: int | None = None) -> "Recording":
    """A `Recording` from a file of any known format (detected from its content).

    The canonical trajectories.csv goes to `read_trajectories` unchanged; any other format
    is read by `read_tracks` and converted by `tracks_to_recording` (see both for the
    arguments).
    """
    fmt = format
    if fmt is None:
        fmt, sure = sniff(path)
        if not sure:
            return read_canonical(os.fspath(path), rig)
    if fmt == "fitlug":
        from ._trajectories import read_trajectories

        return read_trajectories(path, rig=rig)
    tracks = read_tracks(path, fmt, length_unit=length_unit, y_origin=y_origin,
                         likelihood=likelihood, fps=fps, camera=camera)
    return tracks_to_recording(tracks, pixels_to_mm=pixels_to_mm, image_height=image_height,
                               fps=fps, rig=rig, body=body, lug=lug)


def _sniff_gzip(path: str) -> tuple[str, bool]:
    """sniff() of a gzip file's content (its first 64 kB, through a temporary file)."""
    import gzip
    import tempfile
    import zlib

    try:
        with gzip.open(path, "rb") as fh:
            head = fh.read(65536)
    except (OSError, EOFError, zlib.error):
        return "fitlug", False  # read_trajectories names the damage
    if head.startswith(b"\x1f\x8b"):
        return "gzip", True
    with tempfile.TemporaryDirectory() as tmp:
        inner = os.path.join(tmp, "head")
        with open(inner, "wb") as fh:
            fh.write(head)
        try:
            return sniff(inner)
        except InputError:
            return "fitlug", False


def read_canonical(path: str, rig: "Rig | None") -> "Recording":
    """`read_trajectories` for a text file of no recognised format: its error, if any, also
    says that the file is no known tracker export either."""
    from ._trajectories import read_trajectories

    try:
        return read_trajectories(path, rig=rig)
    except InputError as exc:
        raise InputError(exc.path, f"{exc.problem} (nor is it another tracker's export: "
                         f"known formats are {', '.join(FORMATS)})", line=exc.line,
                         place=exc.place) from None
