"""Plausibility of a recording before it is fitted: say what looks wrong, in one line.

`check_recording` runs first in `build_problem`. It refuses (InputError naming the file)
what the fit could only turn into a misleading "did not converge" or a silently wrong
number, and drops markers that hold no sample at all (with a warning line):

- marker ids that are not tracks: a new id on nearly every frame (at least 50 ids, with a
  median of fewer than 3 samples each or more ids than frames): refused, with "link the
  tracks first" (`check_marker_ids`, called first by fitlug.fit._prepare).
- a marker with no valid sample (x_mm, y_mm empty in every row): dropped, with a warning
  naming it. A tracker may list a marker it never found, and the other markers still
  measure everything; refusing would block a good recording for an empty column. When
  every marker of a role is empty the recording is refused (naming them).
- a robot that never moves: the body markers' travel is within the noise (or below 1 µm).
  If the lug markers do move, the message says the track turns while the body stands
  still (slip 100 %).
- values in another unit, judged from figures that do not depend on the motion profile:
  the markers' vertical spread in a frame (lug markers above and below the wheels, body
  markers above: 2 mm to 5 m on any tracked vehicle), the noise from fourth differences
  (below 1 mm; fitlug.fit._noise), the body's mean speed (below 10 m/s) and the frame
  interval (at most 1 s). The message names the figure, its plausible range and the
  unit the data look like (metres or micrometres as mm, milliseconds as s). Noise below
  0.1 µm alone is not refused: a noiseless simulation has it.
- a time stamp far off (a gap of more than 1000 frame intervals), and
- a [camera] fps in rig.toml that disagrees with the time stamps (fitlug.io checks it
  when it reads the file with its rig; this repeats it for recordings built in memory).
"""

from __future__ import annotations

import warnings

import numpy as np

from .._errors import InputError
from ._noise import fourth_differences, noise_from_differences

MIN_FRAMES = 20  # frames a recording needs to be fitted (build_problem) or judged here

# plausible ranges (mm, mm/s, s); outside: most likely another unit
SPREAD_MM = (2.0, 5000.0)
NOISE_MAX_MM = 1.0
SPEED_MAX_MM_S = 1e4
FRAME_INTERVAL_MAX_S = 1.0
# a robot "moves" when its body travels more than this many noise sigmas (and > 1 µm)
MOVE_SIGMAS = 50.0
MOVE_MIN_MM = 1e-3
# this many marker ids or more are judged for "a new id on nearly every frame"
ID_FLOOD_MIN = 50


def _unit_hint(value: float, lo: float, hi: float) -> str:
    """Which unit a figure outside [lo, hi] looks like, as a phrase."""
    if value < lo:
        return "the positions look like metres, not mm (x 1000)" if value * 1000 >= lo * 0.5 \
            else "the positions look far too small for mm"
    return "the positions look like micrometres, not mm (/ 1000)" if value / 1000 <= hi * 2 \
        else "the positions look far too large for mm"


def _drop_empty(rec):
    valid = rec.valid
    counts = np.bincount(rec.marker_index[valid], minlength=rec.n_markers)
    is_empty = counts == 0
    empty = np.flatnonzero(is_empty).tolist()
    if not empty:
        return rec
    for role in ("body", "lug"):
        ids = [m for m, r in enumerate(rec.roles) if r == role]
        if ids and all(is_empty[m] for m in ids):
            names = ", ".join(rec.markers[m] for m in ids)
            raise InputError(rec.path, f"every {role} marker ({names}) is empty: x_mm and y_mm "
                                       "are missing in all their rows")
    names = ", ".join(rec.markers[m] for m in empty)
    warnings.warn(f"{rec.path or '<recording>'}: marker(s) {names} have no valid sample "
                  "(x_mm, y_mm empty in all their rows): left out of the fit", stacklevel=3)
    keep = ~is_empty
    new_index = np.cumsum(keep) - 1
    rows = keep[rec.marker_index]
    changes = {name: getattr(rec, name)[rows]
               for name in ("t", "x", "y", "sigma", "frame", "x_px", "y_px", "quality")
               if getattr(rec, name) is not None}
    return rec.with_(markers=tuple(m for m, k in zip(rec.markers, keep) if k),
                     roles=tuple(r for r, k in zip(rec.roles, keep) if k),
                     marker_index=new_index[rec.marker_index[rows]], **changes)


