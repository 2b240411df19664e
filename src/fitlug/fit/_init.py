"""Initial estimates from the data itself, so no hand-tuned start is ever needed.

1. Body reference X(t): body markers' x minus their position at t = 0, averaged.
2. Geometry from the lug tracks relative to the body: the y extremes give the bottom and
   top runs (2R + 2e apart), the x extremes the arcs (D/2 + R + e from the middle);
   R alone from timing: on the straight top run markers move at the belt speed v_t,
   on the arcs they turn at v_t / R about the wheel centres.
3. Belt length P = 2D + 2 pi R, lugs on the belt N = round(P / pitch).
4. Belt coordinate u of every lug sample by projection onto the stadium; the slip s and
   each marker's sigma_0 by a 1-D search: u = sigma_0 + X(t) / (1 - s) (mod P) must hold
   for one sigma_0 per marker.
"""

from __future__ import annotations

import numpy as np

from .._errors import InputError


def body_reference(rec, body_ids, t_ref=0.0):
    """(times, X) at the body markers' unique times, and their offsets (cx, cy); X(t_ref) = 0.

    Markers may be seen over different spans (entering or leaving the view): the offsets
    are chained through overlaps, starting from the marker seen longest around t_ref.
    """
    tracks = []
    for m in body_ids:
        sel = (rec.marker_index == m) & np.isfinite(rec.x) & np.isfinite(rec.y)
        t, x, y = rec.t[sel], rec.x[sel], rec.y[sel]
        if len(t) < 2:
            raise InputError(rec.path, f"body marker {rec.markers[m]} has fewer than 2 valid samples")
        tracks.append((t, x, y))
    tu = np.unique(np.concatenate([t for t, _, _ in tracks]))
    # reference: the marker whose span is closest to t_ref, longest first
    dist = [max(t[0] - t_ref, t_ref - t[-1], 0.0) for t, _, _ in tracks]
    order = sorted(range(len(tracks)), key=lambda j: (dist[j], -len(tracks[j][0])))
    cx = np.full(len(tracks), np.nan)
    acc = np.zeros_like(tu)
    cnt = np.zeros_like(tu)
    j0 = order[0]
    t0, x0, _ = tracks[j0]
    if t0[0] <= t_ref <= t0[-1]:
        cx[j0] = float(np.interp(t_ref, t0, x0))
    else:  # no body marker seen at t_ref (lug markers enter the picture first): the
        # reference marker's motion extrapolated there, so that X(t_ref) = 0 as the model's
        # gauge has it (a constant end put X 70 mm off where the robot drives in)
        end = t0[0] if t_ref < t0[0] else t0[-1]
        cx[j0] = _line_at(t0, x0, end, t_ref, span=0.15)
    pending = order[1:]
    while True:
        acc[:] = 0
        cnt[:] = 0
        for j in range(len(tracks)):
            if np.isfinite(cx[j]):
                t, x, _ = tracks[j]
                idx = np.searchsorted(tu, t)
                acc[idx] += x - cx[j]
                cnt[idx] += 1
        if not pending:
            break
        seen = cnt > 0
        # the pending marker with the largest overlap with what is known
        best, best_n = None, -1
        for j in pending:
            n = int(np.sum(seen[np.searchsorted(tu, tracks[j][0])]))
            if n > best_n:
                best, best_n = j, n
        t, x, _ = tracks[best]
        idx = np.searchsorted(tu, t)
        X_known = np.where(seen, acc / np.maximum(cnt, 1), np.nan)
        if best_n > 0:
            cx[best] = float(np.median((x - X_known[idx])[seen[idx]]))
        else:  # no overlap at all: bridge the gap with both sides' local velocity
            k = np.flatnonzero(seen)
            cx[best] = _bridge(tu[k], X_known[k], t, x)
        pending.remove(best)
    X = acc / np.maximum(cnt, 1)
    cy = np.array([float(np.median(y)) for _, _, y in tracks])
    return tu, X, cx, cy


