"""DLTdv (Hedrick lab) and Argus `*xypts.csv`: one header row, then one row per video frame.

DLTdv: columns `pt{i}_cam{j}_X, pt{i}_cam{j}_Y` (DLTdv 5 to 8.3) or `{point}_cam{j}_U,
{point}_cam{j}_V` (8.4 and later); values in pixels, `NaN` where a point is not digitised;
no frame or time column (row k is frame k, counted from 1). The origin is the image's
top-left corner in DLTdv8 and the bottom-left corner (y up) in DLTdv7 and earlier, which
wrote the same X/Y columns as 8.0-8.3: for X/Y files the caller must say which
(`y_origin` 'top' or 'bottom'); U/V files are always top-left.

Argus (argus_gui's clicker, which shares DLTdv's layout): columns `{track}_cam_{j}_x,
{track}_cam_{j}_y` (`Track 1_cam_1_x`), written by pandas (`NaN`, full-precision floats,
CRLF on Windows); the origin is the image's bottom-left corner, y up ("origin is lower left
in Argus and DLTdv 1-7", argus_gui/resources/scripts/argus-click, `load_dlc`), unless the
caller says otherwise.
"""

from __future__ import annotations

import csv
import re

import numpy as np

from .._errors import InputError
from ._imported import Tracks, numbers_column, read_text

COLUMN = re.compile(r"^(.+)_cam(\d+)_([XYUV])$")
ARGUS_COLUMN = re.compile(r"^(.+)_cam_(\d+)_([xy])$")


def _column(name: str) -> tuple[str, int, str, str] | None:
    """(point, camera, 'x' | 'y', style 'XY' | 'UV' | 'argus') of a header cell, or None."""
    m = COLUMN.match(name)
    if m:
        axis = m.group(3)
        return m.group(1), int(m.group(2)), "x" if axis in "XU" else "y", \
            "UV" if axis in "UV" else "XY"
    m = ARGUS_COLUMN.match(name)
    if m:
        return m.group(1), int(m.group(2)), m.group(3), "argus"
    return None


def looks_like_dltdv(header: list[str]) -> str | None:
    """'dltdv' when every header cell is a DLTdv `<point>_cam<j>_<X|Y|U|V>` column, 'argus'
    when every one is an Argus `<track>_cam_<j>_<x|y>` column, else None."""
    cells = [c.strip().strip('"') for c in header if c.strip()]
    styles = {c[3] if c else None for c in map(_column, cells)}
    if not cells or None in styles:
        return None
    return "argus" if styles == {"argus"} else "dltdv" if "argus" not in styles else None


def read_dltdv(path: str, y_origin: str | None = None, camera: int | None = None) -> Tracks:
    """Points of one camera of a DLTdv or Argus xypts.csv, in pixels.

    Args:
        path: the file.
        y_origin: 'top' (DLTdv8: origin top-left, y down) or 'bottom' (DLTdv7 and Argus:
            bottom-left, y up); needed for DLTdv's X/Y columns; U/V columns are 'top', Argus
            columns 'bottom' unless given.
        camera: which camera's columns (default: the first).

    Raises:
        InputError: a header that is not DLTdv's or Argus', an X without its Y, text in a
            cell, an X/Y file without `y_origin`, a camera the file has no columns for.
    """
    text = read_text(path)
    rows = list(csv.reader(text.splitlines()))  # a lone CR ends a line too
    numbered = [(i + 1, r) for i, r in enumerate(rows) if any(c.strip() for c in r)]
    if not numbered:
        raise InputError(path, "empty file")
    header = [c.strip() for c in numbered[0][1]]
    points: dict[tuple[int, str], dict[str, int]] = {}
    styles = set()
    for j, name in enumerate(header):
        col = _column(name)
        if col is None:
            raise InputError(path, f"column {j + 1} {name!r} is not a DLTdv "
                                   "<point>_cam<j>_<X|Y|U|V> or Argus <track>_cam_<j>_<x|y> "
                                   "column", line=1)
        point, cam, axis, style = col
        styles.add(style)
        points.setdefault((cam, point), {})[axis] = j
    if len(styles) > 1:
        raise InputError(path, f"mixes {' and '.join(sorted(styles))} columns", line=1)
    style = styles.pop()
    cams = sorted({c for c, _ in points})
    cam = cams[0] if camera is None else camera
    if cam not in cams:
        raise InputError(path, f"no columns for camera {cam} (the file's cameras: "
                               f"{', '.join(map(str, cams))}): give --camera "
                               f"{' or '.join(map(str, cams))}", line=1)
    chosen = {p: c for (c_, p), c in points.items() if c_ == cam}
    for p, c in chosen.items():
        if set(c) != {"x", "y"}:
            raise InputError(path, f"point {p} of camera {cam} lacks its "
                                   f"{'y' if 'x' in c else 'x'} column", line=1)
    if style == "UV":
        origin = "top" if y_origin in (None, "top") else y_origin
    elif style == "argus":
        origin = y_origin or "bottom"
    else:
        if y_origin not in ("top", "bottom"):
            raise InputError(path, "DLTdv X/Y columns are written by DLTdv 5-7 (origin at the "
                                   "image's bottom-left, y up) and by DLTdv 8.0-8.3 (top-left, y "
                                   "down): say which with --y-origin bottom|top", line=1)
        origin = y_origin
    data = [r for _, r in numbered[1:]]
    lines = [n for n, _ in numbered[1:]]
    if not data:
        raise InputError(path, "no rows below the header", line=1)
    for r, n in zip(data, lines):
        if len(r) < len(header):
            raise InputError(path, f"row has {len(r)} fields, the header has {len(header)}",
                             line=n)
    names = list(chosen)
    xy = np.full((len(data), len(names), 2), np.nan)
    for m, p in enumerate(names):
        for a, axis in enumerate("xy"):
            j = chosen[p][axis]
            xy[:, m, a] = numbers_column(data, j, lines, path, header[j])
    frame = np.array([n - lines[0] + 1 for n in lines], dtype=np.int64)  # DLTdv counts from 1
    meta = {"camera": str(cam), "pixel_origin": "bottom-left" if origin == "bottom" else "top-left"}
    fmt = "argus" if style == "argus" else "dltdv"
    return Tracks(fmt, path, tuple(names), frame, xy_px=xy, px_y_up=origin == "bottom",
                  meta=meta)
