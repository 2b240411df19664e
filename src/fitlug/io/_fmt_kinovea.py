"""Kinovea trajectory exports: CSV (one table) and TXT (one section per track).

CSV (Kinovea's `ExporterCSVTrajectory`): a header `"Time","<track>/<point>/X",
"<track>/<point>/Y",...`, every cell double-quoted, an empty cell where a point has no
value, the locale's decimal separator (the list separator becomes ';' when the decimal is
a comma). TXT (`ExporterTXTTrajectory`): `#Kinovea Trajectory data export`, `#T X Y`, then
per track a `# <name>` line and space-separated `t x y` rows. Time is in seconds by default
(or frames, ms, µs, by the user's preference; older versions write time codes
`h:mm:ss:cc`, the last field hundredths, or thousandths above 100 fps). Coordinates are
in Kinovea's world space by default (preference `ExportSpace.WorldSpace`,
Kinovea.Services/Preferences/PlayerPreferences.cs): `DrawingTrack.CollectMeasuredData` maps
each point through `CalibrationHelper.GetPointAtTime`, whose `CalibratorPlane.
GridToWorldWithOffset` returns (x - x0, -y + y0): y up, in the calibrated unit, or without a
calibration in pixels with the origin at the image centre (`CalibrationHelper.Reset`: a
100 px line from the centre). Since Kinovea 2023.1 the preference `ExportSpace.ImageSpace`
exports the raw image point instead: pixels, origin top-left, y down (`y_origin='top'`).
The unit is not written, so `length_unit` ('px', 'mm', 'cm', 'm', ...) must be given.
"""

from __future__ import annotations

import csv
import io
from decimal import Decimal, InvalidOperation

import numpy as np

from .._errors import InputError
from ._imported import Tracks, length_factor, merge_by_time, number, read_text

_TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "frames": None}


def _time_value(text: str, decimal_comma: bool) -> tuple[float, float]:
    """(time, the resolution it was written to): "0.008" -> (0.008, 0.001)."""
    s = text.strip().strip('"')
    if ":" in s:  # a time code h:mm:ss:cc (or :ccc)
        parts = s.split(":")
        if len(parts) != 4 or not all(p.isdigit() for p in parts):
            raise ValueError(s)
        h, m, sec, frac = parts
        return (int(h) * 3600 + int(m) * 60 + int(sec) + int(frac) / 10 ** len(frac),
                10.0 ** -len(frac))
    value = number(s, decimal_comma)
    try:
        exponent = Decimal(s.replace(",", ".")).as_tuple().exponent
    except InvalidOperation:
        exponent = 0
    return value, 10.0 ** exponent if isinstance(exponent, int) else 0.0


def _frame_numbers(t: np.ndarray, q: float, path: str) -> np.ndarray:
    """Frame numbers (from 0) of increasing stamps `t` written to resolution `q` (Kinovea
    rounds its times: 1 ms in s with three decimals). The rate is the frames over the whole
    span, the frame counts between stamps rounded from it (a gap where no track was seen is
    several); every stamp must lie within its rounding of first stamp + frames / rate."""
    if t.size < 3 or not np.all(np.diff(t) > 0):
        return np.arange(t.size)  # too few, or out of order: _times says what is wrong
    d = np.diff(t)
    step = float(np.median(d))
    for _ in range(20):
        n = np.maximum(np.round(d / step), 1)
        if not np.all(n < 1e7):
            raise InputError(path, f"a gap of {float(np.max(d)):g} between time stamps that step "
                                   f"by {step:g}: no frame rate explains both")
        k = np.concatenate([[0], np.cumsum(n)]).astype(np.int64)
        new = float(t[-1] - t[0]) / float(k[-1])
        if new == step:
            break
        step = new
    off = t - (t[0] + k * step)
    tol = q * (1 + 1e-6) + 1e-9 * float(np.max(np.abs(t)))
    i = int(np.argmax(np.abs(off)))
    if abs(off[i]) > tol:
        raise InputError(path, f"the time stamps keep no steady frame rate: the stamp {t[i]:g} is "
                               f"{abs(off[i]):.3g} off frame {k[i]} at {1 / step:.6g} frames per "
                               f"time unit (the whole span's rate), more than the stamps' rounding "
                               f"{q:g}")
    return k


def _seconds(t: np.ndarray, k: np.ndarray, fps: float | None, path: str,
             codes: bool) -> tuple[np.ndarray, str]:
    """Kinovea's time column in s: as written (s) unless an fps shows it is ms, µs or frames."""
    if codes or fps is None or t.size < 3:
        return t, "s"
    step = float(t[-1] - t[0]) / float(k[-1] - k[0])  # the span's step, not the commonest
    for unit, scale in _TIME_UNITS.items():
        s = step * (scale if scale is not None else 1.0 / fps)
        if step > 0 and abs(s * fps - 1) <= 0.02:
            return (t * scale if scale is not None else t / fps), unit
    raise InputError(path, f"the time column steps by {step:g} per frame, which matches "
                           f"{fps:g} fps in none of s, ms, µs or frames")


