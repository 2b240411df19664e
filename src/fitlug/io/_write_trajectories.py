"""Write a `Recording` as long-form trajectories.csv (DATA.md), atomically."""

from __future__ import annotations

import csv
import os
import re

import numpy as np

from ._atomic import atomic_path
from ._recording import OPTIONAL_COLUMNS, Recording
from ._table import _LONG_OPTIONAL, _LONG_REQUIRED

def _format(values: np.ndarray, precision: int | None) -> list[str]:
    fmt = repr if precision is None else f"%.{precision}g".__mod__
    return [fmt(v) if v == v else "" for v in values.tolist()]  # v != v: NaN -> empty


def write_trajectories(path: str | os.PathLike, recording: Recording, *,
                       meta: dict | None = None, precision: int | None = None) -> None:
    """Write `recording` as long-form trajectories.csv, atomically.

    `# key: value` lines come first (recording.meta updated with `meta`), then the columns
    time_s, marker, role, x_mm, y_mm and whichever of frame, sigma_mm, x_px, y_px, quality
    the recording has. NaN is written as an empty field. Floats are written with the
    shortest text that reads back to the same number (so read(write(r)) == r), or with
    `precision` significant digits when given. Rows go frame by frame when that keeps the
    markers' order of first appearance, else marker by marker.

    Raises:
        ValueError: a metadata key/value that cannot be written as a comment line, a time
            that is not finite, an infinite coordinate, or times not increasing per marker
            (the file would not read back).
    """
    r = recording
    all_meta = {**r.meta, **(meta or {})}
    for key, value in all_meta.items():
        if not re.fullmatch(r"[A-Za-z_][\w.\-]*", str(key)) or "\n" in str(value) \
                or "\r" in str(value):
            raise ValueError(f"metadata {key!r}: {value!r} cannot be written as '# key: value'")
    for name in ("t", "x", "y", *OPTIONAL_COLUMNS):
        value = getattr(r, name)
        if value is not None and np.isinf(value).any():
            raise ValueError(f"write_trajectories: infinite value in {name}")
    if not np.isfinite(r.t).all():
        raise ValueError("write_trajectories: time stamps must be finite")
    by_marker = np.lexsort((r.t, r.marker_index))
    ms, ts = r.marker_index[by_marker], r.t[by_marker]
    if np.any((ms[1:] == ms[:-1]) & (ts[1:] <= ts[:-1])):
        raise ValueError("write_trajectories: times must be strictly increasing per marker")
    by_frame = np.lexsort((r.marker_index, r.t))
    _, first = np.unique(r.marker_index[by_frame], return_index=True)
    keeps_order = np.array_equal(np.argsort(first, kind="stable"), np.arange(first.size))
    order = by_frame if keeps_order else by_marker

    header = list(_LONG_REQUIRED)
    columns = [_format(r.t[order], precision),
               [r.markers[k] for k in r.marker_index[order].tolist()],
               [r.roles[k] for k in r.marker_index[order].tolist()],
               _format(r.x[order], precision), _format(r.y[order], precision)]
    for column, fieldname in _LONG_OPTIONAL.items():
        value = getattr(r, fieldname)
        if value is None:
            continue
        header.append(column)
        if value.dtype.kind == "i":
            columns.append([str(v) for v in value[order].tolist()])
        else:
            columns.append(_format(value[order], precision))
    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="", encoding="utf-8") as fh:
            for key, value in all_meta.items():
                fh.write(f"# {key}: {value}\n")
            writer = csv.writer(fh, lineterminator="\n")
            writer.writerow(header)
            writer.writerows(zip(*columns))
