"""Where the misfit is: by marker, role, axis, path segment, motion phase, time, frequency.

The misfit of a set of samples is its structured misfit (sum of lag-1 residual products,
see :mod:`._table`): the chi^2 the systematic part of the residuals carries there, with
white noise contributing zero on average. Shares are fractions of the positive total.

The located mismatch (DATA.md `discrepancy.located`) is a short list of parts, one per
(axis, path segment) cell that holds a significant share, each with the markers that
carry most of it, the motion phase it concentrates in ('all' if none), its time range,
and the frequency of its residual spectrum's peak when there is a clear one. The cells'
shares add up to at most 100 %. Rows found by a test rather than by a cell (a spectral
line, one non-white series) come after them with `share_of_misfit` None (they overlap
the cells) and their share of the excess chi^2 apart.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ._table import AXES, PHASES, SEGMENTS, Geometry, lag_products

MIN_Z = 3.0  # a cell's misfit must stand this many white-noise sd above zero, and
CELL_ALPHA = 1e-3  # ... beat chance over all the cells (family-wise, Bonferroni): with
# ~12 cells z > 3.8. At z > 3 alone, 2 of 16 clean recordings of bench_coverage whose
# Ljung-Box test fired by chance (it allows 5 %) found a 'place' at z = 3.1 and came out
# 'unexplained'.
MIN_SHARE = 0.05
MAX_PARTS = 6
MARKER_COVER = 0.8  # list markers until they hold this share of a part
PHASE_DOMINANCE = 0.6
WINDOW_S = 0.5
STRONG_P = 1e-4  # a test-only part needs this p-value (a place, not a fluke)
PEAK_FACTOR = 8.0  # a spectral peak must exceed the median power this many times


@dataclass
class Location:
    """Breakdown of a fit's misfit and the located parts (DATA.md dicts)."""

    total: float  # structured misfit M, chi^2 units
    total_z: float
    breakdown: dict = field(default_factory=dict)
    parts: list = field(default_factory=list)

    def as_dict(self) -> dict:
        return {"structured_misfit_chi2": self.total, "structured_misfit_z": self.total_z,
                "breakdown": self.breakdown}


def _shares(m: np.ndarray, labels: np.ndarray, names, pairs: np.ndarray) -> dict:
    # sums per label in one pass (bincount): a mask per name made the time windows' breakdown
    # quadratic in the recording's length (windows x samples)
    n = len(names)
    labels = np.asarray(labels)
    ok = (labels >= 0) & (labels < n)
    lab = labels[ok].astype(np.int64)
    count = np.bincount(lab, minlength=n)
    vs = np.bincount(lab, weights=np.asarray(m, float)[ok], minlength=n)
    ps = np.bincount(lab, weights=np.asarray(pairs, float)[ok], minlength=n)
    out = {}
    tot = 0.0
    for i, name in enumerate(names):
        if count[i] == 0:
            continue
        v = float(vs[i])
        out[name] = (v, float(np.sqrt(max(ps[i], 1.0))))
        tot += max(v, 0.0)
    return {k: {"share": (max(v, 0.0) / tot if tot > 0 else 0.0), "misfit_chi2": v,
                "z": v / sd} for k, (v, sd) in out.items()}


def _pair_counts(geo: Geometry) -> np.ndarray:
    c = np.zeros(len(geo.t))
    np.add.at(c, geo.pair_a, 0.5)
    np.add.at(c, geo.pair_b, 0.5)
    return c


def spectrum(geo: Geometry, r: np.ndarray, sel: np.ndarray):
    """(frequencies Hz, mean periodogram) of the series with samples in `sel` (Hann window).

    Each series is taken whole, in time order, with the samples outside `sel` set to zero
    (a gate that keeps the frequencies, broadened by the gate's own period).
    """
    n_max = 0
    series = []
    for s in np.unique(geo.series[sel]):
        idx = np.flatnonzero(geo.valid & (geo.series == s))
        idx = idx[np.argsort(geo.t[idx])]
        if len(idx) >= 16:
            series.append(np.where(sel[idx], r[idx], 0.0))
            n_max = max(n_max, len(idx))
    if not series:
        return np.zeros(0), np.zeros(0)
    f = np.fft.rfftfreq(n_max, 1.0 / geo.fps)
    P = np.zeros(len(f))
    for x in series:
        w = np.hanning(len(x))
        X = np.fft.rfft((x - x.mean()) * w, n_max)
        P += np.abs(X) ** 2 / np.sum(w ** 2)
    return f, P / len(series)


