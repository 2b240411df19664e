"""The belt's own clock: its travel read off the lug markers' passages, not the model's path.

The slip at cruise is 1 - (the body's travel) / (the belt's travel relative to the body)
over the same time (explain._straight, the engine's own definition). Where the model does
not describe the path (a chain of links wrapping its wheels as a polygon, lug tips that hold
on the ground and spring back, a body surging on its lugs: MODEL.md §2 "Real tracks"), the
belt's travel can still be read exactly, because a track carries its lugs on a pitch grid:

- two markers k lugs apart pass the same point of the body's frame when the belt has
  travelled exactly k p, and one marker passes it again after exactly one belt length
  P = N p (N the lugs on the belt, p the rig's lug pitch);
- nothing about the path's shape is needed (the point is the same point), and the chordal
  ripple of a chain cancels (its configuration repeats every pitch);
- the body's pitch is taken out: the lug markers are carried into the body's frame, its
  position and angle from the body markers (two or more in view) at every frame.

Only the part of the path where a lug is free is used: from late on the rear arc (LO of its
half-turn, after the lug's shear has sprung back) over the top run to the front arc's upper
quarter (before a lug reaches for the ground). Passages of each level of that part (LEVEL_MM
apart) by consecutive markers give rows psi(t_b) - psi(t_a) = k p + n P: first those less
than half a belt length apart (whole pitches counted on the base fit's belt travel), then
those a belt length apart (the marked lugs went round), whose count of pitches N comes from
the first rows' belt speed as a ratio to the body's, carried across the gap by the body's
own travel, and must agree between rows. psi(t) = kappa X(t) + a cubic spline (KNOT_S) is
fitted to the rows by least squares: the body's travel (seen throughout) carries the speed
profile's shape where no lug is seen free (the marked lugs all on the ground), the spline
what differs, with a prior on its acceleration (ACC_PRIOR, the body's surge) that only
matters there.

The window is the body's cruise (explain._body_frame: its speed over BODY_MEAN_S within
BODY_PLATEAU of a plateau, its ends within EDGE of it), from one contact time D / v after the
ramp (the lugs that landed during the ramp have lifted off: the brush has settled) to its
end, each end moved inward to the nearest passage (where the cruise ends in a gap of the
passages, the marked lugs on the ground or hidden, the last passage before the gap; at
least MIN_WINDOW_S remain): psi is read where passages pin it, never from the spline's
prior across a gap, and the window never reaches into a ramp. The belt's speed is read
over that window, the body's over the settled cruise, a contact time after the ramp to
its end, even where the window had to start earlier (the belt is driven: its speed
changes over a cruise half as much as the body's, which carries the slip's changes), and
the slip is 1 - v_body / v_belt. The body's speed over its cruise is the slope of its
travel's least-squares line there, not the travel between the cruise's ends: a body
surging on its lugs is anywhere in its swing at either end, and a difference takes that
swing whole (one engine run started abruptly, its body surging by 3.7 mm peak to peak:
a tracker's view put the cruise's start 0.22 s earlier than the clean view, the travel
between the ends moved by 1.4 %, and the slip read 0.017 +- 0.006 for the engine's
0.038; the line's slope moved by 0.02 %, and the slip reads 0.023 +- 0.010, its error
mostly the belt's unseen change: the body's speed between the window's ends, as the
belt's is read, stands 1.6 % above its cruise's line). Where the window is not the
cruise (four marked lugs on consecutive links visit the clean part once a turn: a window
of about half a 2-s cruise), the belt's speed over the cruise is taken to differ from the window's by
BELT_FOLLOWS of the body's difference between them, +- as much: a belt driven by its
wheel's friction runs faster where the body does (a light robot on the engine: the belt
0.6 % faster outside the window, the body 1 %; read at the window's speed alone its slip
was 0.0070 for 0.0098, 3 of its errors). Its error holds the spline's (the passages'
scatter and, where no passage lies inside the window, the prior), the body's noise, the
belt speed's trend carried from the window to the cruise, that change of the belt's
speed, and the surge: the 'slip displacement' X - (1 - s) psi wanders about its line
while the body surges on its lugs, so a slip over one window differs from another's by
about sqrt(2) times that scatter over the belt's travel; where the window holds
MIN_BATCHES contact times or more, at least the scatter of the slip over each contact time
over the root of their number, times Student's t (batch means): a surge at about 1 Hz
swings the slip over a window of one or two of its periods by more than the scatter about
that window's own line shows (the engine at 400 mm/s, its slip 0.023-0.058 from one
contact period to the next: 0.0367 +- 0.0011 over 1.56-3.16 s, where its own whole
periods before the cruise's end read 0.0416; with batch means +- 0.0043); and at least
sqrt(2) times the body's own travel's scatter about its line over its cruise, over that
travel: between the visits psi = kappa X + spline follows X, so the scatter at the
passages shows little of a surge slower than the visits (the engine at 300 mm/s under
15 kg, seen for two contact times: 0.24 mm at the passages, 0.73 mm of the body, which
surges by +-1.2 mm at 1.7 Hz; 0.048 +- 0.0013 for the engine's 0.0433, +- 0.0038 with it;
measured on the engine's recordings: docs/engine.md). Where it gives no reading, it says why
(`why`), in words a user can act on.

Longer than 400 lines because the reading, its window, its error budget and the reasons it
gives none are one computation over the same passages and their dozen shared locals.
"""

