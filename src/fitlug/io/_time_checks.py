"""The samples of a trajectories.csv put in order and checked against the frame rate.

`_sort_samples` sorts by (marker, time), drops identical repeated rows and refuses what
can only be time going backwards; `_check_frame_rate` refuses a time stamp far off and a
metadata or rig fps that disagrees with the time stamps. Both name the line.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from .._errors import InputError
from ._table import _Table

if TYPE_CHECKING:
    from ._rig import Rig

# a gap of more than this many frame intervals with no sample of any marker is not a
# recording but a time stamp far off (and would cost one model row per missing frame)
_MAX_GAP_FRAMES = 1000
_MAX_FRAMES = 10_000_000
# metadata / rig fps and the time stamps must agree to this relative tolerance
_FPS_TOLERANCE = 0.02


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
