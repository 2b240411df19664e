"""Two recordings in one file: the time stamps continue, the positions start again.

Concatenated runs (a tracker appending the next take, a user pasting two files) show as
a frame at which every body marker jumps at once (at least half of those seen on both
sides: a static reflection labelled body stays put), by one common displacement (the body
is rigid) or each back against the direction of travel (the ids of the first run may
end swapped), far more than the body moves in a frame anywhere else, and stays there. A
glitch comes back within a frame or two; an identity swap moves two markers by opposite
displacements; markers entering or leaving the picture do not jump. When no id spans
the join (new ids for the second run, fragments), the body markers' centre in a frame is
thrown back against the travel by more than the body's extent instead, and so is one
body marker seen again after a gap (it left the picture) that far back. Such a file is
refused (the line of the first frame of the second run is named): fitting it as one run
gave a slip 8 % off and k, C_rr a thousand times too large.
"""

from __future__ import annotations

import numpy as np

#: a jump is this many times the body's 90th-percentile motion in one frame, plus 1 mm
JUMP_FACTOR = 20.0
JUMP_MIN_MM = 1.0
AGREE = 0.2  # body markers' jumps agree to this fraction of their size
STAY_FRAMES = 3  # no jump back within this many samples after
BACK = 0.7  # cosine: a jump back against the direction of travel


def find_restart(rec) -> dict | None:
    """The first frame where every body marker jumps by one common displacement and stays.

    Returns {"t": time of the first frame after the jump, "t_before": the frame before,
    "jump_mm": (dx, dy), "markers": [ids]} or None.
    """
    times = np.unique(rec.t)
    if times.size < 10:
        return None
    dt = float(np.median(np.diff(times)))
    valid = np.isfinite(rec.x) & np.isfinite(rec.y)
    body = np.isin(rec.marker_index, rec.markers_of("body")) & valid
    if body.sum() < 10:
        return None
    mi, t, x, y = rec.marker_index[body], rec.t[body], rec.x[body], rec.y[body]
    same = mi[1:] == mi[:-1]  # samples are sorted by (marker, t)
    gap = np.maximum(np.rint((t[1:] - t[:-1]) / dt), 1.0)
    dx, dy = x[1:] - x[:-1], y[1:] - y[:-1]
    size = np.hypot(dx, dy)
    per_frame = (size / gap)[same]
    if per_frame.size < 10:
        return None
    thresh = JUMP_FACTOR * float(np.percentile(per_frame, 90)) + JUMP_MIN_MM
    cand = np.flatnonzero(same & (size > thresh))
    # the direction of travel: the body's steps, jumps left out (the net displacement of
    # two runs may be nil)
    steady = same & ~(size > thresh)
    travel = np.array([dx[steady].sum(), dy[steady].sum()])
    travel = travel / max(float(np.hypot(*travel)), 1e-12)
    if cand.size > 50:  # many jumps: a broken tracker, not two runs
        return None
    by_time: dict[float, list[int]] = {}
    for k in cand.tolist():
        by_time.setdefault(float(t[k + 1]), []).append(k)
    for t_after in sorted(by_time):
        ks = by_time[t_after]
        # every body marker seen just before and at t_after jumps
        seen = set(np.intersect1d(mi[t == t_after],
                                  mi[(t < t_after) & (t >= t_after - 3 * dt)]).tolist())
        jumped = {int(mi[k]) for k in ks}
        # every body marker seen on both sides jumps (at least half of them: a static
        # reflection labelled body stays where it is)
        if not seen or not jumped <= seen or 2 * len(jumped) < len(seen):
            continue
        vec = np.array([[dx[k], dy[k]] for k in ks])
        mean = vec.mean(axis=0)
        agree = not np.any(np.hypot(*(vec - mean).T) > AGREE * np.hypot(*mean))
        # every marker thrown back against the travel (ids swapped in the first run make
        # their jumps differ by the markers' spacing)
        back_all = bool(np.all(vec @ travel < -BACK * np.hypot(*vec.T)))
        if not (agree or back_all):
            continue  # opposite jumps: an identity swap, not a restart
        back = False
        for k in ks:  # the jump stays: no step back towards the old position soon after
            after = np.arange(k + 1, min(k + 1 + STAY_FRAMES, mi.size - 1))
            after = after[same[after]]
            if np.any(size[after] > 0.5 * size[k]):
                back = True
        if back:
            continue
        k0 = ks[0]
        return {"t": t_after, "t_before": float(t[k0]), "jump_mm": (float(mean[0]),
                                                                     float(mean[1])),
                "markers": [rec.markers[m] for m in sorted(jumped)]}
    return _restart_without_ids(rec, t, x, y, mi, travel, thresh, dt, same, dx, dy)