from __future__ import annotations

import numpy as np

from ._body_frame import body_cruise, body_pose, loop_coordinate, top_run_pitch
from ._scatter import about_line, batch_mean_std, line_slope

#: level spacing along the clean part of the path, mm
LEVEL_MM = 1.0
#: the clean part: from LO of the rear arc's half-turn to HI of the front arc's
LO, HI = 0.8, 0.5
#: knot spacing of psi(t), s
KNOT_S = 0.1
#: prior on the belt's acceleration, mm/s^2 (a ramp of 150 mm/s in 1 s peaks at ~240)
ACC_PRIOR = 100.0
#: a pair of passages is dropped when its row misses by more than this many robust sigmas
CLIP = 5.0
#: markers whose fitted places on the belt sit further than this share of a pitch from
#: the pitch grid are not paired with others (only with themselves, a belt length later)
GRID_TOL = 0.25
#: the slip displacement X - (1 - s) psi may wander about its line by this share of a
#: pitch at most (a belt length miscounted across a gap steps it by a pitch; where the
#: line takes a step up, the top run's reading catches it: explain._straight.choose) ...
WANDER_MAX = 0.125
#: ... and this many times the body's own scatter about its line (its surge: 2.5 mm, 20 kg)
STEP_OVER_SURGE = 1.5
#: the least window (s) where the cruise's end falls in a gap of the passages
MIN_WINDOW_S = 0.5
#: relative error of a lug pitch read off the top run (used only where the rig gives none)
TOP_PITCH_REL = 0.002
#: the belt's speed over the part of the cruise where no passage is seen changes by this
#: share of the body's change there, +- as much (0 to 1 at one sigma): a belt driven by
#: its wheel's friction runs faster where the body does (the engine's chain: 0.5-0.65 of
#: the body's change between a clock's window and the rest of its cruise); a belt on a
#: sprocket would not change at all
BELT_FOLLOWS = 0.5
#: the surge's slow part from each contact time's slip (batch means, Student's t) where the
#: window holds this many (two: half their difference); n where it holds n - BATCH_SHORT
MIN_BATCHES = 3
BATCH_SHORT = 0.25


def _passages(t, i, u, lo, hi, levels):
    """(level index, time, marker) of every crossing of `levels` by each marker's visits to
    [lo, hi] (u increasing along a visit; a visit's non-increasing steps split it)."""
    out = []
    for m in np.unique(i):
        k = np.flatnonzero((i == m) & np.isfinite(u) & (u >= lo) & (u <= hi))
        if len(k) < 4:
            continue
        k = k[np.argsort(t[k], kind="stable")]
        cut = np.flatnonzero((np.diff(u[k]) <= 0) | (np.diff(t[k]) > 0.1)) + 1
        for seg in np.split(k, cut):
            if len(seg) < 4:
                continue
            us, ts = u[seg], t[seg]
            inr = np.flatnonzero((levels > us[0]) & (levels < us[-1]))
            if len(inr):
                out.append(np.c_[inr, np.interp(levels[inr], us, ts), np.full(len(inr), m)])
    return np.concatenate(out) if out else np.zeros((0, 3))


