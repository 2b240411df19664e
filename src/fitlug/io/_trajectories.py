"""Read and write trajectories.csv (DATA.md): long ("tidy") form and wide form.

Parsing is row-wise with the csv module (to keep line numbers for errors), then
column-wise with numpy, so 10^5 rows take a fraction of a second.
"""

from __future__ import annotations

import csv
import os
import re
import sys
from array import array
from typing import TYPE_CHECKING

import numpy as np

from .._errors import InputError
from . import _declared, _runs
from ._atomic import atomic_path
from ._recording import OPTIONAL_COLUMNS, ROLES, Recording

if TYPE_CHECKING:
    from ._rig import Rig

_LONG_REQUIRED = ("time_s", "marker", "role", "x_mm", "y_mm")
# file column -> Recording field, for the optional per-sample columns
_LONG_OPTIONAL = {"frame": "frame", "sigma_mm": "sigma", "x_px": "x_px", "y_px": "y_px",
                  "quality": "quality"}
_META_LINE = re.compile(r"^#\s*([A-Za-z_][\w.\-]*)\s*:\s*(.*?)\s*$")
_WIDE_COLUMN = re.compile(r"^(.+)_([xy])_mm$", re.IGNORECASE)
# longest prefix first: 'COG' must win over 'C', 'body' over 'B'
_NAME_ROLES = (("body", "body"), ("cog", "lug"), ("lug", "lug"), ("qs", "body"),
               ("c", "body"), ("q", "body"), ("b", "lug"), ("l", "lug"))


class _Table:
    """The rows of a CSV file below its header, with their physical line numbers."""

    def __init__(self, path: str):
        self.path = path
        self.meta: dict[str, str] = {}
        self.meta_lines: dict[str, int] = {}
        self.header: list[str] = []
        self.header_line = 0
        self.header_text = ""
        self.rows: list[list[str]] = []
        self.lines = array("q")  # physical line of each row (8 bytes a row, not 36)

    def error(self, problem: str, row: int | None = None, line: int | None = None) -> InputError:
        if row is not None:
            line = self.lines[row]
        return InputError(self.path, problem, line=line)


def _read_table(path: str) -> _Table:
    table = _Table(path)
    lineno = 0
    last = [""]  # the text of the line the csv reader took last

    def lines(fh):
        nonlocal lineno
        for lineno, text in enumerate(fh, 1):  # `lineno` is read by the csv loop below
            stripped = text.strip()
            if not stripped:
                continue
            if stripped.startswith("#"):
                match = _META_LINE.match(stripped)
                if match and not table.header:  # metadata only from the preamble
                    table.meta[match.group(1)] = match.group(2)
                    table.meta_lines[match.group(1)] = lineno
                    if match.group(1) == "fps":
                        _check_fps(table, match.group(2), lineno)
                continue
            last[0] = text
            yield text

    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except FileNotFoundError:
        raise InputError(path, "file not found") from None
    except IsADirectoryError:
        raise InputError(path, "is a directory, not a CSV file") from None
    except PermissionError:
        raise InputError(path, "cannot read file (permission denied)") from None
    except OSError as exc:
        raise InputError(path, f"cannot read file: {exc.strerror or exc}") from None
    data = _gunzip(path, data)
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputError(path, f"not UTF-8 text ({exc.reason})",
                         line=data.count(b"\n", 0, exc.start) + 1) from None
    del data  # the text holds it now: one copy of a large file at a time
    try:
        # lines split as open(..., newline="") does (\n, \r\n or \r, kept), as the csv
        # module wants, one at a time: io.StringIO copied the whole text (4 bytes a char)
        reader = csv.reader(lines(m.group() for m in _LINE.finditer(text)))
        shared: list[int] = []  # columns of few distinct values (marker, role): one str each
        for row in reader:
            if not table.header:
                table.header = [c.strip() for c in row]
                table.header_line = lineno
                table.header_text = last[0]
                shared = [j for j, c in enumerate(table.header) if c.lower() in ("marker", "role")]
            else:
                for j in shared:
                    if j < len(row):
                        row[j] = sys.intern(row[j])
                table.rows.append(row)
                table.lines.append(lineno)
    except csv.Error as exc:
        raise InputError(path, f"malformed CSV: {exc}", line=lineno) from None
    if not table.header:
        raise InputError(path, "empty file: no header line")
    return table


