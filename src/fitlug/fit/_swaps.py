"""Identity swaps: two markers of one role exchange their ids from one frame on.

A tracker that confuses two markers (they pass close, one is hidden for a frame) may go
on with their ids exchanged. Each id then jumps, in one frame, to where the other marker
was heading, and stays there; fitted as they stand, each id holds two markers' paths
(slip 2 % off, chi^2/dof 6e5, an explanation that does not end). The data say which:

- a *jump* of a marker at frame t: its step from the sample before differs from its own
  local step (the median of the two steps before and the two after) by more than
  JUMP_SIGMAS times the role's noise of steps and JUMP_MIN_MM;
- a *swap* of markers a and b at t: both jump at t, and each lands where the other was
  heading (its position extrapolated from its two samples before t), to within
  LAND_FRACTION of the jump and LAND_MM; three or more ids permuted in one frame are
  the same, a cycle of landings.

The samples of a and b from t on are exchanged (the tails re-joined to their physical
markers, as tracker fragments are), and the swap is listed (fit.json `swaps`). Swaps are
undone latest first (the tracker made them in time order, and two that share a marker do
not commute), so chains of swaps and a swap back all come undone. A jump that is no
swap (a glitch, a marker knocked loose) is left to the glitch rule and the explanation.
"""

from __future__ import annotations

import warnings

import numpy as np

JUMP_SIGMAS = 30.0
JUMP_MIN_MM = 0.5
LAND_FRACTION = 0.2
LAND_MM = 5.0
MAX_GAP = 3  # frames: samples further apart are not compared
MAX_JUMPS = 200  # more jumps than this: a broken tracker, left to the other checks


def _jumps(t, x, y, mi, dt):
    """Per sample k (of samples sorted by (marker, t)): jump size at k (NaN where the
    sample before is not of the same marker or too far), and the predicted position."""
    n = t.size
    size = np.full(n, np.nan)
    pred = np.full((n, 2), np.nan)
    if n < 6:
        return size, pred
    same = (mi[1:] == mi[:-1]) & ((t[1:] - t[:-1]) <= MAX_GAP * dt * 1.01)
    d = np.stack([x[1:] - x[:-1], y[1:] - y[:-1]], axis=1)  # step into sample k+1
    d[~same] = np.nan
    # local step: the median of the steps two before and two after (NaN-aware)
    pad = np.full((2, 2), np.nan)
    dp = np.vstack([pad, d, pad])
    neigh = np.stack([dp[0:-4], dp[1:-3], dp[3:-1], dp[4:]], axis=0)  # (4, n-1, 2)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN neighbours at a gap
        local = np.nanmedian(neigh, axis=0)
    dev = np.hypot(*(d - local).T)
    size[1:] = dev
    # where each marker was heading at sample k: from its two samples before
    prev = np.stack([x[:-1], y[:-1]], axis=1)
    step_before = np.vstack([np.full((1, 2), np.nan), d[:-1]])
    pred[1:] = prev + np.where(np.isfinite(step_before), step_before, 0.0)
    return size, pred


def _cycles(lands: dict) -> list:
    """The cycles of a partial map (each a list of keys, in map order)."""
    out, done = [], set()
    for start in lands:
        if start in done:
            continue
        path, k = [], start
        while k in lands and k not in path and k not in done:
            path.append(k)
            k = lands[k]
        if k == start and len(path) >= 2:
            out.append(path)
        done.update(path)
    return out


def find_and_repair(rec):
    """`rec` with swapped tails exchanged back, and the list of swaps found:
    [{"markers": [a, b], "role": .., "t_s": .., "jump_mm": .., "reason": ..}]."""
    valid = rec.valid
    times = np.unique(rec.t[valid])
    if times.size < 10:
        return rec, []
    dt = float(np.median(np.diff(times)))
    mi_all = rec.marker_index.copy()
    found = []
    found_all = []  # (t, a, b): repaired latest first (each an exchange of tails)
    for role in ("lug", "body"):
        ids = rec.markers_of(role)
        if ids.size < 2:
            continue
        sel = np.flatnonzero(valid & np.isin(rec.marker_index, ids))
        t, x, y, mi = rec.t[sel], rec.x[sel], rec.y[sel], rec.marker_index[sel]
        size, pred = _jumps(t, x, y, mi, dt)
        ok = np.isfinite(size)
        if ok.sum() < 10:
            continue
        noise = 1.4826 * float(np.median(np.abs(size[ok] - np.median(size[ok]))))
        noise = max(noise, float(np.median(size[ok])))
        thresh = max(JUMP_SIGMAS * noise, JUMP_MIN_MM)
        cand = np.flatnonzero(ok & (size > thresh))
        if cand.size < 2 or cand.size > MAX_JUMPS:
            continue
        by_time: dict = {}
        for k in cand.tolist():
            by_time.setdefault(float(t[k]), []).append(k)
        for tk in sorted(by_time):
            ks = by_time[tk]
            # each jumping id to the marker whose path it landed on (where that one was
            # heading); the ids that form cycles were permuted by the tracker
            lands = {}
            for ka in ks:
                pa = np.array([x[ka], y[ka]])
                near = [kb for kb in ks if kb != ka and np.hypot(*(pa - pred[kb]))
                        < min(LAND_FRACTION * max(size[ka], size[kb]), LAND_MM)]
                if len(near) == 1:
                    lands[ka] = near[0]
            for cycle in _cycles(lands):
                ids_c = [int(mi[k]) for k in cycle]
                relabel = {int(mi[k]): int(mi[lands[k]]) for k in cycle}
                found_all.append((tk, relabel))
                found.append({"markers": [rec.markers[m] for m in ids_c], "role": role,
                              "t_s": tk, "jump_mm": float(max(size[k] for k in cycle)),
                              "reason": "the ids jump in one frame, each to where another "
                                        "of them was heading: their samples from t_s on "
                                        "are given back to the markers they follow"})
    if not found:
        return rec, []
    # the faulty ids are the exchanges applied in time order, so they come undone in the
    # reverse order (exchanges that share a marker do not commute)
    for tk, relabel in sorted(found_all, key=lambda f: -f[0]):
        tail = rec.t >= tk
        masks = {a: tail & (mi_all == a) for a in relabel}
        for a, b in relabel.items():
            mi_all[masks[a]] = b
    found.sort(key=lambda f: f["t_s"])
    order = np.lexsort((rec.t, mi_all))
    changes = {name: getattr(rec, name)[order]
               for name in ("t", "x", "y", "sigma", "frame", "x_px", "y_px", "quality")
               if getattr(rec, name) is not None}
    return rec.with_(marker_index=mi_all[order], **changes), found