def _travel(rows, dpsi, spans, ut, tx, cruise):
    """The belt's travel over each (t_a, t_b) of `spans`, enough to count whole pitches over
    a belt length: the speed the short rows measure (whole pitches over their times) as a
    ratio to the body's (0.1 s bins, medians), that ratio linear across a gap and the
    body's own travel (seen throughout) carrying the speed profile there."""
    tm = 0.5 * (rows[:, 0] + rows[:, 1])
    dxb = np.interp(rows[:, 1], ut, tx) - np.interp(rows[:, 0], ut, tx)
    # the ratio from the cruise only: in a ramp the slip follows the acceleration
    ok = (dxb > 0) & (rows[:, 0] >= cruise[0]) & (rows[:, 1] <= cruise[1])
    if np.sum(ok) < 4:
        ok = dxb > 0
    ratio = dpsi[ok] / dxb[ok]
    tm = tm[ok]
    b = np.floor(tm / 0.1).astype(int)
    ub = np.unique(b)
    tb = np.array([np.median(tm[b == k]) for k in ub])
    rb = np.array([np.median(ratio[b == k]) for k in ub])
    grid = np.linspace(float(np.min(spans)), float(np.max(spans)), 4000)
    xg = np.interp(grid, ut, tx)
    rg = np.interp(0.5 * (grid[1:] + grid[:-1]), tb, rb)
    cum = np.r_[0.0, np.cumsum(rg * np.diff(xg))]
    return np.interp(spans[:, 1], grid, cum) - np.interp(spans[:, 0], grid, cum)


def _solve(A, target, use, prior, anchor):
    """Least squares of psi's coefficients on the rows `use` (robustly clipped) and the
    `prior` rows (scaled, zero targets); (coef, rows kept, their robust scatter, design)
    or None."""
    keep = use.copy()
    sig_c = 0.05
    for _ in range(4):
        if np.sum(keep) < 8:
            return None
        W = np.r_[A[keep] / sig_c, prior, anchor]
        Y = np.r_[target[keep] / sig_c, np.zeros(len(prior)), [0.0]]
        coef, *_ = np.linalg.lstsq(W, Y, rcond=None)
        r = A @ coef - target
        mad = 1.4826 * float(np.median(np.abs(r[keep] - np.median(r[keep]))))
        sig_c = max(mad, 1e-3)
        new = use & (np.abs(r) < CLIP * sig_c)
        if np.array_equal(new, keep):
            break
        keep = new
    W = np.r_[A[keep] / sig_c, prior, anchor]
    return coef, keep, sig_c, W


def _end(et, t, inward):
    """A window's end near `t` where psi is read at a passage (`et`, sorted): the nearest
    passage inside the window (`inward` +1: after t, -1: before), else t itself. Never one
    outside (an end 0.27 s into the ramp down read the engine's heavy20 3.3 of its errors
    low), never psi from the spline inside a gap of the passages (held there by its prior:
    a top run hidden for the cruise's last 0.8 s read the belt 4 % fast, 2.3 errors)."""
    d = (et - t) * inward
    inside = d[d >= 0]
    return float(t + inward * inside.min()) if len(inside) else float(t)


def _unseen(t1, t2, ta, tb, v_cruise, v_window):
    """(share, change): the share of the body's cruise [t1, t2] outside the belt's window
    [ta, tb] and the body's mean speed over the cruise relative to its speed over the
    window (0, 0 where the window covers the cruise)."""
    outside = (t2 - t1) - max(0.0, min(t2, tb) - max(t1, ta))
    if outside <= 1e-6 * (t2 - t1) or v_window <= 0:
        return 0.0, 0.0
    return float(outside / (t2 - t1)), float((v_cruise - v_window) / v_window)