_LINE = re.compile(r"[^\r\n]*(?:\r\n|\r|\n)|[^\r\n]+\Z")
GZIP_MAGIC = b"\x1f\x8b"


def _gunzip(path: str, data: bytes) -> bytes:
    """A gzip-compressed file's content (read transparently, as `gzip -c` would give it);
    other bytes unchanged. A damaged or cut-short gzip file is one line, naming it."""
    if not data.startswith(GZIP_MAGIC):
        return data
    import gzip
    import zlib

    try:
        return gzip.decompress(data)
    except (OSError, EOFError, zlib.error) as exc:
        raise InputError(path, f"a gzip-compressed file that cannot be decompressed, "
                               f"truncated or damaged ({exc})") from None


def _separator(text: str) -> str | None:
    """The separator a line of fields seems to use when it has no comma: ';', tab, '|' or
    runs of spaces; None when it looks like one field (or has commas)."""
    text = text.strip()
    if not text or "," in text:
        return None
    counts = {";": text.count(";"), "tab": text.count("\t"), "'|'": text.count("|")}
    best = max(counts, key=counts.get)
    if counts[best]:
        return "';'" if best == ";" else best
    return "spaces" if len(text.split()) >= 2 else None


def _separator_error(table: _Table, sep: str, line: int) -> InputError:
    return table.error(f"the separator looks wrong: {sep} between the fields, but "
                       f"trajectories.csv must be comma-separated (DATA.md)", line=line)


def _check_fps(table: _Table, text: str, line: int) -> None:
    try:
        fps = float(text)
    except ValueError:
        fps = float("nan")
    if not (np.isfinite(fps) and fps > 0):
        raise InputError(table.path, f"metadata fps must be a number > 0, got {text!r}", line=line)


def _columns(table: _Table) -> dict[str, int]:
    """Map of column name -> index; duplicated names are an error."""
    index: dict[str, int] = {}
    for j, name in enumerate(table.header):
        if not name:
            continue  # an unnamed column (a trailing comma in the header) is ignored
        key = name.lower() if name.lower() in (*_LONG_REQUIRED, *_LONG_OPTIONAL) else name
        if key in index:
            raise table.error(f"column {name!r} appears twice in the header", line=table.header_line)
        index[key] = j
    return index


def _check_row_lengths(table: _Table) -> None:
    width = len(table.header)
    for i, row in enumerate(table.rows):
        # trailing empty fields (a trailing comma) are harmless
        if len(row) < width or (len(row) > width and any(f.strip() for f in row[width:])):
            text = ",".join(row)
            sep = _separator(text) if len(row) < width else None
            if sep and _split_count(text, sep) >= width:
                raise _separator_error(table, sep, table.lines[i])
            if len(row) < width and not _looks_numeric(row):
                where = "after the data" if i == len(table.rows) - 1 else "among the data"
                raise table.error(f"not a data row: {_clip(text)!r} ({len(row)} field"
                                  f"{'s' if len(row) != 1 else ''}, the header has {width}), "
                                  f"a note or trailer {where}? remove it or start it with #",
                                  row=i)
            raise table.error(f"row has {len(row)} fields, the header has {width}", row=i)


def _split_count(text: str, sep: str) -> int:
    """Fields of `text` split by a separator as `_separator` names it."""
    text = text.strip()
    if sep == "spaces":
        return len(text.split())
    return text.count({"tab": "\t", "';'": ";", "'|'": "|"}[sep]) + 1


