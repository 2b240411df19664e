"""Tracks that are not markers: found from their motion, kept out of the fit, listed.

A tracker also follows what is not a marker: a reflection on the ground or the body, a
speck of dust. Fitted as a marker, such a track biases everything (a 3-frame reflection
tracked as a lug moved the slip by 82 sigma; a static reflection labelled body for 1 s
gave chi^2/dof 8e5 and an explanation that did not end). The roles say what a marker
must do, so a track that does not do it is found:

- a body marker is rigid with the body: its offset from each other body marker stays
  put. A pair is not rigid when, over the frames they share, the offset moves (first to
  last) by more than RIGID_FRACTION of the body's travel there and MOVED_MIN_MM (a static
  point moves by all of it), or spreads by more than that fraction and RIGID_MM (pitching
  moves it by less). A body track not rigid with most others is kept out when the other
  body markers agree among themselves (the majority is the body), or when it is shorter
  than half the longest body track (with two body markers);
- a lug marker goes round the same closed path relative to the body as every other lug,
  in the same direction: at each sample, the nearest sample of the other lugs in the
  body frame lies within LOOP_MM, and the two move the same way there (their body-frame
  velocities less than 90 degrees apart). A lug track is kept out when fewer than half
  of its samples are on the loop; judged are the samples within the span of the body
  reference where the belt moves (at least MIN_JUDGED of them).

Nothing is judged with fewer than two body markers (for the body) or three lug markers
(for the lugs), nor more than a third of a role's markers kept out (then the recording
is odd in another way, and the fit and explanation say so). Kept-out tracks are listed
with the reason (fit.json `excluded`).
"""

from __future__ import annotations

import numpy as np

RIGID_MM = 5.0
RIGID_FRACTION = 0.3
MOVED_MIN_MM = 0.2
LOOP_MM = 4.0
ON_LOOP = 0.5
MAX_TRACKS = 500  # tracks of one role beyond which nothing is judged
PER_TRACK = 2000  # samples of a track judged at most (evenly thinned beyond)
MIN_JUDGED = 3  # samples of a lug track within the body reference's span