def _per_marker(rec, role):
    """(t, x, y) of the valid samples of each marker with `role`, in the file's order per
    marker: one stable sort, linear in the samples (not markers x samples)."""
    valid = np.flatnonzero(rec.valid)
    order = valid[np.argsort(rec.marker_index[valid], kind="stable")]
    mi = rec.marker_index[order]
    edges = np.searchsorted(mi, np.arange(rec.n_markers + 1))
    out = []
    for m, r in enumerate(rec.roles):
        if r == role:
            sel = order[edges[m]:edges[m + 1]]
            out.append((rec.t[sel], rec.x[sel], rec.y[sel]))
    return out


def check_coordinates(rec) -> None:
    """Refuse a position beyond COORD_LIMIT_MM (fitlug.io names its line when it reads a
    file; this guards recordings built in memory, where a 1e300 overflowed into warnings
    and a traceback), naming the marker and the time."""
    from ..io._trajectories import COORD_LIMIT_MM

    for name in ("x", "y"):
        v = getattr(rec, name)
        with np.errstate(invalid="ignore"):
            bad = np.flatnonzero(~(np.abs(v) <= COORD_LIMIT_MM) & ~np.isnan(v))
        if bad.size:
            i = int(bad[0])
            raise InputError(rec.path, f"absurd {name}_mm {float(v[i])!r} of marker "
                                       f"{rec.markers[rec.marker_index[i]]} at time_s "
                                       f"{float(rec.t[i])!r} (beyond {COORD_LIMIT_MM:g} in "
                                       "magnitude: a corrupt or mistyped number, or not mm?)")


def check_marker_ids(rec) -> None:
    """Refuse a recording whose marker ids are not tracks: a new id on nearly every frame
    (a tracker's unlinked detections), which no per-marker step can use. Judged in linear
    time, before anything loops over the markers: at least ID_FLOOD_MIN ids with a median of
    fewer than 3 samples each, or more ids than frames."""
    if rec.n_markers < ID_FLOOD_MIN:
        return
    valid = rec.valid
    counts = np.bincount(rec.marker_index[valid], minlength=rec.n_markers)
    counts = counts[counts > 0]
    if counts.size < ID_FLOOD_MIN:
        return
    n_frames = np.unique(rec.t[valid]).size
    median = float(np.median(counts))
    if median < 3 or counts.size > n_frames:
        raise InputError(rec.path, f"{counts.size} marker ids in {n_frames} frames, "
                                   f"{median:g} sample(s) per id at the median: a new marker "
                                   "id on nearly every frame, not tracks; link the tracks "
                                   "first (one id per physical marker over the recording)")


def _noise(tracks) -> float:
    diffs = [fourth_differences(t, v) for t, x, y in tracks for v in (x, y)]
    sigma, _ = noise_from_differences(diffs)
    return sigma


def _span(v: np.ndarray) -> float:
    return float(np.percentile(v, 99) - np.percentile(v, 1)) if v.size >= 2 else 0.0


def _check_moves(rec, body, lug, sigma) -> None:
    travel = max((_span(x) for _, x, _ in body), default=0.0)
    floor = max(MOVE_SIGMAS * (sigma if np.isfinite(sigma) else 0.0), MOVE_MIN_MM)
    if travel > floor:
        return
    lug_travel = max((_span(x) for _, x, _ in lug), default=0.0)
    t = rec.t[rec.valid]
    duration = float(t.max() - t.min()) if t.size else 0.0
    what = (f"the robot never moves: its body markers travel {travel:.3g} mm in "
            f"{duration:.3g} s, within the noise ({sigma:.2g} mm)")
    if lug_travel > floor:
        what += (f", while the lug markers travel {lug_travel:.3g} mm: the track turns but "
                 f"the body stands still (slip 100 %?)")
    raise InputError(rec.path, what + "; the fit needs a recording of the robot driving")