def _restart_without_ids(rec, t, x, y, mi, travel, thresh, dt, same, dx, dy) -> dict | None:
    """The same, when no marker id spans the join (the tracker's ids of the second run are
    new, or the markers at the join are fragments): the body markers' centre of a frame
    thrown back against the travel by more than the body's extent (the spread of its
    markers in one frame, which a hand-over from one marker to another can move it by)
    plus the jump threshold, and staying there."""
    times, inv = np.unique(t, return_inverse=True)
    if times.size < 10:
        return None
    n = np.bincount(inv, minlength=times.size)
    proj = x * travel[0] + y * travel[1]  # along the travel
    centre = np.bincount(inv, weights=proj, minlength=times.size) / np.maximum(n, 1)
    lo = np.full(times.size, np.inf)
    hi = np.full(times.size, -np.inf)
    np.minimum.at(lo, inv, proj)
    np.maximum.at(hi, inv, proj)
    extent = float(np.percentile(hi - lo, 95))
    # one marker seen again after a gap (it left the picture) further back than the body
    # is long: the robot does not drive backwards, a second run starts behind
    back = same & ((dx * travel[0] + dy * travel[1]) < -(extent + thresh))
    if back.any():
        k = int(np.flatnonzero(back)[0])
        return {"t": float(t[k + 1]), "t_before": float(t[k]),
                "jump_mm": (float(dx[k]), float(dy[k])), "markers": [rec.markers[mi[k]]],
                "gap": True}
    step = np.diff(centre)
    near = np.diff(times) <= 3 * dt * 1.01
    cand = np.flatnonzero(near & (step < -(extent + thresh)))
    for k in cand.tolist()[:50]:
        after = centre[k + 1:k + 1 + STAY_FRAMES]
        if after.size and np.all(np.abs(after - centre[k + 1]) <= extent + thresh):
            before = mi[inv == k].tolist()
            at = mi[inv == k + 1].tolist()
            jump = float(step[k])
            return {"t": float(times[k + 1]), "t_before": float(times[k]),
                    "jump_mm": (jump * float(travel[0]), jump * float(travel[1])),
                    "markers": [rec.markers[m] for m in sorted(set(before) | set(at))]}
    return None


def restart_problem(found: dict) -> str:
    """The one-line problem for a restart `found` by :func:`find_restart`."""
    dx, dy = found["jump_mm"]
    names = ", ".join(found["markers"])
    if found.get("gap"):
        return (f"two recordings in one file? body marker {names} is seen again at time_s = "
                f"{found['t']!r} ({dx:.4g}, {dy:.4g}) mm from where it was last seen "
                f"({found['t_before']!r} s), back against the travel by more than the "
                "body is long: the time stamps continue but the positions start again; "
                "split the file into its runs")
    return (f"two recordings in one file? at time_s = {found['t']!r} every body marker "
            f"({names}) jumps by ({dx:.4g}, {dy:.4g}) mm from the frame before "
            f"({found['t_before']!r} s) and stays there: the time stamps continue but the "
            "positions start again; split the file into its runs")