def peak(f: np.ndarray, P: np.ndarray, f_min: float = 0.3):
    """(peak frequency, its share of the excess power) or (None, 0) without a clear peak."""
    if len(f) < 8:
        return None, 0.0
    ok = f >= f_min
    if not ok.any():
        return None, 0.0
    med = float(np.median(P[ok]))
    k = int(np.flatnonzero(ok)[np.argmax(P[ok])])
    if med <= 0 or P[k] < PEAK_FACTOR * med:
        return None, 0.0
    band = np.abs(f - f[k]) <= 2.5 * (f[1] - f[0])
    exc = np.clip(P - med, 0, None)
    return float(f[k]), float(exc[band].sum() / max(exc.sum(), 1e-300))


def locked_power(geo: Geometry, r: np.ndarray) -> dict:
    """Misfit locked to belt phase: chi^2 drop of sin/cos regressions per series, minus noise.

    Lug passing: harmonics 1, 2 of 2 pi psi / p; wheel revolution: of psi / R; each with a
    constant amplitude and one growing with the speed (a speed ripple's trace does).
    """
    out = {}
    vn = geo.v / max(float(np.max(np.abs(geo.v))), 1e-12)
    for name, w in (("lug_passing", 2 * np.pi / geo.pitch), ("wheel_revolution", 1.0 / geo.R)):
        tot, k_tot = 0.0, 0
        for s in geo.series_ids():
            idx = np.flatnonzero((geo.series == s) & geo.valid)
            th = w * geo.psi[idx]
            A = np.column_stack([np.sin(th), np.cos(th), np.sin(2 * th), np.cos(2 * th)])
            A = np.hstack([A, A * vn[idx, None]])
            coef = np.linalg.lstsq(A, r[idx], rcond=None)[0]
            tot += float(np.sum((A @ coef) ** 2))
            k_tot += A.shape[1]
        out[name] = tot - k_tot  # noise alone gives chi^2(k_tot) on average
    return out


def locate(geo: Geometry, r: np.ndarray, det=None) -> Location:
    """Break the misfit of residuals `r` down and list the located parts.

    With the residuals' :class:`~fitlug.explain.Detection` `det`, a strong spectral line
    or one strongly non-white series (p < STRONG_P) is a located part too, so a misfit
    too fast for the lag-1 measure (a vibration above ~15 Hz) still has a place.
    """
    r = np.where(geo.valid, np.asarray(r, float), 0.0)
    m = lag_products(geo, r)
    pc = _pair_counts(geo)
    M = float(m.sum())
    sdM = float(np.sqrt(max(pc.sum(), 1.0)))
    markers = list(geo.markers)
    bd = {
        "role": _shares(m, geo.role, ("lug", "body"), pc),
        "marker": _shares(m, geo.marker, markers, pc),
        "axis": _shares(m, geo.axis, AXES, pc),
        "segment": _shares(m, geo.segment, SEGMENTS, pc),
        "phase": _shares(m, geo.phase, PHASES, pc),
    }
    edges = np.arange(geo.t_lo, geo.t_hi + WINDOW_S, WINDOW_S)
    win = np.clip(np.searchsorted(edges, geo.t, side="right") - 1, 0, len(edges) - 2)
    ws = _shares(m, win, [f"{edges[i]:.2f}-{edges[i + 1]:.2f}" for i in range(len(edges) - 1)],
                 pc)
    bd["time_window"] = [{"t_range_s": [float(a) for a in k.split("-")], **v}
                         for k, v in ws.items()]
    f, P = spectrum(geo, r, geo.valid)
    fpk, fsh = peak(f, P)
    locked = locked_power(geo, r)
    pos = max(M, 1e-300)
    bd["frequency"] = {
        "lug_passing_hz": geo.f_lug, "wheel_revolution_hz": geo.f_wheel,
        "peak_hz": fpk, "peak_share_of_excess_power": fsh,
        "locked_to_lug_passing_share": float(np.clip(locked["lug_passing"] / pos, 0, 1))
        if M > 0 else 0.0,
        "locked_to_wheel_revolution_share": float(np.clip(locked["wheel_revolution"] / pos, 0, 1))
        if M > 0 else 0.0,
    }
    parts = _parts(geo, r, m, pc, M)
    if det is not None:
        parts += _test_parts(geo, r, det, parts)
    return Location(total=M, total_z=M / sdM, breakdown=bd, parts=parts)


