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
  of its samples (at frames where the body is seen) are on the loop.

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


def _tracks(rec, ids):
    valid = rec.valid
    out = {}
    for m in ids.tolist():
        sel = valid & (rec.marker_index == m)
        out[m] = (rec.t[sel], rec.x[sel], rec.y[sel])
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
    keep = [m for m in ids if m not in bad]
    t0, x0, y0 = tracks[keep[0]]
    X, Y, n = np.zeros_like(x0), np.zeros_like(y0), np.zeros_like(x0)
    for m in keep:
        t, x, y = tracks[m]
        common, i, j = np.intersect1d(t, t0, return_indices=True)
        if common.size < 2:
            continue
        ox, oy = np.median(x[i] - x0[j]), np.median(y[i] - y0[j])
        X[j] += x[i] - ox
        Y[j] += y[i] - oy
        n[j] += 1
    ok = n > 0
    return list(bad), (t0[ok], X[ok] / n[ok], Y[ok] / n[ok])


def _velocity(t, u, w):
    if t.size < 2:
        return np.full((t.size, 2), np.nan)
    return np.stack([np.gradient(u, t), np.gradient(w, t)], axis=1)


def _lug_outliers(tracks: dict, ref) -> list:
    from scipy.spatial import cKDTree

    tb, X, Y = ref
    if len(tracks) < 3 or tb.size < 2:
        return []
    frame = {}
    for m, (t, x, y) in tracks.items():
        inside = (t >= tb[0]) & (t <= tb[-1])
        t, x, y = t[inside], x[inside], y[inside]
        u, w = x - np.interp(t, tb, X), y - np.interp(t, tb, Y)
        frame[m] = (u, w, _velocity(t, u, w))
    share = {}
    for m, (u, w, vel) in frame.items():
        if u.size == 0:
            continue
        others = [n for n in frame if n != m and frame[n][0].size]
        if not others:
            return []
        pu = np.concatenate([frame[n][0] for n in others])
        pw = np.concatenate([frame[n][1] for n in others])
        pv = np.concatenate([frame[n][2] for n in others])
        dist, idx = cKDTree(np.stack([pu, pw], axis=1)).query(np.stack([u, w], axis=1))
        same_way = np.sum(vel * pv[idx], axis=1) > 0
        share[m] = float(np.mean((dist < LOOP_MM) & same_way))
    bad = [m for m, s in share.items() if s < ON_LOOP]
    return [] if len(bad) * 3 > len(tracks) else bad


def find_and_exclude(rec):
    """`rec` without the tracks that are not markers, and their list:
    [{"marker", "role", "n_samples", "t_range_s", "reason"}]."""
    body = _tracks(rec, rec.markers_of("body"))
    lug = _tracks(rec, rec.markers_of("lug"))
    if not body:
        return rec, []
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