#: why no reading (`why` of :func:`belt_clock_slip`)
FEW_PASSAGES = ("the marked lugs pass the belt's free part (the rear wheel's upper arc, the "
                "top run) fewer than 8 times")
FEW_PAIRS = ("the marked lugs' passages of the belt's free part give fewer than 8 pairs (two "
             "passages of the same place)")
UNFIXED = "the passages do not fix the belt's travel"
UNCOUNTED = ("the passages do not count the belt's travel in whole lug pitches (the base "
             "model's belt is too far from the markers')")
MISCOUNTED = "the passages step by a pitch where the body does not surge (belt lengths miscounted)"


def _no(why: list | None, reason: str) -> None:
    """None, with `reason` appended to `why` (when a list is given)."""
    if why is not None:
        why.append(reason)
    return None


def _spans(t, gap: float = 0.25) -> str:
    """'2.0-2.5 and 4.8-5.2': the spans of times `t` (s) split where they leave a gap."""
    t = np.unique(np.asarray(t, float))
    parts = np.split(t, np.flatnonzero(np.diff(t) > gap) + 1)
    out = [f"{a[0]:.1f}-{a[-1]:.1f}" for a in parts if len(a)]
    return out[0] if len(out) == 1 else ", ".join(out[:-1]) + " and " + out[-1]