def _looks_numeric(row: list[str]) -> bool:
    """Whether the row's first field is a number (a time stamp): data, not a note."""
    first = (row[0] if row else "").strip()
    try:
        float(first.replace(";", " ").replace("\t", " ").replace("|", " ").split()[0])
    except (ValueError, IndexError):
        return False
    return True


def _clip(text: str, n: int = 60) -> str:
    text = text.strip()
    return text if len(text) <= n else text[: n - 1] + "…"


def _floats(table: _Table, j: int, name: str, *, missing_ok: bool,
            limit: float | None = None) -> np.ndarray:
    """Column j as float64; empty -> NaN when `missing_ok`; text, NaN (if not ok), inf and
    (with `limit`) a magnitude above `limit` raise, naming the line."""
    rows = table.rows
    try:  # fast path; blank-but-not-empty fields fall through to the careful one
        values = np.fromiter(map(float, [row[j] or "nan" for row in rows]), dtype=np.float64,
                             count=len(rows))
    except ValueError:
        values = np.empty(len(rows))
        for i, row in enumerate(rows):
            try:
                values[i] = float(row[j]) if row[j].strip() else np.nan
            except ValueError:
                raise table.error(f"text in number column {name}: {row[j].strip()!r}",
                                  row=i) from None
    if not missing_ok:
        bad = np.flatnonzero(np.isnan(values))
        if bad.size:
            i = int(bad[0])
            what = "empty" if not rows[i][j].strip() else "NaN"
            raise table.error(f"{what} value in column {name}", row=i)
    bad = np.flatnonzero(np.isinf(values))
    if bad.size:
        i = int(bad[0])
        raise table.error(f"infinite value in column {name}: {rows[i][j].strip()!r}", row=i)
    if limit is not None:
        with np.errstate(invalid="ignore"):
            bad = np.flatnonzero(np.abs(values) > limit)
        if bad.size:
            i = int(bad[0])
            raise table.error(f"absurd value in column {name}: {rows[i][j].strip()!r} (beyond "
                              f"{limit:g} in magnitude: a corrupt or mistyped number, or "
                              "not mm?)",
                              row=i)
    return values


# a coordinate beyond 10 km is no position on a test bed (micrometres of a 5 m field, which
# the fit's unit check names, are 5e6): a corrupt or mistyped number, refused with its line
# (a 1e300 overflowed the fit's arithmetic into warnings and a traceback)
COORD_LIMIT_MM = 1e7
# frame numbers beyond 2**53 cannot be told apart as float64 (and 2**63 overflows int64)
_FRAME_LIMIT = 2 ** 53
# a gap of more than this many frame intervals with no sample of any marker is not a
# recording but a time stamp far off (and would cost one model row per missing frame)
_MAX_GAP_FRAMES = 1000
_MAX_FRAMES = 10_000_000
# metadata / rig fps and the time stamps must agree to this relative tolerance
_FPS_TOLERANCE = 0.02


def _ints(table: _Table, j: int, name: str) -> np.ndarray:
    raw = [row[j] for row in table.rows]
    try:
        out = np.fromiter(map(int, raw), dtype=np.int64, count=len(raw))
    except (ValueError, OverflowError):  # text, '5.0', '1e19' or a number past int64
        out = np.empty(len(raw), dtype=np.int64)
        for i, s in enumerate(raw):
            if not s.strip():
                raise table.error(f"empty value in column {name}", row=i) from None
            try:
                value = int(s)
            except ValueError:
                try:
                    number = float(s)
                except ValueError:
                    number = float("nan")
                if not (np.isfinite(number) and number.is_integer()):
                    raise table.error(f"column {name} must hold integers, got {s.strip()!r}",
                                      row=i) from None
                value = int(number)
            if abs(value) > _FRAME_LIMIT:
                raise table.error(f"{name} number {s.strip()} is out of range (|{name}| must "
                                  f"be below 2^53)", row=i)
            out[i] = value
    bad = np.flatnonzero(np.abs(out) > _FRAME_LIMIT)
    if bad.size:
        i = int(bad[0])
        raise table.error(f"{name} number {raw[i].strip()} is out of range (|{name}| must be "
                          f"below 2^53)", row=i)
    return out


