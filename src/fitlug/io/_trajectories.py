"""Read trajectories.csv (DATA.md): long ("tidy") form and wide form, as a `Recording`.

The table is parsed by `_table` (row-wise, keeping line numbers), the samples are
ordered and checked by `_time_checks`; here the columns become a `Recording`, with the
roles of wide-form markers from the rig or the names. Writing: `_write_trajectories`.
"""

from __future__ import annotations

import os
import re
from typing import TYPE_CHECKING

import numpy as np

from . import _declared, _runs
from ._imported import _role_from_name
from ._recording import ROLES, Recording
from ._table import (_LONG_OPTIONAL, _LONG_REQUIRED, _check_row_lengths, _columns, _floats, _ints,
                     _read_table, _separator, _separator_error, _Table)
from ._time_checks import _check_frame_rate, _sort_samples

if TYPE_CHECKING:
    from ._rig import Rig

_WIDE_COLUMN = re.compile(r"^(.+)_([xy])_mm$", re.IGNORECASE)
# a coordinate beyond 10 km is no position on a test bed (micrometres of a 5 m field, which
# the fit's unit check names, are 5e6): a corrupt or mistyped number, refused with its line
# (a 1e300 overflowed the fit's arithmetic into warnings and a traceback)
COORD_LIMIT_MM = 1e7


def _read_long(table: _Table, cols: dict[str, int], rig: "Rig | None") -> Recording:
    n = len(table.rows)
    t = _floats(table, cols["time_s"], "time_s", missing_ok=False)
    x = _floats(table, cols["x_mm"], "x_mm", missing_ok=True, limit=COORD_LIMIT_MM)
    y = _floats(table, cols["y_mm"], "y_mm", missing_ok=True, limit=COORD_LIMIT_MM)
    j_marker, j_role = cols["marker"], cols["role"]
    ids: dict[str, int] = {}
    roles: list[str] = []
    mi = np.empty(n, dtype=np.int64)
    for i, row in enumerate(table.rows):
        marker, role = row[j_marker].strip(), row[j_role].strip().lower()
        if not marker:
            raise table.error("empty marker id", row=i)
        if role not in ROLES:
            raise table.error(f"role must be 'body' or 'lug', got {row[j_role].strip()!r} "
                              f"for marker {marker}", row=i)
        k = ids.setdefault(marker, len(ids))
        if k == len(roles):
            roles.append(role)
        elif roles[k] != role:
            raise table.error(f"marker {marker} changes role from {roles[k]} to {role}", row=i)
        mi[i] = k
    optional: dict[str, np.ndarray] = {}
    for column, fieldname in _LONG_OPTIONAL.items():
        if column in cols:
            if column == "frame":
                optional[fieldname] = _ints(table, cols[column], column)
            else:
                optional[fieldname] = _floats(table, cols[column], column, missing_ok=True)
    if "sigma" in optional:
        bad = np.flatnonzero(optional["sigma"] <= 0)
        if bad.size:
            raise table.error("sigma_mm must be > 0, got "
                              f"{table.rows[bad[0]][cols['sigma_mm']].strip()!r}", row=int(bad[0]))
    markers = list(ids)
    _check_frame_rate(table, t, optional.get("frame"), rig)
    order = _sort_samples(table, t, mi, np.arange(n), markers,
                          [x, y, *optional.values()], optional.get("frame"))
    return Recording(markers=tuple(markers), roles=tuple(roles), t=t[order],
                     marker_index=mi[order], x=x[order], y=y[order],
                     **{k: v[order] for k, v in optional.items()},
                     meta=table.meta, path=table.path)



def _wide_roles(table: _Table, markers: list[str], rig: "Rig | None") -> list[str]:
    roles = []
    for marker in markers:
        if rig is not None and marker in rig.body_markers:
            role = "body"
        elif rig is not None and marker in rig.lug_markers:
            role = "lug"
        else:
            role = _role_from_name(marker)
        if role is None:
            raise table.error(
                f"cannot tell the role of marker {marker} from its name (body markers start "
                f"with C, Q, QS or body; lug markers with B, L, COG or lug): list it under "
                f"[markers] body = [...] or lug = [...] in rig.toml", line=table.header_line)
        roles.append(role)
    return roles


