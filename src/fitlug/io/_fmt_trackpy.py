"""trackpy's linked features: a long table `frame, particle, x, y` (+ mass, size, ...).

trackpy's DataFrames put `y` before `x` (image row, then column); positions are pixels with
the origin top-left, y down; a particle missing from a frame has no row. Users save them
with `DataFrame.to_csv` (often with the index as a first, unnamed column). Markers are
named by their particle number. No time is written: fps is needed.

Also `recording_from_dataframe`, behind `Recording.from_dataframe`: a canonical long table
(time_s, marker, role, x_mm, y_mm), a trackpy table or a DeepLabCut table, for notebooks.
"""

from __future__ import annotations

import csv
import io

import numpy as np

from .._errors import InputError
from ._imported import Tracks, number, read_text, tracks_to_recording

TRACKPY_COLUMNS = ("mass", "size", "ecc", "signal", "raw_mass", "ep")


def looks_like_trackpy(header: list[str]) -> bool:
    cols = {c.strip() for c in header}
    return {"frame", "x", "y"} <= cols and ("particle" in cols or bool(cols & set(TRACKPY_COLUMNS)))


def _tracks(path: str, frame: np.ndarray, particle: np.ndarray, x: np.ndarray, y: np.ndarray,
            where=None) -> Tracks:
    if frame.size == 0:
        raise InputError(path, "no rows")
    ids = np.unique(particle)
    frames = np.unique(frame)
    xy = np.full((frames.size, ids.size, 2), np.nan)
    fi = np.searchsorted(frames, frame)
    pi = np.searchsorted(ids, particle)
    key = fi * ids.size + pi
    uniq, first, counts = np.unique(key, return_index=True, return_counts=True)
    if (counts > 1).any():
        k = int(np.flatnonzero(counts > 1)[0])
        i = int(first[k])
        place = "" if where is None else f" (row {where(i)})"
        raise InputError(path, f"particle {particle[i]} appears twice in frame {frame[i]}{place}")
    xy[fi, pi, 0], xy[fi, pi, 1] = x, y
    names = tuple(str(int(p)) if float(p).is_integer() else str(p) for p in ids)
    return Tracks("trackpy", path, names, frames.astype(np.int64), xy_px=xy)


def read_trackpy_csv(path: str) -> Tracks:
    """A trackpy table saved with `to_csv`: columns frame, particle, x, y (any order)."""
    rows = list(csv.reader(io.StringIO(read_text(path))))
    numbered = [(i + 1, r) for i, r in enumerate(rows) if any(c.strip() for c in r)]
    header = [c.strip() for c in numbered[0][1]]
    col = {c: j for j, c in enumerate(header) if c}
    if "particle" not in col:
        raise InputError(path, "no 'particle' column: the features are not linked "
                               "(run trackpy.link first)", line=1)
    data = numbered[1:]
    lines = [n for n, _ in data]
    out = {}
    for name in ("frame", "particle", "x", "y"):
        j = col[name]
        v = np.empty(len(data))
        for i, (no, r) in enumerate(data):
            try:
                v[i] = number(r[j] if j < len(r) else "")
            except ValueError:
                raise InputError(path, f"column {name}: {r[j]!r} is not a number", line=no) from None
            if name != "x" and name != "y" and not np.isfinite(v[i]):
                raise InputError(path, f"empty {name}", line=no)
        out[name] = v
    if not np.all(out["frame"] == np.round(out["frame"])):
        i = int(np.flatnonzero(out["frame"] != np.round(out["frame"]))[0])
        raise InputError(path, "frame must be an integer", line=lines[i])
    return _tracks(path, out["frame"].astype(np.int64), out["particle"], out["x"], out["y"],
                   where=lambda i: lines[i])


def tracks_from_dataframe(df, path: str = "<DataFrame>", likelihood: float = 0.6) -> Tracks:
    """Tracks from a trackpy DataFrame (frame, particle, x, y) or a DeepLabCut DataFrame."""
    if getattr(df.columns, "nlevels", 1) >= 3:
        from ._fmt_dlc import tracks_from_dlc_frame

        return tracks_from_dlc_frame(df, path, likelihood, "deeplabcut")
    cols = set(map(str, df.columns))
    missing = [c for c in ("frame", "particle", "x", "y") if c not in cols]
    if missing:
        raise InputError(path, f"missing column {missing[0]!r}: expected trackpy's frame, "
                               "particle, x, y, or time_s, marker, role, x_mm, y_mm")
    get = {c: np.asarray(df[c].to_numpy(), dtype=np.float64) for c in ("frame", "particle", "x", "y")}
    return _tracks(path, get["frame"].astype(np.int64), get["particle"], get["x"], get["y"])


def recording_from_dataframe(df, *, fps=None, mm_per_px=None, calibration=None, rig=None,
                             body=None, lug=None, likelihood: float = 0.6):
    """See `Recording.from_dataframe`."""
    from ._recording import Recording

    cols = set(map(str, df.columns)) if getattr(df.columns, "nlevels", 1) == 1 else set()
    if {"time_s", "marker", "role", "x_mm", "y_mm"} <= cols:
        markers = list(dict.fromkeys(map(str, df["marker"])))
        roles = dict(zip(map(str, df["marker"]), map(str, df["role"])))
        index = {m: k for k, m in enumerate(markers)}
        mi = np.array([index[str(m)] for m in df["marker"]], dtype=np.int64)
        t = np.asarray(df["time_s"], dtype=np.float64)
        order = np.lexsort((t, mi))
        return Recording(markers=tuple(markers), roles=tuple(roles[m] for m in markers),
                         t=t[order], marker_index=mi[order],
                         x=np.asarray(df["x_mm"], dtype=np.float64)[order],
                         y=np.asarray(df["y_mm"], dtype=np.float64)[order],
                         meta={"source": "DataFrame"})
    tracks = tracks_from_dataframe(df, likelihood=likelihood)
    to_mm = None
    height = None
    if calibration is None and mm_per_px is not None:
        # the scale-only calibration of `fit-lug track` (x = S x_px, y = S (H - y_px))
        from ._calibration import Calibration

        try:
            calibration = Calibration.from_scale(float(mm_per_px), (0, 0))
        except ValueError as exc:
            raise InputError(None, f"mm_per_px: {exc}") from None
    if calibration is not None:
        to_mm, height = calibration.pixels_to_mm, calibration.image_size[1]
    return tracks_to_recording(tracks, pixels_to_mm=to_mm, image_height=height, fps=fps,
                               rig=rig, body=body, lug=lug)