def _who(markers: list[str], k) -> str:
    return f"marker {markers[int(k)]}" if markers else "every marker"


def _same_sample(values: list[np.ndarray], a: int, b: int) -> bool:
    return all(v[a] == v[b] or (v.dtype.kind == "f" and np.isnan(v[a]) and np.isnan(v[b]))
               for v in values)


def _sort_samples(table: _Table, t: np.ndarray, mi: np.ndarray, rows: np.ndarray,
                  markers: list[str], values: list[np.ndarray],
                  frame: np.ndarray | None) -> np.ndarray:
    """The order that sorts samples by (marker, time), checked; rows may come in any order.

    With rows in any order, "time going backwards" can only show as (DATA.md, README
    "Readings of the contract"): one marker at one time stamp twice with different values
    (an identical repeated row is dropped with a warning), or a frame column that
    disagrees with the time stamps (a marker's frame numbers not increasing with its time,
    or one frame number with two time stamps). `rows` maps each sample to its table row
    (for the line numbers); `values` are the per-sample columns compared for duplicates.
    Returns the indices of the kept samples in (marker, time) order.
    """
    order = np.lexsort((rows, t, mi))  # ties (duplicates) stay in file order
    ts, ms = t[order], mi[order]
    dup = np.flatnonzero((ms[1:] == ms[:-1]) & (ts[1:] == ts[:-1]))
    drop = []
    for k in dup.tolist():
        a, b = int(order[k]), int(order[k + 1])
        if _same_sample(values, a, b):
            drop.append(k + 1)
            continue
        here, before = int(rows[b]), int(rows[a])
        what = (f"marker {markers[int(ms[k])]} appears twice at time_s = {float(ts[k])!r}"
                if markers else f"time_s = {float(ts[k])!r} appears twice")
        raise table.error(f"{what} with different values (also on line {table.lines[before]})",
                          row=here)
    if drop:
        import warnings
        first = int(order[drop[0]])
        warnings.warn(f"{table.path}:{table.lines[int(rows[first])]}: {len(drop)} repeated "
                      f"row(s) (same marker, time and values as an earlier row) ignored",
                      stacklevel=3)
        order = np.delete(order, drop)
        ms = mi[order]
    if frame is not None:
        fs = frame[order]
        bad = np.flatnonzero((ms[1:] == ms[:-1]) & (fs[1:] <= fs[:-1]))
        if bad.size:
            k = int(bad[np.argmin(np.maximum(rows[order[bad]], rows[order[bad + 1]]))])
            here, other = sorted((int(order[k]), int(order[k + 1])), key=lambda i: -rows[i])
            who, line = _who(markers, ms[k]), table.lines[int(rows[other])]
            if frame[here] == frame[other]:
                problem = (f"{who}: frame {int(frame[here])} has two time stamps, "
                           f"{float(t[here])!r} s here and {float(t[other])!r} s on line {line}")
            else:
                problem = (f"time going backwards for {who}: frame {int(frame[here])} at "
                           f"{float(t[here])!r} s here, frame {int(frame[other])} at "
                           f"{float(t[other])!r} s on line {line} (the frame numbers and the "
                           f"time stamps disagree)")
            raise table.error(problem, row=int(rows[here]))
        # one frame, one time stamp, whichever marker
        by_frame = np.lexsort((t, frame))
        fs, ts = frame[by_frame], t[by_frame]
        bad = np.flatnonzero((fs[1:] == fs[:-1]) & (ts[1:] != ts[:-1]))
        if bad.size:
            k = int(bad[0])
            a, b = sorted((int(by_frame[k]), int(by_frame[k + 1])), key=lambda i: rows[i])
            raise table.error(f"frame {int(fs[k])} has two time stamps: {float(t[b])!r} s here "
                              f"and {float(t[a])!r} s on line {table.lines[int(rows[a])]}",
                              row=int(rows[b]))
    return order