def _tracks(rec, ids):
    """{marker: (t, x, y) of its valid samples}, in one pass (no mask per marker); a
    track longer than PER_TRACK samples is thinned evenly to about that many."""
    sel = rec.valid & np.isin(rec.marker_index, ids)
    mi, t, x, y = rec.marker_index[sel], rec.t[sel], rec.x[sel], rec.y[sel]
    order = np.lexsort((t, mi))
    mi, t, x, y = mi[order], t[order], x[order], y[order]
    cuts = np.flatnonzero(np.diff(mi)) + 1
    out = {int(m): (np.empty(0), np.empty(0), np.empty(0)) for m in np.asarray(ids).tolist()}
    for a, b in zip(np.r_[0, cuts], np.r_[cuts, mi.size]):
        if b > a:
            step = max(1, (b - a) // PER_TRACK)  # long recordings: every step-th sample
            out[int(mi[a])] = (t[a:b:step], x[a:b:step], y[a:b:step])
    return out


def _body_outliers(tracks: dict) -> tuple[list, dict]:
    """Body markers not rigid with the others, and the body reference (t, X, Y) from the
    rest (the longest marker, the others' median offsets added)."""
    ids = sorted(tracks, key=lambda m: -tracks[m][0].size)
    rigid: dict = {}  # (m, n) -> True/False over the frames they share
    for a, m in enumerate(ids):
        t, x, y = tracks[m]
        for n in ids[a + 1:]:
            tn, xn, yn = tracks[n]
            common, i, j = np.intersect1d(t, tn, return_indices=True)
            if common.size < 2:
                continue
            ox, oy = x[i] - xn[j], y[i] - yn[j]
            moved = float(np.hypot(ox[-1] - ox[0], oy[-1] - oy[0]))
            spread = max(float(np.ptp(ox)), float(np.ptp(oy)), moved)
            # the body's travel over the shared frames, from the longer track
            tr, xr, yr = (tn, xn, yn) if tn.size >= t.size else (t, x, y)
            k = np.searchsorted(tr, common[[0, -1]])
            travel = float(np.hypot(xr[k[1]] - xr[k[0]], yr[k[1]] - yr[k[0]]))
            ok = spread <= max(RIGID_MM, RIGID_FRACTION * travel) and \
                moved <= max(MOVED_MIN_MM, RIGID_FRACTION * travel)
            rigid[(m, n)] = rigid[(n, m)] = ok
    bad = {}
    longest = tracks[ids[0]][0].size
    for m in ids:
        votes = sum(v for (a, _), v in rigid.items() if a == m)
        against = sum(not v for (a, _), v in rigid.items() if a == m)
        others_agree = any(v for (a, b), v in rigid.items() if m not in (a, b))
        if against > votes and (others_agree or tracks[m][0].size < 0.5 * longest):
            bad[m] = against
    if len(bad) * 3 > len(ids) and not (len(ids) == 2 and len(bad) == 1):
        bad = {}
    return list(bad), _reference({m: tracks[m] for m in ids if m not in bad})


def _reference(tracks: dict):
    """The body reference (t, X, Y): the longest body track, the others chained on through
    their overlaps (each shifted by its median offset), averaged where several are seen."""
    ids = sorted(tracks, key=lambda m: -tracks[m][0].size)
    t_all = np.unique(np.concatenate([tracks[m][0] for m in ids]))
    X, Y, n = np.zeros(t_all.size), np.zeros(t_all.size), np.zeros(t_all.size)
    pending = list(ids)
    while pending:
        added = False
        for m in list(pending):
            t, x, y = tracks[m]
            k = np.searchsorted(t_all, t)
            if n.any():
                have = n[k] > 0
                if have.sum() < 2:
                    continue
                ox = float(np.median(x[have] - X[k][have] / n[k][have]))
                oy = float(np.median(y[have] - Y[k][have] / n[k][have]))
            else:
                ox, oy = float(x[0]), float(y[0])
            X[k] += x - ox
            Y[k] += y - oy
            n[k] += 1
            pending.remove(m)
            added = True
        if not added:
            break
    ok = n > 0
    return t_all[ok], X[ok] / n[ok], Y[ok] / n[ok]


def _velocity(t, u, w):
    if t.size < 2:
        return np.full((t.size, 2), np.nan)
    return np.stack([np.gradient(u, t), np.gradient(w, t)], axis=1)


def _lug_outliers(tracks: dict, ref) -> list:
    from scipy.spatial import cKDTree

    tb, X, Y = ref
    if len(tracks) < 3 or tb.size < 2:
        return []
    ids, us, ws, vs, sps = [], [], [], [], []
    for m, (t, x, y) in tracks.items():
        inside = (t >= tb[0]) & (t <= tb[-1])
        t, x, y = t[inside], x[inside], y[inside]
        u, w = x - np.interp(t, tb, X), y - np.interp(t, tb, Y)
        ids.append(np.full(t.size, m))
        us.append(u)
        ws.append(w)
        vs.append(_velocity(t, u, w))
        gap = np.hypot(np.diff(u), np.diff(w))  # the sampling's spacing along the path
        sps.append(np.r_[gap[:1], gap] if gap.size else np.zeros(u.size))
    mi, u, w, vel, sp = (np.concatenate(ids), np.concatenate(us), np.concatenate(ws),
                         np.concatenate(vs), np.concatenate(sps))
    if mi.size < 10:
        return []
    speed = np.hypot(*vel.T)
    # samples where the belt is (nearly) at rest say nothing about the direction, and pile
    # up in one place: only the moving ones are judged
    moving = speed > 0.05 * np.nanpercentile(speed, 90)
    mi, pts, vel, sp = mi[moving], np.stack([u, w], axis=1)[moving], vel[moving], sp[moving]
    if mi.size < 10:
        return []
    rows = np.arange(mi.size)
    dist, idx = cKDTree(pts).query(pts, k=min(8, mi.size))
    other = mi[idx] != mi[:, None]
    first = np.argmax(other, axis=1)
    found = other[rows, first]
    nn = idx[rows, first]
    d = np.where(found, dist[rows, first], np.inf)
    for m in np.unique(mi[~found]).tolist():  # its own samples nearest: search the others
        mine = (mi == m) & ~found
        rest = mi != m
        if rest.any():
            dd, jj = cKDTree(pts[rest]).query(pts[mine])
            d[mine] = dd
            nn[mine] = np.flatnonzero(rest)[jj]
    # within LOOP_MM of the loop, widened by half the samples' spacing (thinned tracks)
    on = (d < LOOP_MM + 0.5 * np.maximum(sp, sp[nn])) & (np.sum(vel * vel[nn], axis=1) > 0)
    counts = np.bincount(mi)
    shares = np.bincount(mi, weights=on.astype(float)) / np.maximum(counts, 1)
    share = {m: float(shares[m]) for m in np.flatnonzero(counts >= MIN_JUDGED).tolist()}
    bad = [m for m, s in share.items() if s < ON_LOOP]
    return [] if len(bad) * 3 > len(tracks) else bad


def find_and_exclude(rec):
    """`rec` without the tracks that are not markers, and their list:
    [{"marker", "role", "n_samples", "t_range_s", "reason"}]."""
    if not 1 <= rec.markers_of("body").size <= MAX_TRACKS \
            or rec.markers_of("lug").size > MAX_TRACKS:
        return rec, []  # nothing to judge by, or a tracker gone wild (a new id per frame)
    body = _tracks(rec, rec.markers_of("body"))
    lug = _tracks(rec, rec.markers_of("lug"))
    bad_body, ref = _body_outliers(body)
    bad_lug = _lug_outliers(lug, ref)
    out = []
    for m in bad_body:
        out.append((m, "a body track not rigid with the other body markers: its offset "
                       "from them moves with the body's travel (a static point?)"))
    for m in bad_lug:
        out.append((m, "a lug track off the loop the other lugs go round relative to the "
                       "body, or going round it the wrong way (a reflection?)"))
    if not out:
        return rec, []
    listing = []
    for m, reason in out:
        t = body[m][0] if m in body else lug[m][0]
        listing.append({"marker": rec.markers[m], "role": rec.roles[m],
                        "n_samples": int(t.size),
                        "t_range_s": [float(t.min()), float(t.max())] if t.size else None,
                        "reason": reason})
    drop = np.array(sorted(m for m, _ in out))
    keep = ~np.isin(np.arange(rec.n_markers), drop)
    new_index = np.cumsum(keep) - 1
    rows = keep[rec.marker_index]
    changes = {name: getattr(rec, name)[rows]
               for name in ("t", "x", "y", "sigma", "frame", "x_px", "y_px", "quality")
               if getattr(rec, name) is not None}
    rec = rec.with_(markers=tuple(m for m, k in zip(rec.markers, keep) if k),
                    roles=tuple(r for r, k in zip(rec.roles, keep) if k),
                    marker_index=new_index[rec.marker_index[rows]], **changes)
    return rec, listing
