"""Are a fit's residuals consistent with the measurement noise?

Four tests, each at level alpha/4 so that together (Bonferroni) the false-alarm rate on
recordings the model describes is at most alpha (measured: benchmarks/bench_explain.py):

1. chi^2/dof against its expected spread. The noise sigma comes from 4th differences of
   the residuals, so chi^2/dof scatters by its own sqrt(2/dof) AND by the relative error
   of sigma^2: 4th differences of white noise are correlated (sum of squared
   autocorrelations K = 2.627), so sigma^2 from n_d of them has variance 2 K / n_d
   (relative). The two add, weighted by each role's share of the data. One-sided.
2. Ljung-Box on every series (one marker, one axis, in time order): Q = n (n+2)
   sum_k rho_k^2 / (n-k) over lags 1..h, summed over series: chi^2 with S h dof.
   Sensitive to misfit shared by many series.
3. Cumulative periodogram (Bartlett): Kolmogorov-Smirnov distance of each series'
   normalised cumulative periodogram from the straight line of white noise; the
   smallest p-value times the number of series (Bonferroni). Sensitive to periodic
   misfit and to one bad series.
4. Spectral line: the periodogram of each series (normalised by its variance) averaged
   over the series of one role and axis; under white noise each ordinate is
   Gamma(S, 1/S) distributed, and the largest of m ordinates gets the p-value
   1 - (1 - P(ordinate > g))^m (Fisher's g test, summed over series), Bonferroni over the
   four (role, axis) groups. Sensitive to a weak periodic misfit that all markers share
   (a speed ripple, a vibration) long before it shows in chi^2.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy import special

from ..fit._noise import fourth_differences
from ._table import Geometry, structured_misfit

ALPHA = 0.05
LB_LAGS = 20
LINE_OVERSAMPLE = 4
K_4TH = 1.0 + 2.0 * (0.8 ** 2 + 0.4 ** 2 + (8 / 70) ** 2 + (1 / 70) ** 2)


@dataclass
class Detection:
    """The tests' statistics and p-values; `consistent` when none rejects at alpha / 4."""

    chi2: float
    dof: int
    chi2_per_dof: float
    chi2_spread: float  # standard deviation of chi2/dof expected from noise alone
    chi2_z: float
    chi2_p: float
    ljung_box_q: float
    ljung_box_dof: int
    ljung_box_p: float
    periodogram_d: float  # largest KS distance of any series
    periodogram_series: str  # which series
    periodogram_p: float  # Bonferroni-corrected
    line_hz: float  # frequency of the strongest common spectral line
    line_group: str  # its (role, axis) group
    line_p: float  # Bonferroni-corrected
    misfit: float  # structured misfit M (chi^2 units)
    misfit_z: float  # M over its white-noise spread
    alpha: float
    consistent: bool

    def as_dict(self) -> dict:
        d = asdict(self)
        return {k: (float(v) if isinstance(v, (np.floating, float)) else v) for k, v in d.items()}


def _series(geo: Geometry, r: np.ndarray):
    for s in geo.series_ids():
        sel = np.flatnonzero((geo.series == s) & geo.valid)
        sel = sel[np.argsort(geo.t[sel], kind="stable")]
        yield s, sel


def sigma_variance(geo: Geometry, r: np.ndarray) -> float:
    """Relative variance of chi^2 from the sigma estimate (0 when sigma was given)."""
    raw = np.where(geo.valid, r / np.where(geo.valid, geo.weight, 1.0), 0.0)
    n_d = {0: 0, 1: 0}
    n_role = {0: 0, 1: 0}
    for s, sel in _series(geo, r):
        role = int(geo.role[sel[0]])
        n_d[role] += len(fourth_differences(geo.t[sel], raw[sel]))
        n_role[role] += len(sel)
    tot = sum(n_role.values())
    return sum((n_role[k] / tot) ** 2 * 2.0 * K_4TH / n_d[k] for k in n_d if n_d[k] > 0)


def ljung_box(x: np.ndarray, h: int) -> float:
    n = len(x)
    if n <= h + 1:
        return 0.0
    den = float(x @ x)
    if den <= 0:
        return 0.0
    rho = np.array([x[:-k] @ x[k:] for k in range(1, h + 1)]) / den
    return float(n * (n + 2) * np.sum(rho ** 2 / (n - np.arange(1, h + 1))))