def _frame_interval(times: np.ndarray) -> float:
    """The frame interval of sorted distinct time stamps: the mean step over runs of up to
    ten missing frames (robust to gaps and to time stamps rounded to a few decimals)."""
    d = np.diff(times)
    med = float(np.median(d))
    k = np.rint(d / med)
    ok = (k >= 1) & (k <= 10)
    return float(d[ok].sum() / k[ok].sum()) if ok.any() else med


def _check_frame_rate(table: _Table, t: np.ndarray, frame: np.ndarray | None,
                      rig: "Rig | None") -> None:
    """Refuse a time stamp far off (one gap of more than _MAX_GAP_FRAMES frame intervals
    in which no marker is seen) and a metadata or rig fps that disagrees with the time
    stamps. Runs on the distinct time stamps, before anything per-frame is allocated."""
    times, first = np.unique(t, return_index=True)  # first: a sample at each time
    if times.size < 3:
        return
    with np.errstate(over="ignore", invalid="ignore"):
        d = np.diff(times)
    if not np.isfinite(d).all():
        d = np.nan_to_num(d, posinf=np.finfo(float).max)
    med = float(np.median(d))
    gaps = np.flatnonzero(d > _MAX_GAP_FRAMES * med)
    if gaps.size:
        g = int(gaps[np.argmax(d[gaps])])
        if times.size - g - 1 <= g + 1:  # fewer time stamps after the gap: they are off
            odd, other, side = g + 1, g, "after"
        else:
            odd, other, side = g, g + 1, "before"
        raise table.error(
            f"time_s = {float(times[odd])!r} breaks the frame rate: it lies {float(d[g]):.6g} s "
            f"({float(d[g]) / med:.3g} frame intervals of {med:.6g} s) {side} the nearest other "
            f"time stamp, {float(times[other])!r} s on line {table.lines[int(first[other])]} "
            f"(a time stamp far off?)", row=int(first[odd]))
    dt = _frame_interval(times)
    span = float(times[-1] - times[0])
    if span / dt > _MAX_FRAMES:
        raise table.error(f"the time stamps span {span:.6g} s = {span / dt:.3g} frame intervals "
                          f"of {dt:.6g} s: more than {_MAX_FRAMES} frames", row=int(first[-1]))
    step = 1
    if frame is not None:  # a decimated recording: the frame numbers step by k
        f_at = frame[first]
        df = np.diff(f_at)
        single = np.rint(d / dt) == 1
        if single.any():
            step = max(int(np.median(df[single])), 1)
    data_fps = step / dt
    claims = []
    if "fps" in table.meta:
        claims.append((float(table.meta["fps"]), "metadata fps",
                       table.path, table.meta_lines.get("fps")))
    if rig is not None and rig.fps is not None:
        claims.append((float(rig.fps), "[camera] fps", rig.path, None))
    for fps, what, path, line in claims:
        if abs(fps / data_fps - 1) > _FPS_TOLERANCE:
            frames = f" and frame numbers stepping by {step}" if step != 1 else ""
            raise InputError(path, f"{what} {fps:g} disagrees with the time stamps of "
                                   f"{table.path}: one frame every {dt:.6g} s{frames} "
                                   f"= {data_fps:.6g} fps", line=line)


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


def _role_from_name(marker: str) -> str | None:
    lower = marker.lower()
    for prefix, role in _NAME_ROLES:
        if lower.startswith(prefix):
            return role
    return None


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


# -- writing --------------------------------------------------------------------------------

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