def X_at(t, tX, X, span: float = 0.15):
    """X at times t: interpolated inside the body reference's span, extrapolated with the
    speed at its ends outside it (lug markers seen before the first or after the last
    body marker: np.interp's constant ends put them tens of mm off while the robot moves)."""
    t = np.asarray(t, float)
    out = np.interp(t, tX, X)
    for end, side in ((tX[0], t < tX[0]), (tX[-1], t > tX[-1])):
        if not side.any() or len(tX) < 2:
            continue
        near = np.abs(tX - end) <= span
        if near.sum() < 2:
            near = np.argsort(np.abs(tX - end))[:2]
        tt, xx = tX[near], X[near]
        if np.ptp(tt) == 0:
            continue
        slope = np.polyfit(tt - end, xx, 1)[0]
        out[side] = np.interp(end, tX, X) + slope * (t[side] - end)
    return out


def _line_at(t, x, t_end, t_at, span=0.2):
    """A parabola (a line if too few samples) through the samples within `span` s of
    t_end, evaluated at t_at: the motion extrapolated into a gap."""
    sel = np.abs(t - t_end) <= span
    if sel.sum() < 3:
        sel = np.argsort(np.abs(t - t_end))[:3]
    tt, xx = t[sel], x[sel]
    if len(tt) < 2 or np.ptp(tt) == 0:
        return float(np.mean(xx))
    deg = 2 if len(tt) >= 6 and np.ptp(tt) >= 0.08 else 1
    c = np.polyfit(tt - t_end, xx, deg)
    return float(np.polyval(c, t_at - t_end))


def _bridge(tk, Xk, t, x):
    """Offset c of a track (t, x) seen while X is not known: X and x - c meet mid-gap."""
    if t[0] >= tk[-1]:
        a, b = tk[-1], t[0]
    elif t[-1] <= tk[0]:
        a, b = t[-1], tk[0]
    else:  # the track sits inside a hole of the known X: bridge from the side before
        before = tk < t[0]
        if before.sum() < 2:
            return float(x[0] - np.interp(t[0], tk, Xk))
        return _bridge(tk[before], Xk[before], t, x)
    tm = 0.5 * (a + b)
    return _line_at(t, x, t[0] if t[0] >= tk[-1] else t[-1], tm) - \
        _line_at(tk, Xk, tk[-1] if t[0] >= tk[-1] else tk[0], tm)


def _project(px, py, R, D, e):
    """Belt coordinate u of relative points (px, py) on the stadium (mm)."""
    u = np.empty_like(px)
    front = px > D / 2
    rear = px < -D / 2
    mid = ~(front | rear)
    phi_f = np.mod(np.arctan2(px[front] - D / 2, py[front] - R), 2 * np.pi)
    u[front] = 2 * D + np.pi * R + R * np.clip(phi_f, 0, np.pi)
    phi_r = np.mod(np.arctan2(-D / 2 - px[rear], R - py[rear]), 2 * np.pi)
    u[rear] = D + R * np.clip(phi_r, 0, np.pi)
    top = mid & (py > R)
    bot = mid & ~top
    u[bot] = D / 2 - px[bot]
    u[top] = D + np.pi * R + px[top] + D / 2
    return u


def _rate(t, v):
    """Finite-difference rate of consecutive samples of one track (NaN across gaps)."""
    dt = np.diff(t)
    r = np.full(len(t), np.nan)
    ok = dt > 0
    mid = np.where(ok, np.diff(v) / np.where(ok, dt, 1), np.nan)
    r[1:-1] = 0.5 * (mid[:-1] + mid[1:])
    return r


#: lug samples within this of the body reference's span (s) are where X is measured
MEASURED_MARGIN_S = 0.02


def measured_samples(rel, tX, margin: float = MEASURED_MARGIN_S) -> list:
    """Per lug marker of `rel` ((m, t, x rel, y) each), its samples where X is measured:
    within `margin` s of the body reference's span tX."""
    return [(t >= tX[0] - margin) & (t <= tX[-1] + margin) for _, t, _, _ in rel]