def _test_parts(geo, r, det, parts) -> list:
    """Parts for a strong spectral line and a strongly non-white series (see locate).

    They are not shares of the structured misfit (the cells' shares add up to at most
    100 %, these overlap them): their `share_of_misfit` is None, and their share of the
    excess chi^2 (sum r^2 - n, which counts fast misfit too) is `share_of_excess_chi2`.
    """
    out = []
    tot = max(float(np.sum(r[geo.valid] ** 2)) - geo.n, 1e-300)

    def share(sel):
        return float(np.clip((np.sum(r[sel] ** 2) - sel.sum()) / tot, 0.0, 1.0))

    if det.line_p < STRONG_P and det.line_group:
        role, ax = det.line_group.split(".")
        rl, axi = (0 if role == "lug" else 1), AXES.index(ax)
        sel = geo.valid & (geo.role == rl) & (geo.axis == axi)
        segs = np.unique(geo.segment[sel])
        # the segment whose gated spectrum carries most power at the line
        best, seg_best = -1.0, int(segs[0])
        for sg in segs:
            f, P = spectrum(geo, r, sel & (geo.segment == sg))
            if len(f):
                v = float(P[np.argmin(np.abs(f - det.line_hz))])
                if v > best:
                    best, seg_best = v, int(sg)
        names = sorted({geo.markers[k] for k in np.unique(geo.marker[sel])})
        out.append({"markers": names, "axis": ax, "segment": SEGMENTS[seg_best], "phase": "all",
                    "frequency_hz": float(det.line_hz),
                    "t_range_s": [float(geo.t[sel].min()), float(geo.t[sel].max())],
                    "share_of_misfit": None, "share_of_excess_chi2": share(sel),
                    "test": "spectral line",
                    "p_value": float(det.line_p)})
    if det.periodogram_p < STRONG_P and det.periodogram_series:
        name, ax = det.periodogram_series.rsplit(".", 1)
        if not any(name in p["markers"] and p["axis"] == ax for p in parts + out):
            mk, axi = geo.markers.index(name), AXES.index(ax)
            sel = geo.valid & (geo.marker == mk) & (geo.axis == axi)
            seg = int(np.bincount(geo.segment[sel], r[sel] ** 2).argmax())
            out.append({"markers": [name], "axis": ax, "segment": SEGMENTS[seg],
                        "phase": "all", "frequency_hz": None,
                        "t_range_s": [float(geo.t[sel].min()), float(geo.t[sel].max())],
                        "share_of_misfit": None, "share_of_excess_chi2": share(sel),
                        "test": "cumulative periodogram",
                        "p_value": float(det.periodogram_p)})
    return out


def _norm_isf(p: float) -> float:
    from scipy.special import ndtri

    return -ndtri(p)


def _parts(geo, r, m, pc, M) -> list:
    cells = []
    for ax in (0, 1):
        for seg in range(len(SEGMENTS)):
            sel = geo.valid & (geo.axis == ax) & (geo.segment == seg)
            if not sel.any():
                continue
            v = float(m[sel].sum())
            z = v / np.sqrt(max(pc[sel].sum(), 1.0))
            cells.append((v, z, ax, seg, sel))
    tot = sum(max(c[0], 0.0) for c in cells)
    if tot <= 0:
        return []
    cells.sort(key=lambda c: -c[0])
    z_min = max(MIN_Z, float(_norm_isf(CELL_ALPHA / max(len(cells), 1))))
    parts = []
    for v, z, ax, seg, sel in cells:
        share = v / tot
        if z < z_min or share < MIN_SHARE or len(parts) >= MAX_PARTS:
            continue
        parts.append(_describe(geo, r, m, sel, ax, seg, share, v))
    return parts


