"""Where the speed profile's knots go, and why.

X(t) must follow any smooth motor profile (rest, accelerate, cruise, decelerate, rest)
to micrometres, yet must not absorb speed content at the wheel-revolution frequency
v_t/(2 pi R) or the lug-passing frequency v_t/p, which the catalog explains as
wheel_runout and lug_ripple. A uniform cubic spline cannot do both: following a 1.5 s
cosine ramp to < 1 um needs knots ~0.1 s apart, while a spacing below ~1 wheel period
absorbs most of a runout (benchmarks/bench_knots.py measures both).

So the knots are adaptive, tied to those frequencies:
- where the body's acceleration is (nearly) constant — rest and cruise — knots sit one
  wheel period apart (clipped to [0.4, 2] s): a cubic B-spline's response has its first
  null at that frequency, so runout and ripple stay in the residuals;
- where the acceleration changes (ramps and their ends, where a smooth profile's jerk
  typically jumps), knots sit 0.45 lug periods apart, clipped to [0.035, 0.07] s: an
  independent smoothstep-ramp recording needs <= 0.07 s to fit at chi2/dof = 1 (0.1 s
  left 1-2 % excess). Belt-locked ripple can hide inside these short windows, but not
  in the cruise, which is where the explanation stage looks for it.
The ramps are found from the body markers' smoothed acceleration.
"""

from __future__ import annotations

import numpy as np


def _smooth_derivs(t: np.ndarray, X: np.ndarray, window_s: float):
    """Local quadratic fits: (v, a) at each t from X within +-window_s/2."""
    v = np.empty_like(X)
    a = np.empty_like(X)
    half = window_s / 2
    lo = np.searchsorted(t, t - half)
    hi = np.searchsorted(t, t + half, side="right")
    for k in range(len(t)):
        sl = slice(lo[k], hi[k])
        tt = t[sl] - t[k]
        if len(tt) < 4:
            v[k], a[k] = np.nan, np.nan
            continue
        c = np.polyfit(tt, X[sl], 2)
        v[k], a[k] = c[1], 2 * c[0]
    return v, a


def place_knots(t: np.ndarray, X: np.ndarray, *, t_lo: float, t_hi: float, R: float,
                pitch: float, slip: float = 0.0, coarse_s: float | None = None,
                fine_s: float | None = None) -> np.ndarray:
    """Break points of the speed spline over [t_lo, t_hi].

    t, X: body reference position samples (s, mm), sorted by t (NaN-free).
    R, pitch: wheel pitch radius and lug pitch, mm; slip: rough slip (for belt speed).
    """
    t = np.asarray(t, float)
    X = np.asarray(X, float)
    v, a = _smooth_derivs(t, X, 0.2)
    ok = np.isfinite(a)
    v_max = np.nanmax(np.abs(v)) if ok.any() else 0.0
    vt = max(v_max / max(1.0 - slip, 0.5), 1.0)
    if coarse_s is None:
        coarse_s = float(np.clip(2 * np.pi * R / vt, 0.4, 2.0))
    if fine_s is None:
        fine_s = float(np.clip(0.45 * pitch / vt, 0.035, 0.07))
    # windows where the acceleration changes: |a| above 5% of its peak (and above noise)
    amax = np.nanmax(np.abs(a[ok])) if ok.any() else 0.0
    thr = max(0.05 * amax, 5.0)
    active = ok & (np.abs(a) > thr)
    margin = max(0.15, 2 * fine_s)
    windows = []
    for k in np.flatnonzero(active):
        lo_, hi_ = t[k] - margin, t[k] + margin
        if windows and lo_ <= windows[-1][1]:
            windows[-1][1] = hi_
        else:
            windows.append([lo_, hi_])
    pts = [t_lo]
    while pts[-1] < t_hi - 1e-9:
        cur = pts[-1]
        dense = any(a_ <= cur < b_ for a_, b_ in windows)
        nxt = cur + (fine_s if dense else coarse_s)
        for a_, _ in windows:  # never step over the start of a dense window
            if cur < a_ < nxt:
                nxt = a_
        pts.append(min(nxt, t_hi))
    br = np.asarray(pts)
    if len(br) >= 3 and br[-1] - br[-2] < 0.25 * fine_s:  # no sliver interval at the end
        br = np.delete(br, -2)
    return br