def lug_geometry(rec, lug_ids, tX, X):
    """Estimates R, D, e, x_off, y_off from the lug tracks (mm)."""
    rel = []
    for m in lug_ids:
        sel = (rec.marker_index == m) & np.isfinite(rec.x) & np.isfinite(rec.y)
        t = rec.t[sel]
        rel.append((m, t, rec.x[sel] - X_at(t, tX, X), rec.y[sel]))
    # the extents from the samples the body reference covers: a robot entering or leaving
    # the picture shows lug markers for a while before and after any body marker, where X
    # is only extrapolated
    inside = measured_samples(rel, tX)
    if sum(int(k.sum()) for k in inside) < 0.5 * sum(len(k) for k in inside):
        inside = [np.ones(len(k), bool) for k in inside]
    allx = np.concatenate([r[2][k] for r, k in zip(rel, inside)])
    ally = np.concatenate([r[3][k] for r, k in zip(rel, inside)])
    if len(allx) < 10:
        raise InputError(rec.path, "too few valid lug-marker samples to fit the track")
    ylo, yhi = np.percentile(ally, [0.5, 99.5])
    xlo, xhi = np.percentile(allx, [0.2, 99.8])
    rho = (yhi - ylo) / 2  # R + e
    x_off = (xlo + xhi) / 2
    half = (xhi - xlo) / 2
    D = 2 * (half - rho)
    yc = ylo + rho  # wheel centres' height
    # R from timing: arcs turn at v_t / R while the straight runs move at v_t; pair
    # samples of the same frame so that accelerations do not bias the ratio
    straight_t, straight_v, arc_t, arc_w = [], [], [], []
    for _, t, xr, y in rel:
        px, py = xr - x_off, y - yc
        vx = np.abs(_rate(t, px))
        run = (np.abs(px) < 0.4 * D) & (np.abs(py) > 0.8 * rho)
        straight_t.append(t[run])
        straight_v.append(vx[run])
        for sgn in (1, -1):
            arc = sgn * px > D / 2 + 0.2 * rho
            ang = np.unwrap(np.arctan2(sgn * (px - sgn * D / 2), py))
            w = np.abs(_rate(t, ang))
            w[~arc] = np.nan
            w[1:-1][~(arc[:-2] & arc[2:])] = np.nan
            arc_t.append(t)
            arc_w.append(w)
    R = rho
    st, sv = np.concatenate(straight_t), np.concatenate(straight_v)
    at, aw = np.concatenate(arc_t), np.concatenate(arc_w)
    ok_s, ok_a = np.isfinite(sv), np.isfinite(aw)
    st, sv, at, aw = st[ok_s], sv[ok_s], at[ok_a], aw[ok_a]
    if len(st) > 10 and len(at) > 10:
        frames, inv = np.unique(np.round(st * 1e6).astype(np.int64), return_inverse=True)
        v_frame = np.bincount(inv, sv) / np.bincount(inv)
        k = np.searchsorted(frames, np.round(at * 1e6).astype(np.int64))
        k = np.clip(k, 0, len(frames) - 1)
        same = frames[k] == np.round(at * 1e6).astype(np.int64)
        vt = v_frame[k[same]]
        w = aw[same]
        good = (vt > 0.3 * np.max(v_frame)) & (w > 0)
        if good.sum() > 10:
            R = float(np.clip(np.median(vt[good] / w[good]), 0.5 * rho, 1.2 * rho))
    e = rho - R
    return {"R": R, "D": D, "e": e, "x_off": x_off, "y_off": ylo + e}, rel


SPREAD_SAMPLES = 20_000