def belt_clock_slip(res, p: dict, nodes, why: list | None = None) -> dict | None:
    """The slip over the cruise from the belt's clock (module docstring).

    `res`: a least-squares fit (its geometry to place the levels, the markers' places on
    the belt and its belt travel to count whole pitches); `p` its parameters as JAX
    arrays and `nodes` their integration (model._model.integrate), which the caller has
    already (the body markers' frame is fitted about the model's X(t)). None where the
    recording does not allow the reading: no body in view, no cruise, fewer than eight
    passage pairs, or less than half the cruise between the first and last passages (a
    list `why` gets the reason, in words a user can act on). Else
    a dict: slip, std, v_body_mm_s, v_belt_mm_s (and stds) over window_s, visits (lug
    markers that passed), passages, pairs (rows kept), pair_rms_mm (their scatter),
    surge_wander_mm (at the passages), surge_body_mm (the body's), error_terms (std's
    parts; surge_from: which surge term is the largest), window_shift (the
    slip's error for the body's speed taken over cruise_s, the belt's over window_s),
    lugs_on_belt (N as the passages one belt length apart count it, or None), pitch_mm
    (the rig's, else the top run's), pitch_top_run_mm (the spacing of markers seen on the
    top run together, or None), R_mm, method 'belt clock'."""
    from ..model._host import kinematics_host
    from ..model._model import ctx_of
    from .families._base import bspline

    prob = res.problem
    lay = prob.lay
    ctx = ctx_of(p, lay)
    D, R = float(ctx.D), float(ctx.R)
    pitch = float(prob.rig.lug_pitch_mm or float(ctx.P) / int(lay.n_belt))
    pose = body_pose(prob, p, lambda t: kinematics_host(p, lay, t, nodes)["X"])
    if pose is None:
        return _no(why, "no body marker is in view")
    ut, tx, ty, th = pose
    cr = body_cruise(ut, tx)
    if cr is None:
        return _no(why, "the body holds no steady speed (no cruise)")
    t1, t2, v_body0 = cr
    settle_s = D / max(v_body0, 1e-9)
    obs = prob.obs
    tl, li = np.asarray(lay.lug_t), np.asarray(lay.lug_i)
    ok = (np.asarray(obs["lug_w"]) > 0) & np.isfinite(np.asarray(obs["lug_x"]))
    f = np.searchsorted(ut, tl)
    f = np.clip(f, 0, len(ut) - 1)
    fl = np.clip(f - 1, 0, len(ut) - 1)
    f = np.where(np.abs(ut[fl] - tl) < np.abs(ut[f] - tl), fl, f)
    dt_frame = float(np.median(np.diff(ut))) if len(ut) > 1 else 1.0
    ok &= np.abs(ut[f] - tl) < 0.5 * dt_frame
    if np.sum(ok) < 8:
        return _no(why, "fewer than 8 lug-marker samples fall where the body is seen")
    dx = np.asarray(obs["lug_x"]) - tx[f]
    dy = np.asarray(obs["lug_y"]) - ty[f]
    c, s = np.cos(th[f]), np.sin(th[f])
    bxl, byl = c * dx + s * dy, -s * dx + c * dy
    x = bxl - float(p["x_off"])
    y = byl - float(p["y_off"])
    u = np.where(ok, loop_coordinate(x, y, D, R), np.nan)
    # the rig's lug pitch sets the clock's scale; without one, the top run's own spacing
    seen_pitch = top_run_pitch(tl, li, x, u, D, R, pitch)
    pitch_rel = 0.0
    if prob.rig.lug_pitch_mm is None and seen_pitch is not None:
        # the top run's links are not quite in line (a chain's polygon rides on it): its
        # spacing read 0.16 % short on the engine's chain, exact on a belt
        pitch, pitch_rel = seen_pitch, TOP_PITCH_REL
    lo, hi = D + LO * np.pi * R, 2 * D + np.pi * R + HI * np.pi * R
    levels = np.arange(lo + 0.5 * LEVEL_MM, hi, LEVEL_MM)
    ev = _passages(tl, li, u, lo, hi, levels)
    if len(ev) < 8:
        return _no(why, FEW_PASSAGES)
    # the markers' places on the belt (base fit) on the pitch grid
    sig = np.asarray(p["sigma0"], float)
    ph = np.angle(np.mean(np.exp(2j * np.pi * sig / pitch))) / (2 * np.pi)
    k_of = np.round(sig / pitch - ph)
    on_grid = np.abs(sig / pitch - ph - k_of) < GRID_TOL
    rows = []
    for lev in np.unique(ev[:, 0]):
        e = ev[ev[:, 0] == lev]
        e = e[np.argsort(e[:, 1], kind="stable")]
        rows += [(a[1], b[1], a[2], b[2]) for a, b in zip(e[:-1], e[1:])]
    if len(rows) < 8:
        return _no(why, FEW_PAIRS)
    rows = np.array(rows)
    ia, ib = rows[:, 2].astype(int), rows[:, 3].astype(int)
    psi_m = kinematics_host(p, lay, rows[:, :2].ravel(), nodes)["psi"].reshape(-1, 2)
    dmod = np.diff(psi_m, axis=1)[:, 0]
    # psi(t) on a cubic spline; rows in the passages' units, the acceleration prior
    T0, T1 = float(ev[:, 1].min()) - 1e-3, float(ev[:, 1].max()) + 1e-3
    n_int = max(4, int(np.ceil((T1 - T0) / KNOT_S)))
    hk = (T1 - T0) / n_int

    def basis(tt):
        # psi = kappa X(t) + a spline: the body's travel (seen throughout), scaled, carries
        # the speed profile's shape across a gap, the spline the slip's changes
        tt = np.asarray(tt, float)
        pm = np.interp(tt, ut, tx)
        return np.c_[pm, bspline(tt, T0, T1, n_int)]

    A = basis(rows[:, 1]) - basis(rows[:, 0])
    nb = A.shape[1] - 1
    D2 = np.c_[np.zeros(nb - 2), np.diff(np.eye(nb), 2, axis=0) / hk ** 2]
    # first the passages less than half a belt length apart (whole pitches, counted on
    # the base fit's travel), then those a belt length apart, counted on that spline
    short = (np.abs(dmod) < 0.5 * float(ctx.P)) & (ia != ib)
    target = np.round(dmod / pitch) * pitch
    anchor = np.r_[0.0, bspline([T0], T0, T1, n_int)[0]][None, :]
    fitted = _solve(A, target, short, D2 / ACC_PRIOR, anchor)
    if fitted is None:
        return _no(why, UNFIXED)
    coef, keep, sig_c, W = fitted
    long_ = ~short
    n_belt = None
    if np.any(long_):
        est = _travel(rows[short & keep], target[short & keep], rows[long_, :2], ut, tx,
                      (t1, t2))
        same = ia[long_] == ib[long_]
        grid = same | (on_grid[ia[long_]] & on_grid[ib[long_]])
        kdiff = np.where(same, 0, k_of[ia[long_]] - k_of[ib[long_]])
        # one belt length apart at most here: the lugs on the belt, counted by each row
        one = grid & (est < 1.5 * float(ctx.P))
        if np.any(one):
            n_row = np.round(est[one] / pitch - kdiff[one]).astype(int)
            n_row = n_row[n_row > 0]
            if len(n_row):
                cnt = np.bincount(n_row)
                if cnt.max() >= 0.7 * len(n_row):
                    n_belt = int(np.argmax(cnt))
        if n_belt:
            tl_ = np.round(est / pitch)
            okl = grid & (np.mod(tl_ - kdiff, n_belt) == 0)
            target[long_] = tl_ * pitch
            use = short.copy()
            use[np.flatnonzero(long_)[okl]] = True
            fitted = _solve(A, target, use, D2 / ACC_PRIOR, anchor)
            if fitted is None:
                return _no(why, UNFIXED)
            coef, keep, sig_c, W = fitted
    cov = np.linalg.pinv(W.T @ W)
    et = np.unique(np.r_[rows[keep, 0], rows[keep, 1]])
    # the brush settles one contact time after the speed does (its lugs landed before);
    # where the settled cruise leaves no window (its passages fall in a gap: a heavy body
    # on soft lugs, the marked lugs on the ground for the cruise's last 0.9 s), the belt's
    # window is read from the cruise's start, but the body's speed (seen over all of its
    # cruise) still over the settled part: a 15 mm wheel's chain swings to 136 mm/s after
    # the ramp and settles at 143.5; with the body over the whole cruise the slip read
    # 0.040 for the engine's settled 0.022
    starts = [t1 + settle_s, t1] if t2 - (t1 + settle_s) >= 0.5 * (t2 - t1) else [t1]
    c1 = starts[0]  # the body's cruise, from its settled start
    for start in starts:
        ta, tb = _end(et, start, +1), _end(et, t2, -1)
        # a cruise that begins or ends while every marked lug is on the ground (six marked
        # of 26, a 1.1-s gap) is read from the first or to the last passage: the spline
        # holds psi only between them
        ta = float(et[0]) if ta < T0 else ta
        tb = float(et[-1]) if tb > T1 else tb
        if T0 <= ta < tb <= T1 and tb - ta >= min(0.5 * (t2 - start), MIN_WINDOW_S):
            break
    else:
        return _no(why, f"the marked lugs pass the belt's free part only at {_spans(et)} s, "
                        f"too little of the body's cruise ({t1:.1f}-{t2:.1f} s) to read")
    tm = 0.5 * (ta + tb)
    B3 = basis([ta, tm, tb])  # the window's ends and its middle (the trend, below)
    pa, pm, pb = B3 @ coef
    dpsi = float(pb - pa)
    g = B3[2] - B3[0]
    var_psi = float(g @ cov @ g)
    Xa, Xb = (float(np.interp(tq, ut, tx)) for tq in (ta, tb))
    dX = Xb - Xa
    if not (dpsi > 0 and np.isfinite(dpsi)):
        return _no(why, UNCOUNTED)
    s_window = 1.0 - dX / dpsi  # the slip over the window itself (the surge's line)
    # body noise at the ends: the frame's translation from its markers
    sb = float(prob.noise.get("body", 0.005)) if isinstance(prob.noise, dict) else 0.005
    var_X = 2.0 * sb ** 2
    te = et[(et >= ta) & (et <= tb)]
    wander = 0.0  # the slip displacement's scatter about its line at the passages
    if len(te) >= 8:
        wander = about_line(te, np.interp(te, ut, tx) - (1.0 - s_window) * (basis(te) @ coef),
                            ta, tb)
    surge_body = about_line(ut, tx, c1, t2)  # the body's own (module docstring)
    if wander > WANDER_MAX * pitch and wander > STEP_OVER_SURGE * surge_body:
        return _no(why, MISCOUNTED)  # it steps, and the body does not surge so
    # the surge's slow part: the slip of each contact time of the window (batch means)
    batch, n_bat = 0.0, int((tb - ta) / settle_s + BATCH_SHORT)
    if n_bat >= 2:
        edges = np.linspace(ta, tb, n_bat + 1)
        s_bat = 1.0 - np.diff(np.interp(edges, ut, tx)) / np.diff(basis(edges) @ coef)
        # two: half their difference (without t: 6.5 times; the body's surge beside it)
        batch = batch_mean_std(s_bat) if n_bat >= MIN_BATCHES else \
            float(abs(s_bat[1] - s_bat[0]) / 2.0)
    # the belt is driven (its speed changes half as much as the body's over a cruise) and
    # the body carries the slip's changes (a brush settling over its first contact
    # periods), so the body's speed over the cruise against the belt's over the window.
    # Its error (window_shift): the belt's speed carried from the window's middle to the
    # cruise's at the trend between the window's halves
    dt = tb - ta
    X1, X2 = float(np.interp(c1, ut, tx)), float(np.interp(t2, ut, tx))
    # the body's speed: the slope of its travel's line over the settled cruise (its ends'
    # swings enter a difference whole: module docstring); over the window as the belt's
    # is read there, between its ends
    v_body = line_slope(ut, tx, c1, t2)
    v_body = (X2 - X1) / (t2 - c1) if v_body is None else v_body  # < 8 frames of cruise
    v_body_window = dX / dt
    trend = ((pb - pm) - (pm - pa)) / (0.5 * dt) ** 2  # mm/s^2
    drift = abs(trend * (0.5 * (c1 + t2) - tm))  # mm/s
    shift = v_body * dt / dpsi * drift / (dpsi / dt)
    # where no passage is seen (the cruise outside the window) the belt's speed is taken
    # to change by BELT_FOLLOWS of the body's change there, +- as much (module docstring)
    unseen, body_rel = _unseen(c1, t2, ta, tb, v_body, v_body_window)
    follow = 1.0 + BELT_FOLLOWS * body_rel
    slip = 1.0 - v_body * dt / (dpsi * follow)
    follow_err = (1.0 - slip) * BELT_FOLLOWS * abs(body_rel)
    # the surge: the largest of the passages' scatter over the window's travel (not the
    # cruise's: docs/engine.md, session 31), the batch means and the body's own (docstring)
    surges = {"passages": np.sqrt(2.0) * wander / dpsi, "contact times": batch,
              "body": np.sqrt(2.0) * surge_body / (X2 - X1)}
    surge_of = max(surges, key=surges.get)
    terms = {"passages": np.sqrt(var_psi) * v_body * dt / dpsi ** 2,
             "body noise": np.sqrt(var_X) / dpsi, "surge": surges[surge_of],
             "pitch": (1.0 - slip) * pitch_rel, "trend": shift, "unseen belt": follow_err}
    std = float(np.sqrt(sum(v ** 2 for v in terms.values())))
    return {"slip": float(slip), "std": std, "v_body_mm_s": v_body,
            "v_body_std": float(np.sqrt(var_X) / (t2 - c1)), "v_belt_mm_s": dpsi / dt * follow,
            "v_belt_window_mm_s": dpsi / dt, "v_body_window_mm_s": float(v_body_window),
            "unseen_share": float(unseen), "belt_follows": BELT_FOLLOWS,
            "belt_follows_err": float(follow_err),
            "v_belt_std": float(np.sqrt(var_psi) / dt), "window_s": [ta, tb],
            "visits": int(len(np.unique(ev[:, 2]))), "passages": int(len(ev)),
            "pairs": int(np.sum(keep)),
            "pair_rms_mm": sig_c, "surge_wander_mm": wander, "surge_body_mm": surge_body,
            "window_shift": float(shift),
            "batches": n_bat, "batch_std": batch, "surge_from": surge_of,
            "error_terms": {k: float(v) for k, v in terms.items()},
            "cruise_s": [c1, t2],
            "margin_mm": 0.0, "pitch_mm": pitch, "pitch_top_run_mm": seen_pitch, "R_mm": R,
            "method": "belt clock",
            "lugs_on_belt": n_belt}
