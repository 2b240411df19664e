"""What a trajectories file declares beside its numbers, honoured or refused.

- `# units: <unit>` in the preamble: positions in cm, m, in (inch), um/µm are converted
  to mm (x_mm, y_mm and sigma_mm scaled; meta `units` becomes "mm" and `units_read`
  keeps the declared unit); pixels, and any unit that is not a length fitlug knows, are
  refused naming the line. A time unit other than seconds (ms, us) is refused too.
- rig.toml `[markers]` body/lug lists against the roles a long-form file gives its
  markers: a marker the rig lists under the other role is refused, naming the rig key
  and the file's line (the wide form takes its roles from the rig, so it cannot clash).
"""

from __future__ import annotations

import re

from .._errors import InputError

LENGTH_MM = {"mm": 1.0, "millimetre": 1.0, "millimeter": 1.0, "millimetres": 1.0,
             "millimeters": 1.0, "cm": 10.0, "m": 1000.0, "metre": 1000.0, "meter": 1000.0,
             "metres": 1000.0, "meters": 1000.0, "in": 25.4, "inch": 25.4, "inches": 25.4,
             "um": 1e-3, "µm": 1e-3, "μm": 1e-3, "micron": 1e-3, "microns": 1e-3}
_TIME = {"s": 1.0, "sec": 1.0, "second": 1.0, "seconds": 1.0}
_TIME_OTHER = {"ms", "us", "µs", "μs", "ns", "min"}
_PIXELS = {"px", "pixel", "pixels", "pix"}


def length_scale(value: str, path: str, line: int | None) -> tuple[float, str]:
    """(mm per unit, the length unit) of a `# units:` value such as "mm", "in" or
    "mm, s"; raises InputError for pixels, a non-second time unit or anything unknown."""
    words = [w for w in re.split(r"[\s,;/()\[\]]+", value.strip().lower()) if w]
    lengths = []
    for word in words:
        if word in LENGTH_MM:
            lengths.append(word)
        elif word in _PIXELS:
            raise InputError(path, f"# units: {value} - positions in pixels; fitlug needs "
                                   "mm in the plane of motion (fit-lug track with a "
                                   "calibration converts them)", line=line)
        elif word in _TIME_OTHER:
            raise InputError(path, f"# units: {value} - time_s must be in seconds, not "
                                   f"{word}", line=line)
        elif word not in _TIME and word not in ("x", "y", "t", "time", "position"):
            raise InputError(path, f"# units: {value} - unknown unit {word!r} (mm, cm, m, "
                                   "in or um for the positions, s for time)", line=line)
    scales = {LENGTH_MM[w] for w in lengths}
    if len(scales) > 1:
        raise InputError(path, f"# units: {value} - more than one length unit", line=line)
    if not lengths:
        return 1.0, "mm"
    return scales.pop(), lengths[0]


def apply_units(rec, meta: dict, meta_lines: dict):
    """`rec` with its positions (and sigma) in mm, as its `# units:` line declares."""
    if "units" not in meta:
        return rec
    scale, unit = length_scale(meta["units"], rec.path, meta_lines.get("units"))
    if scale == 1.0:
        return rec
    new_meta = {**rec.meta, "units": "mm", "units_read": meta["units"]}
    changes = {"x": rec.x * scale, "y": rec.y * scale, "meta": new_meta}
    if rec.sigma is not None:
        changes["sigma"] = rec.sigma * scale
    return rec.with_(**changes)


def check_rig_roles(rec, rig, marker_lines: dict) -> None:
    """Refuse a marker whose role in the file contradicts rig.toml's [markers] lists.

    marker_lines: {marker id: the file's line of its first row}.
    """
    if rig is None:
        return
    for key, listed, other in (("body", rig.body_markers, "lug"),
                               ("lug", rig.lug_markers, "body")):
        for name in listed:
            if name in rec.markers and rec.role_of(name) == other:
                raise InputError(rig.path, f"[markers] {key} lists {name}, but "
                                           f"{rec.path} line {marker_lines.get(name, '?')} "
                                           f"gives {name} the role {other}: correct the rig "
                                           "file or the file's role column",
                                 line=_rig_line(rig, key))


def _rig_line(rig, key: str) -> int | None:
    from ._rig import _key_line

    try:
        with open(rig.path, encoding="utf-8") as fh:
            return _key_line(fh.read(), "markers", key)
    except (OSError, TypeError, UnicodeDecodeError):
        return None


def first_lines(table, j_marker: int) -> dict:
    """{marker id: the physical line of its first row} of a long-form table."""
    out: dict = {}
    for row, line in zip(table.rows, table.lines):
        out.setdefault(row[j_marker].strip(), line)
    return out


__all__ = ["apply_units", "check_rig_roles", "first_lines", "length_scale"]