def slip_and_phases(rel, geom, tX, X, P, inside=None, s=None):
    """(s, sigma0 per lug marker) by a 1-D search on the belt-coordinate consistency.

    `inside`: per marker, the samples to read (where X is measured); a marker with fewer
    than 3 of them gets sigma0 NaN. `s`: a slip already read (the phases alone)."""
    us = []
    for j, (_, t, xr, y) in enumerate(rel):
        u = _project(xr - geom["x_off"], y - geom["y_off"], geom["R"], geom["D"], geom["e"])
        if inside is not None:
            t, u = t[inside[j]], u[inside[j]]
        us.append((t, u))

    # belt travel at each sample; a long recording's markers evenly thinned to SPREAD_SAMPLES
    # samples each (a start value: the circular means of 20 000 samples are as sharp, and
    # the search's ~300 slips x every sample cost 10 s at 100 000 frames)
    Xt = []
    for t, u in us:
        k = max(1, -(-len(u) // SPREAD_SAMPLES))
        Xt.append((u[::k], X_at(t[::k], tX, X)))

    def spread(s):
        """Total circular spread of the belt coordinates and each marker's mean phase, for
        every slip in the array s at once."""
        s = np.atleast_1d(np.asarray(s, float))[:, None]
        tot = np.zeros(s.shape[0])
        phases = []
        for u, xt in Xt:
            if len(u) == 0:  # a marker seen only where X is not measured
                phases.append(np.full(s.shape[0], np.nan))
                continue
            mz = np.empty(s.shape[0], complex)
            step = max(1, 2_000_000 // max(len(u), 1))  # bounded memory on long recordings
            for a in range(0, s.shape[0], step):
                sa = s[a:a + step]
                mz[a:a + step] = np.exp(2j * np.pi * (u[None, :] - xt[None, :] / (1 - sa))
                                        / P).mean(axis=1)
            tot += 1 - np.abs(mz)
            phases.append(np.angle(mz))
        return tot, phases

    if s is None:
        grid = np.linspace(-0.1, 0.5, 241)
        k = int(np.argmin(spread(grid)[0]))
        lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
        fine = np.linspace(lo, hi, 41)
        s = float(fine[int(np.argmin(spread(fine)[0]))])
    phases = [p[0] for p in spread(s)[1]]
    sigma0 = np.mod(np.array(phases) * P / (2 * np.pi), P)
    if inside is not None:
        sigma0 = np.where([len(u) >= 3 for _, u in us], sigma0, np.nan)
    return s, sigma0


def infer_n_belt(P: float, pitch: float | None, sigma0: np.ndarray) -> int:
    """Lugs on the belt: from the rig's pitch, else the smallest common marker spacing."""
    if pitch is not None:
        return max(int(round(P / pitch)), 1)
    if len(sigma0) < 2:
        return max(int(round(P / 18.0)), 1)
    d = sigma0 - sigma0[0]
    for N in range(4, 200):
        if np.all(np.abs(np.mod(d * N / P + 0.5, 1) - 0.5) < 0.08):
            return N
    return max(int(round(P / 18.0)), 1)


def _stadium_np(u, R, D, e, P):
    """(px, py) of belt coordinate u on the stadium, relative to (x_off, y_off): numpy,
    the start's forward map (the model's own is :func:`fitlug.model.stadium`)."""
    u = np.mod(u, P)
    re = R + e
    b1, b2, b3 = D, D + np.pi * R, 2.0 * D + np.pi * R
    x = np.where(u < b1, D / 2 - u,
                 np.where(u < b2, -D / 2 - re * np.sin((u - D) / R),
                          np.where(u < b3, -D / 2 + (u - b2), D / 2 + re * np.sin((u - b3) / R))))
    y = np.where(u < b1, -e,
                 np.where(u < b2, R - re * np.cos((u - D) / R),
                          np.where(u < b3, 2.0 * R + e, R + re * np.cos((u - b3) / R))))
    return x, y


#: a frame's X is followed where moving it by STANDIN_PROBE_MM raises the frame's squared
#: misfit by at least STANDIN_SHARP_MM2 (a lug on the bottom run moves s / (1 - s) as much
#: as X: two of them at s = 0.1 are followed, 0.025 mm^2, and the robot at rest with only
#: its bottom run in view is held; at s = 0.02 they are not), and kept as a stand-in where
#: its rms misfit per lug is
#: below STANDIN_MAX_MM (the start's geometry is a few mm off on the arcs: 4.5 mm rms was
#: seen on a right X; a sample off by more than 5 mm, a reflection, costs 5 mm)
STANDIN_PROBE_MM, STANDIN_SHARP_MM2, STANDIN_MAX_MM = 1.0, 0.01, 4.5


def lug_standins(rec, lug_ids, geom, P, s, sigma0, tX, X,
                 margin: float = MEASURED_MARGIN_S):
    """X(t) where no body marker is seen, from the lug markers whose phase is known.

    A robot driving into the picture shows its front arc (or leaving, its rear arc) for a
    second or more before (after) any body marker; the body reference only extrapolates
    there. With the geometry, slip and phases read where X is measured, each such frame's
    lug samples fix X: a lug at belt coordinate sigma0 + X / (1 - s) sits at
    X + x_off + stadium(.), so X moves the point along the belt and in x at once. X is
    followed frame by frame outward from the body reference's end, each frame searched
    within what the speed allows of the last (a search over all X found the mirror image of
    two arc lugs 140 mm away). Returns (t, X) of the frames whose X is sharply determined
    (see STANDIN_*), sorted."""
    R, D, e, x_off, y_off = (float(geom[k]) for k in ("R", "D", "e", "x_off", "y_off"))
    t_all, x_all, y_all, sg = [], [], [], []
    for m, s0 in zip(lug_ids, sigma0):
        if not np.isfinite(s0):
            continue
        sel = (rec.marker_index == m) & np.isfinite(rec.x) & np.isfinite(rec.y)
        t = rec.t[sel]
        out = (t < tX[0] - margin) | (t > tX[-1] + margin)
        t_all.append(t[out]), x_all.append(rec.x[sel][out]), y_all.append(rec.y[sel][out])
        sg.append(np.full(int(out.sum()), s0))
    empty = np.zeros(0), np.zeros(0)
    if not t_all or not sum(len(t) for t in t_all) or len(tX) < 2:
        return empty
    t_all, x_all, y_all, sg = (np.concatenate(a) for a in (t_all, x_all, y_all, sg))
    frames, inv = np.unique(np.round(t_all * 1e6).astype(np.int64), return_inverse=True)
    tf = frames / 1e6
    order = np.argsort(inv, kind="stable")
    bounds = np.searchsorted(inv[order], np.arange(len(tf) + 1))
    span = max(float(tX[-1] - tX[0]), 1e-6)
    rate = np.abs(np.diff(X) / np.maximum(np.diff(tX), 1e-9)) if len(tX) > 2 else np.zeros(1)
    v_max = max(float(np.percentile(rate, 99)), abs(float(X[-1] - X[0])) / span, 10.0)
    k = 1.0 / (1.0 - s)
    cap = 25.0  # mm^2: a sample 5 mm off (a reflection) costs no more than that

    def cost(f, Xc):  # frame f's summed capped squared misfit at the X values Xc
        rows = order[bounds[f]:bounds[f + 1]]
        px, py = _stadium_np(sg[rows, None] + k * Xc[None, :], R, D, e, P)
        r2 = (x_all[rows, None] - Xc[None, :] - x_off - px) ** 2 \
            + (y_all[rows, None] - y_off - py) ** 2
        return np.minimum(r2, cap).sum(axis=0), len(rows)

    t_out, X_out = [], []
    for side in (np.flatnonzero(tf < tX[0])[::-1], np.flatnonzero(tf > tX[-1])):
        if not len(side):
            continue
        t_prev = float(tX[0] if tf[side[0]] < tX[0] else tX[-1])
        X_prev = float(X_at(np.array([t_prev]), tX, X)[0])
        for f in side:
            half = 1.5 * v_max * abs(tf[f] - t_prev) + 2.0
            grid = X_prev + np.linspace(-half, half, int(np.ceil(2 * half / 0.05)) + 1)
            c, n = cost(f, grid)
            Xb = float(grid[int(np.argmin(c))])
            c0 = float(cost(f, np.array([Xb]))[0][0])
            cp = cost(f, np.array([Xb - STANDIN_PROBE_MM, Xb + STANDIN_PROBE_MM]))[0]
            if float(np.min(cp)) - c0 >= STANDIN_SHARP_MM2:  # followed; kept if it fits
                t_prev, X_prev = float(tf[f]), Xb
                if c0 / n < STANDIN_MAX_MM ** 2:
                    t_out.append(tf[f]), X_out.append(Xb)
    if not t_out:
        return empty
    t_out, X_out = np.array(t_out), np.array(X_out)
    o = np.argsort(t_out)
    return t_out[o], X_out[o]
