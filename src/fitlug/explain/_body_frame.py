"""The body's own frame, its cruise, and places along the loop in that frame, from the
markers themselves (explain._belt_clock: the belt's clock reads the lug markers there)."""

from __future__ import annotations

import numpy as np

from ._plateau import SMOOTH_S, plateau

#: the body's speed for its cruise: its mean over this time (s)
BODY_MEAN_S = 0.5
#: ... and within this share of its plateau (a body surging on its lugs swings by 5 %
#: about it; a motor's ramp leaves it within a few tenths of a second)
BODY_PLATEAU = 0.08
#: the cruise's ends: where that mean speed comes within this share of its plateau
EDGE = 0.02
#: a cruise shorter than this (s) is looked for again with the mean over twice the time
MIN_CRUISE_S = 1.0


def body_pose(prob, p, X_at):
    """Per frame with a body marker in view: (t, Tx, Ty, theta), the body's frame from its
    markers (rotation from two or more, else interpolated; translation from all)."""
    obs = prob.obs
    lay = prob.lay
    w = (np.asarray(obs["body_w"]) > 0) & np.isfinite(np.asarray(obs["body_x"]))
    if not np.any(w):
        return None
    tb = np.asarray(lay.body_t)[w]
    jb = np.asarray(lay.body_j)[w]
    bx, by = np.asarray(obs["body_x"])[w], np.asarray(obs["body_y"])[w]
    cx, cy = np.asarray(p["cx"])[jb], np.asarray(p["cy"])[jb]
    ut, inv = np.unique(tb, return_inverse=True)
    cnt = np.bincount(inv)
    X = np.asarray(X_at(ut))
    # offsets about the frame's origin (X, 0): observed minus X against the model's (cx, cy)
    ox, oy = bx - X[inv], by
    th = np.full(len(ut), np.nan)
    two = cnt >= 2
    if np.any(two):
        mx, my = (np.bincount(inv, ox) / cnt), (np.bincount(inv, oy) / cnt)
        ax, ay = np.bincount(inv, cx) / cnt, np.bincount(inv, cy) / cnt
        dox, doy = ox - mx[inv], oy - my[inv]
        dcx, dcy = cx - ax[inv], cy - ay[inv]
        s_ = np.bincount(inv, dcx * doy - dcy * dox)
        c_ = np.bincount(inv, dcx * dox + dcy * doy)
        th[two] = np.arctan2(s_, c_)[two]
    if np.all(np.isnan(th)):
        th[:] = 0.0
    else:
        ok = np.isfinite(th)
        th = np.interp(ut, ut[ok], th[ok])
    c, s = np.cos(th)[inv], np.sin(th)[inv]
    # translation: observed = T + R(theta) (cx, cy)
    tx = np.bincount(inv, bx - (c * cx - s * cy)) / cnt
    ty = np.bincount(inv, by - (s * cx + c * cy)) / cnt
    return ut, tx, ty, th


def loop_coordinate(x, y, D, R):
    """The place u along the stadium (MODEL.md §2's belt coordinate from the bottom run's
    front end) of body-frame points (x, y) relative to the bottom pitch line's middle, for
    the rear arc, the top run and the front arc (NaN on the bottom run)."""
    u = np.full(np.shape(x), np.nan)
    ra = x < -D / 2
    u[ra] = D + R * np.arctan2(-D / 2 - x[ra], R - y[ra])
    top = (x >= -D / 2) & (x <= D / 2) & (y > R)
    u[top] = D + np.pi * R + (x[top] + D / 2)
    fa = x > D / 2
    u[fa] = 2 * D + np.pi * R + R * np.arctan2(x[fa] - D / 2, y[fa] - R)
    return u


def top_run_pitch(t, i, x, u, D, R, pitch0):
    """The lug pitch as the top run shows it (mm), or None: markers seen on the top run at
    the same frame sit whole pitches apart along it (the run is straight, the belt
    unloaded there); the median of their spacing over the pitches (counted on `pitch0`)."""
    on = np.isfinite(u) & (u > D + np.pi * R + 0.2 * D) & (u < 2 * D + np.pi * R - 0.2 * D)
    k = np.flatnonzero(on)
    if len(k) < 2:
        return None
    order = np.lexsort((i[k], t[k]))
    k = k[order]
    same = np.flatnonzero((np.diff(t[k]) == 0) & (np.diff(i[k]) != 0))
    if not len(same):
        return None
    dx = np.abs(x[k[same + 1]] - x[k[same]])
    n = np.round(dx / pitch0)
    good = n >= 1
    if np.sum(good) < 8:
        return None
    return float(np.median(dx[good] / n[good]))


def body_cruise(ut, tx):
    """(t1, t2, v) of the body's cruise: where its speed (from its markers, seen at the
    frames `ut`) holds a plateau (explain._straight.plateau), its mean taken over
    BODY_MEAN_S, or over twice that where the first gives no cruise of MIN_CRUISE_S (a
    heavy body on soft lugs surges by +-10 % at about 1 Hz: half a second's mean still
    swings by more than the plateau's share; a second's cancels it)."""
    if len(ut) < 16:
        return None
    best = None
    for mean_s in (BODY_MEAN_S, 2.0 * BODY_MEAN_S):
        cr = _cruise_over(ut, tx, mean_s)
        if cr is not None and cr[1] - cr[0] >= MIN_CRUISE_S:
            return cr
        if cr is not None and (best is None or cr[1] - cr[0] > best[1] - best[0]):
            best = cr
    return best


def _cruise_over(ut, tx, mean_s):
    """body_cruise with the body's speed a mean over `mean_s`, or None."""
    tg = np.linspace(float(ut[0]), float(ut[-1]), 2000)
    # the body's mean speed over mean_s (its lug-passing ripple and most of its surge
    # averaged out), centred; within half of that of the view's ends, over what is seen
    # (a robot that drives into the picture at cruise: a mean over positions held flat
    # outside the view read its first and last 0.4 s as a ramp, and a window of 1.6 s of
    # cruise left the belt's clock 0.3 s, too short for a reading)
    h = 0.5 * mean_s
    lo, hi = np.maximum(tg - h, ut[0]), np.minimum(tg + h, ut[-1])
    v = (np.interp(hi, ut, tx) - np.interp(lo, ut, tx)) / np.maximum(hi - lo, 1e-9)
    cr = plateau(tg, v, BODY_PLATEAU, SMOOTH_S)
    if cr is None:
        return None
    t1, t2, v0 = cr
    # its ends where the mean speed is within EDGE of the plateau: a ramp's end
    run = np.flatnonzero((tg >= t1) & (tg <= t2) & (v >= (1.0 - EDGE) * v0))
    if len(run) < 2:
        return None
    # the mean over mean_s reaches a ramp a quarter of that before the speed falls by
    # EDGE (a cos ramp): the end is taken that much earlier, and the start that much
    # later (the mean reaches the plateau before the speed does: the cruise began 0.13 s
    # early on the engine's recordings, the slip read partly in the ramp's end); not at
    # the view's ends, where the cruise runs on out of the picture
    q = 0.25 * mean_s
    a = float(tg[run[0]]) + (q if tg[run[0]] > ut[0] + h else 0.0)
    b = float(tg[run[-1]]) - (q if tg[run[-1]] < ut[-1] - h else 0.0)
    return a, b, v0