def _describe(geo, r, m, sel, ax, seg, share, v) -> dict:
    # markers holding most of the part
    per = []
    for mk in np.unique(geo.marker[sel]):
        per.append((float(m[sel & (geo.marker == mk)].sum()), int(mk)))
    per.sort(reverse=True)
    pos = sum(max(a, 0.0) for a, _ in per)
    names, acc = [], 0.0
    for a, mk in per:
        if a <= 0 or (acc >= MARKER_COVER * pos and names):
            break
        names.append(geo.markers[mk])
        acc += a
    # phase
    ph = {}
    for i, name in enumerate(PHASES):
        ph[name] = float(m[sel & (geo.phase == i)].sum())
    pos_ph = sum(max(a, 0.0) for a in ph.values())
    best = max(ph, key=ph.get)
    phase = best if (best != "rest" and pos_ph > 0
                     and ph[best] >= PHASE_DOMINANCE * pos_ph) else "all"
    # time range: where the cumulative misfit of the part's markers climbs from 5 to 95 %
    own = sel & np.isin(geo.marker, [geo.markers.index(n) for n in names])
    idx = np.flatnonzero(own if own.any() else sel)
    idx = idx[np.argsort(geo.t[idx], kind="stable")]
    c = np.cumsum(m[idx])
    if c[-1] > 0:
        t0 = float(geo.t[idx][np.argmax(c >= 0.05 * c[-1])])
        t1 = float(geo.t[idx][np.argmax(c >= 0.95 * c[-1])])
    else:
        t0, t1 = float(geo.t[idx][0]), float(geo.t[idx][-1])
    f, P = spectrum(geo, r, sel)
    fpk, _ = peak(f, P)
    return {"markers": names, "axis": AXES[ax], "segment": SEGMENTS[seg], "phase": phase,
            "frequency_hz": fpk, "t_range_s": [t0, t1], "share_of_misfit": float(share),
            "misfit_chi2": float(v)}


def residual_map(geo: Geometry, r: np.ndarray, bin_s: float = 0.1) -> dict:
    """Mean weighted residual per series and time bin (NaN where empty), for the report."""
    r = np.asarray(r, float)
    edges = np.arange(geo.t_lo, geo.t_hi + bin_s, bin_s)
    nb = len(edges) - 1
    ids = geo.series_ids()
    rows = []
    for s in ids:
        sel = geo.valid & (geo.series == s)
        b = np.clip(np.searchsorted(edges, geo.t[sel], side="right") - 1, 0, nb - 1)
        tot = np.bincount(b, r[sel], nb)
        cnt = np.bincount(b, None, nb)
        with np.errstate(invalid="ignore", divide="ignore"):
            rows.append(np.where(cnt > 0, tot / np.maximum(cnt, 1), np.nan))
    return {"series": [geo.series_name(int(s)) for s in ids],
            "t_edges_s": [round(float(e), 6) for e in edges],
            "mean_residual_sigma": [[None if not np.isfinite(v) else round(float(v), 3)
                                     for v in row] for row in rows]}


def spectrum_summary(geo: Geometry, r: np.ndarray, df: float = 0.1) -> dict:
    """Mean residual periodogram of all series, rebinned to `df` Hz, for the report."""
    f, P = spectrum(geo, np.asarray(r, float), geo.valid)
    if len(f) == 0:
        return {"f_hz": [], "power": []}
    edges = np.arange(0.0, f[-1] + df, df)
    b = np.clip(np.searchsorted(edges, f, side="right") - 1, 0, len(edges) - 2)
    cnt = np.bincount(b, None, len(edges) - 1)
    tot = np.bincount(b, P, len(edges) - 1)
    ok = cnt > 0
    return {"f_hz": [round(float(v), 4) for v in (edges[:-1] + df / 2)[ok]],
            "power": [float(f"{v:.4g}") for v in (tot[ok] / cnt[ok])],
            "lug_passing_hz": geo.f_lug, "wheel_revolution_hz": geo.f_wheel}
