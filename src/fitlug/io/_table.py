"""The CSV table of a trajectories.csv: its rows with their physical line numbers, then
typed columns.

`_read_table` reads the file (gzip decompressed transparently, UTF-8, `# key: value`
metadata from the preamble) row-wise with the csv module, to keep line numbers for the
errors; `_columns`, `_check_row_lengths` and the separator checks judge its shape;
`_floats` and `_ints` read a column at a time with numpy, so 10^5 rows take a fraction of
a second.
"""

from __future__ import annotations

import csv
import re
import sys
from array import array

import numpy as np

from .._errors import InputError
from ._files import read_bytes

_LONG_REQUIRED = ("time_s", "marker", "role", "x_mm", "y_mm")
# file column -> Recording field, for the optional per-sample columns
_LONG_OPTIONAL = {"frame": "frame", "sigma_mm": "sigma", "x_px": "x_px", "y_px": "y_px",
                  "quality": "quality"}
_META_LINE = re.compile(r"^#\s*([A-Za-z_][\w.\-]*)\s*:\s*(.*?)\s*$")


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

    data = _gunzip(path, read_bytes(path, "CSV file"))
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



# frame numbers beyond 2**53 cannot be told apart as float64 (and 2**63 overflows int64)
_FRAME_LIMIT = 2 ** 53


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