def bartlett(x: np.ndarray) -> tuple[float, float]:
    """(KS distance, p-value) of the cumulative periodogram of x against white noise."""
    n = len(x)
    m = (n - 1) // 2
    if m < 4:
        return 0.0, 1.0
    I = np.abs(np.fft.rfft(x)[1:m + 1]) ** 2
    tot = I.sum()
    if tot <= 0:
        return 0.0, 1.0
    C = np.cumsum(I) / tot
    j = np.arange(1, m + 1) / m
    D = float(np.max(np.abs(C - j)))
    sm = np.sqrt(m)
    return D, float(special.kolmogorov(D * (sm + 0.12 + 0.11 / sm)))


def serial_tests(series) -> tuple:
    """Tests 2 and 3 over `series` (1-D residual arrays, each in time order):
    (Ljung-Box Q summed over the series, its dof, its p-value, the largest KS distance of a
    cumulative periodogram, the index of that series (-1: none), its Bonferroni p-value)."""
    q_tot, n_lb, n_series = 0.0, 0, 0
    best_d, best_p, best_i = 0.0, 1.0, -1
    for i, x in enumerate(series):
        n_series += 1
        if len(x) > LB_LAGS + 1:
            q_tot += ljung_box(x, LB_LAGS)
            n_lb += LB_LAGS
        d, p = bartlett(x)
        if p < best_p or best_i < 0:
            best_d, best_p, best_i = d, p, i
    p_lb = float(special.chdtrc(n_lb, q_tot)) if n_lb else 1.0
    return q_tot, n_lb, p_lb, best_d, best_i, min(1.0, best_p * max(n_series, 1))


def spectral_line(geo: Geometry, r: np.ndarray) -> tuple[float, str, float]:
    """(frequency Hz, group, p-value) of the strongest line in the series-averaged periodogram."""
    best = (0.0, "", 1.0)
    groups = []
    for role, rname in ((0, "lug"), (1, "body")):
        for ax, aname in ((0, "x"), (1, "y")):
            xs = [r[sel] for s, sel in _series(geo, r)
                  if geo.role[sel[0]] == role and geo.axis[sel[0]] == ax]
            xs = [x for x in xs if len(x) >= 16]
            if xs:
                groups.append((f"{rname}.{aname}", xs))
    for name, xs in groups:
        n = min(len(x) for x in xs)
        m = (n - 1) // 2
        nf = LINE_OVERSAMPLE * n  # zero padding: a line between Fourier frequencies keeps its power
        mf = LINE_OVERSAMPLE * m
        acc = np.zeros(mf)
        for x in xs:
            x = x[:n]
            I = np.abs(np.fft.rfft(x, nf)[1:mf + 1]) ** 2 / n
            acc += I / max(float(x @ x) / n, 1e-300)
        S = len(xs)
        g = acc / S
        k = int(np.argmax(g))
        p1 = float(special.gammaincc(S, g[k] * S))
        # Bonferroni over all padded ordinates (conservative: they are not independent)
        p = float(-np.expm1(mf * np.log1p(-min(p1, 1 - 1e-16)))) * len(groups)
        if p < best[2] or not best[1]:
            best = ((k + 1) * geo.fps / nf, name, min(p, 1.0))
    return best


def detect(geo: Geometry, r: np.ndarray, dof: int, *, sigma_estimated: bool = True,
           alpha: float = ALPHA) -> Detection:
    """Test the weighted residuals `r` (laid out as `geo`) of a fit with `dof` degrees."""
    r = np.where(geo.valid, np.asarray(r, float), 0.0)
    chi2 = float(r @ r)
    cpd = chi2 / max(dof, 1)
    var = 2.0 / max(dof, 1) + (sigma_variance(geo, r) if sigma_estimated else 0.0)
    spread = float(np.sqrt(var))
    z = (cpd - 1.0) / spread
    p_chi2 = float(special.ndtr(-z))

    parts = list(_series(geo, r))
    q_tot, n_lb, p_lb, best_d, best_i, p_cp = serial_tests(r[sel] for _, sel in parts)
    best_s = geo.series_name(int(parts[best_i][0])) if best_i >= 0 else ""
    f_line, g_line, p_line = spectral_line(geo, r)
    M, sdM = structured_misfit(geo, r)
    level = alpha / 4.0
    ok = p_chi2 >= level and p_lb >= level and p_cp >= level and p_line >= level
    return Detection(chi2=chi2, dof=int(dof), chi2_per_dof=cpd, chi2_spread=spread, chi2_z=z,
                     chi2_p=p_chi2, ljung_box_q=q_tot, ljung_box_dof=n_lb, ljung_box_p=p_lb,
                     periodogram_d=best_d, periodogram_series=best_s, periodogram_p=p_cp,
                     line_hz=f_line, line_group=g_line, line_p=p_line,
                     misfit=M, misfit_z=M / sdM, alpha=alpha, consistent=bool(ok))
