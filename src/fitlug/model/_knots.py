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
The ramps are found where the body markers' smoothed acceleration is large both locally
and averaged over one wheel period (a ramp's acceleration lasts, a runout's or a
ripple's averages out: the body's own speed modulation must not buy itself dense
knots), measured on each body
marker's own track (never on a chained average, where a marker entering or leaving the
picture makes a step), after isolated gross errors are set aside (a sample far from the
cubic through its 4 neighbours), and only where the smoothing window is covered on both
sides: a track's ends and gaps are not ramps. Where no body marker measures the
acceleration (the robot entering or leaving the picture shows its lugs first and last;
all body markers hidden), lug markers on the straight top run stand in for them: they
move at v + v_t = v (2 - s) / (1 - s), so their x scaled by (1 - s) / (2 - s) is the
body's travel up to an offset (`aux_tracks`; see :func:`top_run_tracks`). Spans that
neither measures get the ramp spacing when the speed differs across them or a ramp
touches them, else the cruise spacing.
"""

from __future__ import annotations

import numpy as np


def _smooth_derivs(t: np.ndarray, X: np.ndarray, window_s: float, *, block: int = 4096):
    """Local quadratic fits: (v, a) at each t from X within +-window_s/2.

    Every sample's fit at once (in blocks of `block` samples): the window's samples are
    gathered into a padded row with a mask, the time scaled by the half window, and the
    3x3 normal equations solved batched - the same numbers as a polyfit per sample to
    rounding, in linear time without a Python loop over the samples."""
    t = np.asarray(t, float)
    X = np.asarray(X, float)
    n = len(t)
    v = np.full(n, np.nan)
    a = np.full(n, np.nan)
    if n == 0:
        return v, a
    half = window_s / 2
    lo = np.searchsorted(t, t - half)
    hi = np.searchsorted(t, t + half, side="right")
    width = int((hi - lo).max())
    cols = np.arange(width)
    for b0 in range(0, n, block):
        k = np.arange(b0, min(b0 + block, n))
        idx = lo[k, None] + cols
        m = idx < hi[k, None]
        idx = np.minimum(idx, n - 1)
        u = np.where(m, (t[idx] - t[k, None]) / half, 0.0)
        y = np.where(m, X[idx], 0.0)
        w = m.astype(float)
        p = [w, u, u * u]
        S = np.empty((len(k), 3, 3))
        r = np.empty((len(k), 3))
        for i in range(3):
            r[:, i] = (p[i] * y).sum(1)
            for j in range(i, 3):
                S[:, i, j] = S[:, j, i] = (p[i] * p[j]).sum(1)
        enough = m.sum(1) >= 4
        c = np.linalg.solve(S[enough], r[enough][..., None])[..., 0]
        v[k[enough]] = c[:, 1] / half
        a[k[enough]] = 2 * c[:, 2] / half ** 2
    return v, a


def _clean(t: np.ndarray, x: np.ndarray):
    """The track without isolated gross errors: samples far from the cubic through their
    four neighbours (x_k vs (-x_k-2 + 4 x_k-1 + 4 x_k+1 - x_k+2) / 6, exact for any cubic
    motion), flagged at the local peak of that misfit, > 8 robust sigmas."""
    n = len(x)
    if n < 9:
        return t, x
    r = np.full(n, np.nan)
    r[2:-2] = x[2:-2] - (-x[:-4] + 4 * x[1:-3] + 4 * x[3:-1] - x[4:]) / 6
    dt = np.diff(t)
    step = np.median(dt)
    even = np.full(n, False)  # the five samples are consecutive, evenly spaced frames
    d = np.abs(dt - step) < 0.25 * step
    even[2:-2] = d[:-3] & d[1:-2] & d[2:-1] & d[3:]
    r[~even] = np.nan
    ok = np.isfinite(r)
    if ok.sum() < 5:
        return t, x
    sig = 1.4826 * np.median(np.abs(r[ok] - np.median(r[ok])))
    a = np.where(ok, np.abs(r), 0.0)
    peak = np.r_[False, (a[1:-1] >= a[:-2]) & (a[1:-1] >= a[2:]), False]
    bad = peak & (a > max(8 * sig, 1e-9))
    return t[~bad], x[~bad]


def _track_derivs(t: np.ndarray, x: np.ndarray, window_s: float):
    """(v, a) of one track where its smoothing window is covered on both sides, else NaN."""
    t, x = _clean(np.asarray(t, float), np.asarray(x, float))
    if len(t) < 4:
        return t, np.full(len(t), np.nan), np.full(len(t), np.nan)
    v, a = _smooth_derivs(t, x, window_s)
    half = window_s / 2
    lo = np.searchsorted(t, t - half)
    hi = np.searchsorted(t, t + half, side="right") - 1
    dt = np.diff(t)
    big = np.r_[np.flatnonzero(dt > 0.25 * window_s), len(t)]
    # covered: samples reach 70 % of the half window each side, no gap > window/4 inside
    nxt_gap = big[np.searchsorted(big, lo)]  # first big gap at or after the window start
    ok = (t - t[lo] >= 0.7 * half) & (t[hi] - t >= 0.7 * half) & (nxt_gap >= hi)
    v[~ok] = np.nan
    a[~ok] = np.nan
    return t, v, a


def _period_mean(t: np.ndarray, a: np.ndarray, window_s: float) -> np.ndarray:
    """Moving mean of a (NaN-free part) over window_s; NaN where under 70 % covered."""
    out = np.full(len(t), np.nan)
    ok = np.isfinite(a)
    if ok.sum() < 2:
        return out
    tv, av = t[ok], a[ok]
    c = np.r_[0.0, np.cumsum(av)]
    lo = np.searchsorted(tv, tv - window_s / 2)
    hi = np.searchsorted(tv, tv + window_s / 2, side="right")
    step = np.median(np.diff(tv))
    n_exp = window_s / step
    good = ((hi - lo) >= 0.7 * n_exp) & (tv - tv[lo] >= 0.35 * window_s) \
        & (tv[hi - 1] - tv >= 0.35 * window_s)
    m = (c[hi] - c[lo]) / np.maximum(hi - lo, 1)
    out[np.flatnonzero(ok)[good]] = m[good]
    return out


#: an end span of the recording (before the first or after the last time any track
#: measures the acceleration) longer than this gets the ramp spacing; a recording that
#: starts or ends in view leaves ~0.1 s there (the smoothing window's half, plus margins)
END_SPAN_S = 0.15


def top_run_tracks(tracks, *, top_y: float, slip: float, tol_mm: float = 0.5,
                   min_samples: int = 8) -> list:
    """Body-travel stand-ins from lug markers on the straight top run.

    tracks: (t, x, y) of each lug marker (ground frame, mm, NaN-free, sorted by t);
    top_y: the top run's height (mm). Returns (t, x (1 - s) / (2 - s)) for every run of
    consecutive samples within `tol_mm` of top_y (at least `min_samples` long): on the top
    run a lug marker moves at v + v_t = v (2 - s) / (1 - s), so that scaled x advances
    like the body's X (up to an offset, and to a slip change over the run)."""
    out = []
    scale = (1.0 - slip) / (2.0 - slip)
    for t, x, y in tracks:
        on = np.abs(np.asarray(y) - top_y) < tol_mm
        if on.sum() < min_samples:
            continue
        k = np.flatnonzero(np.diff(np.r_[0, on.astype(np.int8), 0]))
        for a, b in zip(k[::2], k[1::2]):
            if b - a >= min_samples:
                out.append((np.asarray(t[a:b], float), scale * np.asarray(x[a:b], float)))
    return out


