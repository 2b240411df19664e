"""What another tracker exported, before it becomes a `Recording`: `Tracks`.

Each reader of a foreign format (Tracker, DLTdv, Kinovea, DeepLabCut, trackpy) returns a
`Tracks`: one row per frame, one column per marker, positions either in the image's pixels
or already in world millimetres (y up), time stamps when the file has them.
`fitlug.io._recording.tracks_to_recording` turns it into a `Recording` in ground-frame mm,
with the time (`_times`: from the file or from fps) and the roles (`_roles`: from the rig,
a body list or the marker names) told here.
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from .._errors import InputError
from ._files import read_bytes

if TYPE_CHECKING:
    from ._rig import Rig

# world length units -> mm
LENGTH_UNITS = {"mm": 1.0, "cm": 10.0, "dm": 100.0, "m": 1000.0, "km": 1e6, "um": 1e-3,
                "µm": 1e-3, "μm": 1e-3, "nm": 1e-6, "in": 25.4, "ft": 304.8, "yd": 914.4}
# time stamps and an fps must agree to this relative tolerance
_FPS_TOLERANCE = 0.02


@dataclass
class Tracks:
    """Marker positions as another program exported them, one row per frame.

    Attributes:
        format: the format's id (see `fitlug.io.FORMATS`).
        path: the file read.
        markers: (M,) marker names.
        frame: (F,) int64 frame numbers, increasing.
        t: (F,) float64 time stamps in s, or None when the file has none (then fps is needed).
        xy_mm: (F, M, 2) world positions in mm, y up, NaN where missing; or None.
        xy_px: (F, M, 2) image positions in px, NaN where missing; or None.
        px_y_up: True when xy_px's y axis points up from the image's bottom edge (DLTdv7),
            False for the usual image convention (origin top-left, y down).
        image_size: (width, height) px when the file says it, else None.
        quality: (F, M) per-sample score (DeepLabCut's likelihood), or None.
        meta: `# key: value` lines for the written trajectories.csv (where it came from).
    """

    format: str
    path: str
    markers: tuple[str, ...]
    frame: np.ndarray
    t: np.ndarray | None = None
    xy_mm: np.ndarray | None = None
    xy_px: np.ndarray | None = None
    px_y_up: bool = False
    image_size: tuple[int, int] | None = None
    quality: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        self.markers = tuple(str(m) for m in self.markers)
        self.frame = np.asarray(self.frame, dtype=np.int64)
        n, m = self.frame.shape[0], len(self.markers)
        for name in ("xy_mm", "xy_px"):
            value = getattr(self, name)
            if value is not None:
                value = np.asarray(value, dtype=np.float64)
                if value.shape != (n, m, 2):
                    raise ValueError(f"Tracks.{name} has shape {value.shape}, expected {(n, m, 2)}")
                setattr(self, name, value)
        if self.t is not None:
            self.t = np.asarray(self.t, dtype=np.float64)
        if self.xy_mm is None and self.xy_px is None:
            raise ValueError("Tracks needs xy_mm or xy_px")

    def with_(self, **changes) -> "Tracks":
        return dataclasses.replace(self, **changes)


def length_factor(unit: str, path: str, place: str) -> float:
    """mm per `unit` (m, cm, mm, in, ...); InputError naming `place` for an unknown unit."""
    key = unit.strip()
    if key in LENGTH_UNITS:
        return LENGTH_UNITS[key]
    if key.lower() in LENGTH_UNITS:
        return LENGTH_UNITS[key.lower()]
    raise InputError(path, f"unknown length unit {unit!r} (known: "
                           f"{', '.join(k for k in LENGTH_UNITS if k.isascii())})", place=place)


# -- text helpers shared by the readers --------------------------------------------------------

def number(text: str, decimal_comma: bool = False) -> float:
    """A cell as a float: empty or NaN -> NaN; a decimal comma when `decimal_comma`.
    Raises ValueError for text."""
    s = text.strip().strip('"').strip()
    if not s or s.lower() in ("nan", "-nan", "na", "null"):
        return float("nan")
    if decimal_comma:
        s = s.replace(",", ".")
    value = float(s)
    if not np.isfinite(value):
        raise ValueError(f"not a finite number: {text!r}")
    return value


def numbers_column(rows: list[list[str]], j: int, lines: list[int], path: str, name: str,
                   decimal_comma: bool = False) -> np.ndarray:
    """Column j of `rows` as float64 (empty -> NaN); InputError at the line of a bad cell."""
    out = np.empty(len(rows))
    for i, row in enumerate(rows):
        cell = row[j] if j < len(row) else ""
        try:
            out[i] = number(cell, decimal_comma)
        except ValueError:
            raise InputError(path, f"column {name}: {cell.strip()!r} is not a number",
                             line=lines[i]) from None
    return out


def read_text(path: str) -> str:
    """The file as text (UTF-8, else Latin-1 as some Windows programs write), with a clear
    InputError for a missing or unreadable file."""
    data = read_bytes(path)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        return data.decode("latin-1")


# -- roles and times of Tracks ------------------------------------------------------------------

# longest prefix first: 'COG' must win over 'C', 'body' over 'B'
_NAME_ROLES = (("body", "body"), ("cog", "lug"), ("lug", "lug"), ("qs", "body"),
               ("c", "body"), ("q", "body"), ("b", "lug"), ("l", "lug"))


def _role_from_name(marker: str) -> str | None:
    lower = marker.lower()
    for prefix, role in _NAME_ROLES:
        if lower.startswith(prefix):
            return role
    return None


# another program's track names tell a role only in the project's own naming (DATA.md's
# C1, B03): a role's letters and a number, or the words body / lug ("cart 1" is no C1)
_NUMBERED = re.compile(r"^(qs|cog|c|q|b|l)[ _-]?\d+$", re.IGNORECASE)
_WORD = re.compile(r"^(body|lug)(?![a-z])", re.IGNORECASE)


def guessed_role(marker: str) -> str | None:
    """The role a foreign file's track name stands for (C1, QS2, B03, COG1, body_front,
    lug 3), or None."""
    name = marker.strip()
    if _NUMBERED.match(name) or _WORD.match(name):
        return _role_from_name(name)
    return None


def _roles(tracks: Tracks, rig: "Rig | None", body, lug) -> list[str]:
    body = set(body or ()) | set(rig.body_markers if rig is not None else ())
    lug = set(lug or ()) | set(rig.lug_markers if rig is not None else ())
    unknown = sorted((body | lug) - set(tracks.markers))
    if unknown and (body or lug):
        raise InputError(tracks.path, f"marker {unknown[0]!r} named in the roles is not in the "
                         f"file (markers: {', '.join(tracks.markers)})")
    roles, guessed = [], {"body": [], "lug": []}
    for marker in tracks.markers:
        if marker in body:
            role = "body"
        elif marker in lug:
            role = "lug"
        elif body and not lug:
            role = "lug"  # a body list alone: every other marker is a lug
        else:
            role = guessed_role(marker)
            if role is not None:
                guessed[role].append(marker)
        if role is None:
            raise InputError(tracks.path, f"cannot tell the role of marker {marker!r}: give "
                             f"--body NAME,... (the others are lugs) or list it under [markers] "
                             f"in rig.toml (a name tells it only when it is C1, Q1, QS1 or "
                             f"body... for the body, B1, L1, COG1 or lug... for a lug)")
        roles.append(role)
    if guessed["body"] or guessed["lug"]:
        import warnings

        said = "; ".join(f"{r} {', '.join(m[:6])}" + (f" and {len(m) - 6} more" if m[6:] else "")
                         for r, m in guessed.items() if m)
        warnings.warn(f"{tracks.path}: roles guessed from the marker names ({said}): if wrong, "
                      f"give --body NAME,... (the others are lugs) or [markers] body = [...] "
                      f"in rig.toml", stacklevel=3)
    return roles


def _times(tracks: Tracks, fps: float | None) -> np.ndarray:
    if fps is not None and not (np.isfinite(fps) and fps > 0):
        raise InputError("--fps", f"must be a number > 0, got {fps!r}")
    if tracks.t is None:
        if fps is None:
            raise InputError(tracks.path, f"the {tracks.format} file has no time stamps: give "
                             f"the frame rate (--fps, or [camera] fps in rig.toml)")
        return (tracks.frame - tracks.frame[0]) / float(fps)
    t = tracks.t
    if not np.isfinite(t).all():
        raise InputError(tracks.path, "a frame has no valid time stamp")
    if np.any(np.diff(t) <= 0):
        k = int(np.flatnonzero(np.diff(t) <= 0)[0])
        raise InputError(tracks.path, f"time going backwards or repeated: frame "
                         f"{int(tracks.frame[k + 1])} at {t[k + 1]!r} s after {t[k]!r} s")
    if fps is not None and t.size > 2:
        data_fps = span_rate(t, tracks.frame)
        if abs(fps / data_fps - 1) > _FPS_TOLERANCE:
            raise InputError(tracks.path, f"the fps {fps:g} (--fps or [camera] fps) disagrees "
                             f"with the file's time stamps ({data_fps:.6g} frames/s)")
    return t


def span_rate(t: np.ndarray, frame: np.ndarray) -> float:
    """Frames per second of time stamps `t` (s) at frame numbers `frame`: the intervals over
    the whole span, which stamps rounded by their writer (Kinovea's 1 ms) leave right where
    the commonest step does not (8 ms at 120 fps reads as 125)."""
    intervals = float(frame[-1] - frame[0]) if frame[-1] > frame[0] else float(t.size - 1)
    return intervals / float(t[-1] - t[0])


def merge_by_time(path: str, fmt: str, series: list[tuple[str, np.ndarray, np.ndarray]],
                  ) -> tuple[np.ndarray, np.ndarray]:
    """One table from per-marker (name, t (K,), xy (K, 2)) series: the sorted union of their
    time stamps (equal to 1e-9 s) and (F, M, 2) positions, NaN where a marker has no sample."""
    all_t = np.concatenate([s[1] for s in series]) if series else np.zeros(0)
    if all_t.size == 0:
        raise InputError(path, f"no samples in the {fmt} file")
    keys = np.round(all_t, 9)
    times = np.unique(keys)
    xy = np.full((times.size, len(series), 2), np.nan)
    for k, (name, t, v) in enumerate(series):
        idx = np.searchsorted(times, np.round(t, 9))
        if np.unique(idx).size != idx.size:
            raise InputError(path, f"marker {name!r} has two samples at one time stamp")
        xy[idx, k] = v
    return times, xy