def _read_wide(table: _Table, cols: dict[str, int], rig: "Rig | None") -> Recording:
    pairs: dict[str, dict[str, int]] = {}
    for name, j in cols.items():
        match = _WIDE_COLUMN.match(name)
        if match:
            pairs.setdefault(match.group(1), {})[match.group(2).lower()] = j
    for marker, pair in pairs.items():
        for have, lack in (("x", "y"), ("y", "x")):
            if lack not in pair:
                raise table.error(f"column {table.header[pair[have]]} has no partner "
                                  f"column {marker}_{lack}_mm", line=table.header_line)
    if "time_s" not in cols:
        raise table.error("missing required column 'time_s'", line=table.header_line)
    markers = list(pairs)
    roles = _wide_roles(table, markers, rig)
    n_rows, n_markers = len(table.rows), len(markers)
    time = _floats(table, cols["time_s"], "time_s", missing_ok=False)
    xs = [_floats(table, pairs[m]["x"], table.header[pairs[m]["x"]], missing_ok=True,
                   limit=COORD_LIMIT_MM)
          for m in markers]
    ys = [_floats(table, pairs[m]["y"], table.header[pairs[m]["y"]], missing_ok=True,
                   limit=COORD_LIMIT_MM)
          for m in markers]
    frame = _ints(table, cols["frame"], "frame") if "frame" in cols else None
    _check_frame_rate(table, time, frame, rig)
    # one row per frame, in any order: every marker shares the frame times, so sorting
    # (and checking) the rows as one marker sorts them all
    order = _sort_samples(table, time, np.zeros(n_rows, dtype=np.int64), np.arange(n_rows),
                          [], [*xs, *ys], frame)
    optional = {} if frame is None else {"frame": np.tile(frame[order], n_markers)}
    n_rows = order.size
    return Recording(markers=tuple(markers), roles=tuple(roles), t=np.tile(time[order], n_markers),
                     marker_index=np.repeat(np.arange(n_markers, dtype=np.int64), n_rows),
                     x=np.concatenate([v[order] for v in xs]),
                     y=np.concatenate([v[order] for v in ys]), **optional,
                     meta=table.meta, path=table.path)


def read_trajectories(path: str | os.PathLike, rig: "Rig | None" = None) -> Recording:
    """Read trajectories.csv in long form or wide form (DATA.md).

    Long form: columns time_s, marker, role, x_mm, y_mm; optional frame, sigma_mm, x_px,
    y_px, quality; other columns are ignored; rows in any order. Wide form: one row per
    frame, time_s plus `<ID>_x_mm`, `<ID>_y_mm` pairs (optional frame); roles from
    `rig.body_markers`/`rig.lug_markers`, else from the marker names. Comment lines
    starting with '#' may come before the header; `# key: value` lines become `meta`.

    Args:
        path: the CSV file.
        rig: used for the roles of wide-form markers only (long form carries its roles).

    Returns:
        Recording with samples sorted by (marker_index, t); x, y NaN where a value is empty.

    Raises:
        InputError: naming the file, the line and the problem: missing or unreadable file,
            no header, missing column, text in a number field, empty/NaN time, infinite
            value, bad role, a marker changing role, time not increasing per marker, an x
            column without its y partner, no data rows, a `# units:` line that is not
            a length in mm, cm, m, in or um (positions are converted to mm), a marker
            whose role contradicts the rig's [markers] lists.
    """
    path = os.fspath(path)
    table = _read_table(path)
    named = [c for c in table.header if c]
    sep = _separator(table.header_text) if len(named) <= 1 else None
    if sep:
        raise _separator_error(table, sep, table.header_line)
    cols = _columns(table)
    is_long = "marker" in cols
    is_wide = not is_long and any(_WIDE_COLUMN.match(name) for name in cols)
    if is_long:
        missing = [c for c in _LONG_REQUIRED if c not in cols]
        if missing:
            raise table.error(f"missing required column {missing[0]!r} (long form needs "
                              f"{', '.join(_LONG_REQUIRED)})", line=table.header_line)
    elif not is_wide:
        raise table.error("missing required column 'marker' (long form needs "
                          f"{', '.join(_LONG_REQUIRED)}; wide form needs time_s and "
                          "<ID>_x_mm, <ID>_y_mm pairs)", line=table.header_line)
    if not table.rows:
        raise table.error("no samples: nothing below the header", line=table.header_line)
    _check_row_lengths(table)
    if "units" in table.meta:  # refused before the numbers are read (pixels, ms, unknown)
        _declared.length_scale(table.meta["units"], path, table.meta_lines.get("units"))
    if is_long:
        rec = _read_long(table, cols, rig)
        _declared.check_rig_roles(rec, rig, _declared.first_lines(table, cols["marker"]))
    else:
        rec = _read_wide(table, cols, rig)
    restart = _runs.find_restart(rec)
    if restart is not None:  # two runs in one file: name the first row of the second
        j, jm = cols["time_s"], cols.get("marker")
        names = set(restart["markers"])
        row = next((i for i, r in enumerate(table.rows)
                    if r[j].strip() and float(r[j]) == restart["t"]
                    and (jm is None or r[jm].strip() in names)), None)
        raise table.error(_runs.restart_problem(restart), row=row)
    return _declared.apply_units(rec, table.meta, table.meta_lines)
