"""Two recordings in one file: the time stamps continue, the positions start again.

Concatenated runs (a tracker appending the next take, a user pasting two files) show as
a frame at which every body marker jumps at once, by one common displacement (the body
is rigid) or each back against the direction of travel (the ids of the first run may
end swapped), far more than the body moves in a frame anywhere else, and stays there. A
glitch comes back within a frame or two; an identity swap moves two markers by opposite
displacements; markers entering or leaving the picture do not jump. Such a file is
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
    if cand.size == 0 or cand.size > 50:  # many jumps: a broken tracker, not two runs
        return None
    # the direction of travel: the body's steps, jumps left out (the net displacement of
    # two runs may be nil)
    steady = same & ~(size > thresh)
    travel = np.array([dx[steady].sum(), dy[steady].sum()])
    travel = travel / max(float(np.hypot(*travel)), 1e-12)
    by_time: dict[float, list[int]] = {}
    for k in cand.tolist():
        by_time.setdefault(float(t[k + 1]), []).append(k)
    for t_after in sorted(by_time):
        ks = by_time[t_after]
        # every body marker seen just before and at t_after jumps
        seen = set(np.intersect1d(mi[t == t_after],
                                  mi[(t < t_after) & (t >= t_after - 3 * dt)]).tolist())
        jumped = {int(mi[k]) for k in ks}
        if not seen or seen != jumped:
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
    return None


def restart_problem(found: dict) -> str:
    """The one-line problem for a restart `found` by :func:`find_restart`."""
    dx, dy = found["jump_mm"]
    names = ", ".join(found["markers"])
    return (f"two recordings in one file? at time_s = {found['t']!r} every body marker "
            f"({names}) jumps by ({dx:.4g}, {dy:.4g}) mm from the frame before "
            f"({found['t_before']!r} s) and stays there: the time stamps continue but the "
            "positions start again; split the file into its runs")
