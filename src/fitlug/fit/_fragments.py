"""Tracker fragments of one marker, recognised from the data and fitted as one marker.

A tracker that loses a marker for a while (it left the picture, something hid it) often
re-acquires it under a new id. The names say nothing (no pattern is assumed); the
physics does:

- a lug marker rides the belt at a fixed belt coordinate sigma_0: two fragments of one
  marker have the same sigma_0 modulo the belt length P. Fragments whose sigma_0 differ by
  a whole number of lug pitches are markers on *other* lugs and stay separate;
- a body marker sits at a fixed offset (c_x, c_y) from the body reference: two fragments
  of one marker have the same offsets.

Fragments are joined only when their time spans do not overlap (two ids seen in one frame
are two markers). Joining is greedy in time order: each fragment goes to the earlier
group it matches best (smallest offset distance), else starts its own group.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Group:
    """Fragments (marker indices into the recording) fitted as one marker."""

    members: list
    spans: list  # (t_first, t_last) of each member's valid samples

    def overlaps(self, span) -> bool:
        return any(not (span[1] < a or span[0] > b) for a, b in self.spans)


def spans_of(rec, ids) -> list:
    """(first, last) time of each marker's valid samples."""
    valid = np.isfinite(rec.x) & np.isfinite(rec.y)
    out = []
    for m in ids:
        t = rec.t[(rec.marker_index == m) & valid]
        out.append((float(t.min()), float(t.max())) if len(t) else (np.inf, -np.inf))
    return out


def group(ids, spans, dist, tol: float) -> list[Group]:
    """Greedy grouping in time order: join a fragment to the earlier group at distance < tol.

    dist(i, j): distance between fragments i and j (positions in `ids`).
    """
    order = sorted(range(len(ids)), key=lambda k: spans[k][0])
    groups: list[Group] = []
    pos: list[list] = []  # positions (into ids) of each group's members
    for k in order:
        best, best_d = None, tol
        for g, members in zip(groups, pos):
            if g.overlaps(spans[k]):
                continue
            d = max(dist(k, j) for j in members)
            if d < best_d:
                best, best_d = g, d
        if best is None:
            groups.append(Group(members=[ids[k]], spans=[spans[k]]))
            pos.append([k])
        else:
            i = groups.index(best)
            best.members.append(ids[k])
            best.spans.append(spans[k])
            pos[i].append(k)
    return groups


def lug_groups(ids, spans, sigma0, P: float, pitch: float) -> list[Group]:
    """Lug fragments whose belt coordinates agree modulo P (within 0.3 pitch); a NaN
    sigma0 (a fragment seen only where X is not measured) joins nothing."""
    s = np.asarray(sigma0, float)

    def dist(i, j):
        d = np.mod(s[i] - s[j] + P / 2, P) - P / 2
        return abs(float(d)) if np.isfinite(d) else np.inf

    return group(list(ids), spans, dist, 0.3 * pitch)


def body_groups(ids, spans, cx, cy, tol_mm: float = 3.0) -> list[Group]:
    """Body fragments with the same offsets (c_x, c_y) to within tol_mm."""
    cx, cy = np.asarray(cx, float), np.asarray(cy, float)

    def dist(i, j):
        return float(np.hypot(cx[i] - cx[j], cy[i] - cy[j]))

    return group(list(ids), spans, dist, tol_mm)


def apply_groups(rec, groups: list[Group]):
    """The recording with each group's fragments under its first member's id.

    Returns (recording, joined): joined = [{"marker", "ids", "reason"}] for groups of
    two or more fragments (reason filled by the caller). Markers not in any group keep
    their own id. Samples are sorted by (marker, t) as read_trajectories leaves them.
    """
    target = np.arange(rec.n_markers)
    joined = []
    for g in groups:
        if len(g.members) < 2:
            continue
        order = np.argsort([a for a, _ in g.spans])
        mem = [g.members[k] for k in order]
        for m in mem[1:]:
            target[m] = mem[0]
        joined.append({"marker": rec.markers[mem[0]], "ids": [rec.markers[m] for m in mem]})
    if not joined:
        return rec, []
    keep = np.flatnonzero(target == np.arange(rec.n_markers))
    new_index = np.full(rec.n_markers, -1)
    new_index[keep] = np.arange(len(keep))
    mi = new_index[target[rec.marker_index]]
    order = np.lexsort((rec.t, mi))
    changes = {"markers": tuple(rec.markers[m] for m in keep),
               "roles": tuple(rec.roles[m] for m in keep),
               "marker_index": mi[order].astype(np.int64)}
    for name in ("t", "x", "y", "sigma", "frame", "x_px", "y_px", "quality"):
        v = getattr(rec, name)
        if v is not None:
            changes[name] = np.asarray(v)[order]
    return rec.with_(**changes), joined


def coverage(rec, joined: list) -> list[dict]:
    """fit.json's `markers`: one entry per (joined) marker with its coverage."""
    valid = np.isfinite(rec.x) & np.isfinite(rec.y)
    n_frames = max(len(np.unique(rec.t[valid])), 1)
    ids_of = {j["marker"]: list(j["ids"]) for j in joined}
    out = []
    for m, (name, role) in enumerate(zip(rec.markers, rec.roles)):
        sel = (rec.marker_index == m) & valid
        t = rec.t[sel]
        n = int(len(np.unique(t)))
        out.append({"id": name, "role": role, "ids": ids_of.get(name, [name]),
                    "n_samples": n, "coverage": n / n_frames,
                    "t_range_s": [float(t.min()), float(t.max())] if n else None})
    return out