def _positions(xy: np.ndarray, length_unit: str | None, path: str,
               y_origin: str | None = None) -> dict:
    if not length_unit:
        raise InputError(path, "Kinovea's export does not say its length unit: give "
                               "--length-unit (px when it is not calibrated, or mm, cm, m)")
    if length_unit == "px":
        if y_origin == "top" and np.nanmin(xy, initial=0.0) < 0:
            raise InputError(path, "negative pixel coordinates, which Kinovea's image-space "
                                   "export (origin top-left) never writes: this is its world "
                                   "space (origin at the image centre, y up); leave out "
                                   "--y-origin top")
        return {"xy_px": xy, "px_y_up": y_origin != "top",
                "meta": {"pixel_origin": "top-left (image space)" if y_origin == "top"
                         else "image centre, y up (world space)"}}
    if y_origin == "top":
        raise InputError(path, "--y-origin top is for Kinovea's image-space export, in pixels "
                               "(--length-unit px); calibrated units are its world space, y up")
    return {"xy_mm": xy * length_factor(length_unit, path, "--length-unit")}


def read_kinovea_csv(path: str, length_unit: str | None = None,
                     fps: float | None = None, y_origin: str | None = None) -> Tracks:
    """Kinovea's trajectory CSV; see the module docstring for the conventions."""
    text = read_text(path)
    first = text.lstrip().splitlines()[0] if text.strip() else ""
    delim = ";" if first.startswith('"Time";') else ","
    rows = list(csv.reader(io.StringIO(text), delimiter=delim))
    numbered = [(i + 1, r) for i, r in enumerate(rows) if any(c.strip() for c in r)]
    header = [c.strip() for c in numbered[0][1]]
    if not header or header[0] != "Time":
        raise InputError(path, "a Kinovea CSV starts with the column \"Time\"", line=1)
    names: dict[str, dict[str, int]] = {}
    for j, h in enumerate(header[1:], 1):
        base, _, axis = h.rpartition("/")
        if axis not in ("X", "Y") or not base:
            raise InputError(path, f"column {h!r} is not <track>/<point>/X or /Y", line=1)
        names.setdefault(base, {})[axis] = j
    for base, c in names.items():
        if set(c) != {"X", "Y"}:
            raise InputError(path, f"{base} has no {'Y' if 'X' in c else 'X'} column", line=1)
    data, lines = [r for _, r in numbered[1:]], [n for n, _ in numbered[1:]]
    if not data:
        raise InputError(path, "no rows below the header", line=1)
    decimal_comma = delim == ";"
    codes = any(":" in r[0] for r in data[:5])
    t, q = np.empty(len(data)), 0.0
    for i, r in enumerate(data):
        try:
            t[i], qi = _time_value(r[0], decimal_comma)
            q = max(q, qi)
        except ValueError:
            raise InputError(path, f"Time {r[0]!r} is not a number or a time code",
                             line=lines[i]) from None
    xy = np.full((len(data), len(names), 2), np.nan)
    for m, base in enumerate(names):
        for a, axis in enumerate("XY"):
            j = names[base][axis]
            for i, r in enumerate(data):
                try:
                    xy[i, m, a] = number(r[j] if j < len(r) else "", decimal_comma)
                except ValueError:
                    raise InputError(path, f"column {header[j]}: {r[j]!r} is not a number",
                                     line=lines[i]) from None
    k = _frame_numbers(t, q, path)
    t, unit = _seconds(t, k, fps, path, codes)
    # short names: the track alone when each track has one point
    tracks = [b.split("/")[0] for b in names]
    short = tracks if len(set(tracks)) == len(tracks) else list(names)
    pos = _positions(xy, length_unit, path, y_origin)
    return Tracks("kinovea-csv", path, tuple(short), k, t=t,
                  meta={"time_unit": unit, "length_unit": length_unit or "",
                        **pos.pop("meta", {})}, **pos)


def read_kinovea_txt(path: str, length_unit: str | None = None,
                     fps: float | None = None, y_origin: str | None = None) -> Tracks:
    """Kinovea's trajectory TXT (gnuplot style); see the module docstring."""
    lines = read_text(path).splitlines()
    if not lines or not lines[0].startswith("#Kinovea Trajectory data export"):
        raise InputError(path, "not a Kinovea trajectory TXT (first line "
                               "'#Kinovea Trajectory data export')", line=1)
    series, name, rows = [], None, []

    def close():
        if name is not None:
            if not rows:
                raise InputError(path, f"track {name!r} has no rows")
            arr = np.array([r[1] for r in rows])
            series.append((name, np.array([r[0] for r in rows]), arr))

    codes, q = False, 0.0
    for no, ln in enumerate(lines, 1):
        s = ln.strip()
        if not s or s.startswith("#T") or no == 1:
            continue
        if s.startswith("#"):
            close()
            name, rows = s[1:].strip(), []
            continue
        if name is None:
            raise InputError(path, "a data row before any '# <track name>' line", line=no)
        cells = s.split()
        if len(cells) < 3:
            raise InputError(path, f"expected 't x y', got {s!r}", line=no)
        try:
            codes = codes or ":" in cells[0]
            stamp, qi = _time_value(cells[0], True)
            q = max(q, qi)
            rows.append((stamp, (number(cells[1], True), number(cells[2], True))))
        except ValueError:
            raise InputError(path, f"not numbers: {s!r}", line=no) from None
    close()
    if not series:
        raise InputError(path, "no track section ('# <name>' and rows)")
    names = [s[0] for s in series]
    if len(set(names)) != len(names):
        raise InputError(path, "two tracks share a name")
    t, xy = merge_by_time(path, "Kinovea", series)
    k = _frame_numbers(t, q, path)
    t, unit = _seconds(t, k, fps, path, codes)
    pos = _positions(xy, length_unit, path, y_origin)
    return Tracks("kinovea-txt", path, tuple(names), k, t=t,
                  meta={"time_unit": unit, "length_unit": length_unit or "",
                        **pos.pop("meta", {})}, **pos)