def _uncovered(parts, aux):
    """The aux tracks' samples at times where no body track measures the acceleration."""
    tb = np.sort(np.concatenate([p[0][np.isfinite(p[2])] for p in parts])) \
        if parts else np.zeros(0)
    out = []
    for t, v, a in aux:
        if len(tb):
            j = np.clip(np.searchsorted(tb, t), 1, max(len(tb) - 1, 1))
            near = np.minimum(np.abs(tb[j - 1] - t), np.abs(tb[np.minimum(j, len(tb) - 1)] - t))
            keep = near > 0.05
        else:
            keep = np.ones(len(t), bool)
        out.append((t, np.where(keep, v, np.nan), np.where(keep, a, np.nan)))
    return out


def place_knots(t: np.ndarray, X: np.ndarray, *, t_lo: float, t_hi: float, R: float,
                pitch: float, slip: float = 0.0, coarse_s: float | None = None,
                fine_s: float | None = None, tracks=None, aux_tracks=None) -> np.ndarray:
    """Break points of the speed spline over [t_lo, t_hi].

    t, X: body reference position samples (s, mm), sorted by t (NaN-free).
    tracks: optional list of (t, x) of each body marker (each sorted by t); when given,
        velocity and acceleration come from each track separately (markers that enter,
        leave or are hidden then make no artefacts).
    aux_tracks: optional (t, X-like) stand-ins (:func:`top_run_tracks`), used only at times
        where no body track measures the acceleration.
    R, pitch: wheel pitch radius and lug pitch, mm; slip: rough slip (for belt speed).
    """
    t = np.asarray(t, float)
    X = np.asarray(X, float)
    if tracks is None:
        tracks = [(t, X)]
    parts = [_track_derivs(tt, xx, 0.2) for tt, xx in tracks]
    if aux_tracks:
        parts = parts + _uncovered(parts, [_track_derivs(tt, xx, 0.2) for tt, xx in aux_tracks])
    vall = np.concatenate([p[1] for p in parts])
    v_max = float(np.nanmax(np.abs(vall))) if np.isfinite(vall).any() else 0.0
    if not np.isfinite(vall).any() and len(t) > 1:
        v_max = float(np.ptp(X) / max(np.ptp(t), 1e-9))
    vt = max(v_max / max(1.0 - slip, 0.5), 1.0)
    period = 2 * np.pi * R / vt
    if coarse_s is None:
        coarse_s = float(np.clip(period, 0.4, 2.0))
    # a ramp's acceleration lasts; a wheel runout's or lug ripple's averages out over one
    # wheel period: ramps are found on the acceleration averaged over a wheel period
    means = [_period_mean(tt, aa, float(np.clip(period, 0.2, 2.0))) for tt, _, aa in parts]
    ta = np.concatenate([p[0] for p in parts])
    va = np.concatenate([p[1] for p in parts])
    aa = np.concatenate([p[2] for p in parts])
    am = np.concatenate(means)
    ok = np.isfinite(aa) & np.isfinite(va)
    order = np.argsort(ta[ok], kind="stable")
    tk, vk, ak, amk = ta[ok][order], va[ok][order], aa[ok][order], am[ok][order]
    # where a track's period mean is not covered, another track's at the same time
    have = np.isfinite(amk)
    if have.any():
        th, ah = tk[have], amk[have]
        j = np.clip(np.searchsorted(th, tk), 1, max(len(th) - 1, 1))
        j0 = np.where(np.abs(th[j - 1] - tk) <= np.abs(th[np.minimum(j, len(th) - 1)] - tk),
                      j - 1, np.minimum(j, len(th) - 1))
        near = np.abs(th[j0] - tk) <= 0.05
        amk = np.where(have, amk, np.where(near, ah[j0], np.nan))
    if fine_s is None:
        fine_s = float(np.clip(0.45 * pitch / vt, 0.035, 0.07))
    # windows where the acceleration changes: |a| above 5% of its peak (and above noise)
    amax = float(np.max(np.abs(ak))) if len(ak) else 0.0
    thr = max(0.05 * amax, 5.0)
    # a ramp: the acceleration is large now and over the surrounding wheel period (where
    # no track covers a whole period, the local value decides)
    active = (np.abs(ak) > thr) & ~(np.abs(amk) <= thr)
    margin = max(0.15, 2 * fine_s)
    spans = [[tk[k] - margin, tk[k] + margin] for k in np.flatnonzero(active)]
    # spans no body marker measures: ramp spacing if the speed changes across or a ramp
    # touches them
    edges = np.r_[t_lo, tk, t_hi]
    vedge = np.r_[vk[:1] if len(vk) else [0.0], vk, vk[-1:] if len(vk) else [0.0]]
    aedge = np.r_[False, active, False]
    last = len(edges) - 2
    for k in np.flatnonzero(np.diff(edges) > 0.1):
        a_, b_ = edges[k], edges[k + 1]
        # at the recording's ends nothing says what the speed did (the robot enters or
        # leaves the picture showing only its arcs and bottom run, where a ramp may begin):
        # an end span longer than END_SPAN_S gets the ramp spacing
        end = (k == 0 or k == last) and b_ - a_ > END_SPAN_S
        if len(vk) == 0 or abs(vedge[k + 1] - vedge[k]) > 0.05 * max(v_max, 1.0) \
                or aedge[k] or aedge[k + 1] or end:
            spans.append([a_ - margin if aedge[k] else a_, b_ + margin if aedge[k + 1] else b_])
    spans.sort()
    windows = []
    for lo_, hi_ in spans:
        if windows and lo_ <= windows[-1][1]:
            windows[-1][1] = max(windows[-1][1], hi_)
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