def _check_units(rec, body, lug, sigma) -> None:
    valid = rec.valid
    t, y = rec.t[valid], rec.y[valid]
    is_body = np.isin(rec.marker_index[valid], rec.markers_of("body"))
    # vertical spread in a frame, over the frames that see a body and a lug marker: the
    # body markers sit above the wheels, the lug markers run above and below them
    order = np.argsort(t, kind="stable")
    ts, ys, bs = t[order], y[order], is_body[order]
    starts = np.flatnonzero(np.r_[True, ts[1:] != ts[:-1]]) if ts.size else np.empty(0, int)
    n_body = np.add.reduceat(bs.astype(int), starts) if ts.size else np.empty(0)
    counts = np.diff(np.r_[starts, ts.size])
    both = (n_body >= 1) & (n_body < counts)
    if both.any():
        spread = float(np.median((np.maximum.reduceat(ys, starts)
                                  - np.minimum.reduceat(ys, starts))[both]))
        lo, hi = SPREAD_MM
        if not lo <= spread <= hi:
            raise InputError(rec.path, f"the markers' vertical spread in a frame is "
                                       f"{spread:.3g} mm (median over frames), outside the "
                                       f"plausible {lo:g} mm to {hi / 1000:g} m for a tracked "
                                       f"robot: {_unit_hint(spread, lo, hi)}")
    if np.isfinite(sigma) and sigma > NOISE_MAX_MM:
        raise InputError(rec.path, f"the position noise (from 4th differences) is "
                                   f"{sigma:.3g} mm, above the plausible {NOISE_MAX_MM:g} mm: "
                                   "the tracker failed, or the positions are in another unit "
                                   "than mm")
    times = np.unique(t)
    if times.size >= 2:
        step = float(np.median(np.diff(times)))
        if step > FRAME_INTERVAL_MAX_S:
            raise InputError(rec.path, f"one frame every {step:.6g} s (median time step) is "
                                       f"slower than any plausible camera (at most "
                                       f"{FRAME_INTERVAL_MAX_S:g} s): the time stamps look "
                                       "like milliseconds, not seconds")
        duration = float(times[-1] - times[0])
        travel = max((_span(x) for _, x, _ in body), default=0.0)
        speed = travel / duration
        if speed > SPEED_MAX_MM_S:
            raise InputError(rec.path, f"the body markers travel {travel:.4g} mm in "
                                       f"{duration:.4g} s = {speed / 1000:.3g} m/s, above the "
                                       f"plausible {SPEED_MAX_MM_S / 1000:g} m/s: "
                                       f"{_unit_hint(speed, 0.0, SPEED_MAX_MM_S)}")


def _check_rig_fps(rec, rig) -> None:
    fps = getattr(rig, "fps", None)
    times = np.unique(rec.t)
    if fps is None or times.size < 3:
        return
    d = np.diff(times)
    med = float(np.median(d))
    k = np.rint(d / med)
    ok = (k >= 1) & (k <= 10)
    dt = float(d[ok].sum() / k[ok].sum())
    step = 1
    if rec.frame is not None:  # a decimated recording: frame numbers step by k
        _, first = np.unique(rec.t, return_index=True)
        df = np.diff(rec.frame[first])
        single = np.rint(d / dt) == 1
        if single.any():
            step = max(int(np.median(df[single])), 1)
    if abs(fps * dt / step - 1) > 0.02:
        raise InputError(getattr(rig, "path", None),
                         f"[camera] fps {fps:g} disagrees with the time stamps of "
                         f"{rec.path or 'the recording'}: one frame every {dt:.6g} s = "
                         f"{step / dt:.6g} fps")


def _check_gaps(rec) -> None:
    """A time stamp far off (fitlug.io names its line when it reads a file; this guards
    recordings built in memory): refused before anything is allocated per frame."""
    times = np.unique(rec.t)
    if times.size < 3:
        return
    with np.errstate(over="ignore", invalid="ignore"):
        d = np.diff(times)
    med = float(np.median(d))
    g = int(np.argmax(d))
    if not d[g] <= 1000 * med:
        odd = times[g + 1] if times.size - g - 1 <= g + 1 else times[g]
        raise InputError(rec.path, f"time_s = {float(odd)!r} breaks the frame rate: a gap of "
                                   f"{float(d[g]):.6g} s against a frame interval of "
                                   f"{med:.6g} s (a time stamp far off?)")


def check_recording(rec, rig):
    """The recording to fit: `rec` less its empty markers (warned), after the checks above.

    Raises:
        InputError: naming the file and what looks wrong (see the module docstring).
    """
    _check_gaps(rec)
    rec = _drop_empty(rec)
    _check_rig_fps(rec, rig)
    if np.unique(rec.t[rec.valid]).size < MIN_FRAMES:
        return rec  # too short to judge: build_problem says how many frames it needs
    body, lug = _per_marker(rec, "body"), _per_marker(rec, "lug")
    sigma = _noise(body + lug)
    if body:
        _check_moves(rec, body, lug, sigma)
    _check_units(rec, body, lug, sigma)
    return rec