#: frames with data each interval of the speed spline holds (its ends: fit._problem.END_FRAMES)
MIN_INTERVAL_FRAMES = 2


def merge_thin_intervals(breaks: np.ndarray, frames: np.ndarray,
                         min_frames: float = MIN_INTERVAL_FRAMES,
                         weights: np.ndarray | None = None) -> np.ndarray:
    """`breaks` with every interval holding fewer than `min_frames` frames of data (each
    frame counted with its weight, default 1) merged into its thinner neighbour.

    Ramp spacing where almost nothing is seen (a drive-in's first lug samples, then 0.2 s
    with no marker before the body enters) left runs of empty intervals whose speed
    coefficients only the few samples around them held: LM swung them to +-700 mm/s, the
    slip law reached s = 0.99 between samples, the Jacobian's s0 column grew to 1e12 and
    the slip's standard error to 2e-9 (z = -2.6e7)."""
    breaks = np.asarray(breaks, float)
    while len(breaks) > 3:
        n = np.histogram(frames, bins=breaks, weights=weights)[0]
        thin = np.flatnonzero(n < min_frames)
        if not len(thin):
            break
        k = int(thin[np.argmin(n[thin])])
        # merge interval k with the neighbour holding fewer frames (delete the break between)
        if k == 0:
            j = 1
        elif k == len(n) - 1:
            j = k
        else:
            j = k if n[k - 1] <= n[k + 1] else k + 1
        breaks = np.delete(breaks, j)
    return breaks
