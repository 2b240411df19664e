"""A camera that shakes: a common image motion at a few frequencies, carried as a nuisance.

A camera on a test rig vibrates with the floor or the motor: the whole image moves, every
marker by the same small displacement d(t), the lug markers in contact with the ground as
much as the body markers. No physics in MODEL.md's catalog moves a lug that stands on the
ground, so such a recording ends 'unexplained' (it is outside the catalog). Its located
misfit is coherent over the whole recording: the scores of the in-time sandwich cancel
from window to window, and the robust errors of explain._robust come out several times
too wide (bench_coverage's vibration row: rms z 0.59 for s0, 0.14 for k).

When the verdict is 'unexplained', this module asks whether the misfit is such a motion:

1. the common mode: per frame and axis the weighted mean residual of all markers
   (what a common displacement of the image leaves), and its periodogram (zero-padded
   FFT on the frame grid, x and y powers summed) between MIN_CYCLES periods per recording
   and 0.45 times the frame rate; the peak, refined on a fine grid, is a candidate line;
2. the line, a sine and a cosine per axis (4 columns, every sample weighted as its
   residual), is fitted beside every parameter of the model (one linear least-squares step
   with the model's exact Jacobian, as the tracker-systematics nuisance is); it must lower
   chi^2 by more than the largest of the periodogram's bins would through the noise alone
   (family-wise false-alarm FALSE_ALARM over the frequencies searched, chi^2 with 4
   degrees);
3. up to MAX_LINES lines (a vibration that is not a pure sine has harmonics), until the
   residuals pass detection (fitlug.explain.detect) or nothing is located in them: the
   motion must hold the whole misfit, else nothing changes (a marker knocked on its lug, a
   speed modulation and tracker systematics leave structure a common motion cannot carry).

Then the verdict stays 'unexplained' (a camera motion is no catalog physics), but the
motion is taken out of the data and the model refitted (explain._robust.motion_result):
the headline is that refit, and each error the larger of its least-squares one and the
one with the motion's own uncertainty carried (the model's covariance with the motion
fitted beside it). On bench_coverage's vibration recordings the base fit's slip lay ~3
least-squares errors from the truth (the motion biases it), the refit's ~0.3.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

from ..fit._lsq import RowChunks
from ._detect import detect
from ._engine import normal_of, pinv_factor
from ._locate import locate

MIN_CYCLES = 2.0  # a line needs two periods in the recording (slower trades with X(t))
F_MAX_NYQUIST = 0.9  # of the Nyquist frequency
PAD = 4  # zero padding of the periodogram
FALSE_ALARM = 1e-3  # family-wise, over the frequencies searched
MAX_LINES = 3
REFINE = 41  # points of the fine grid over +-1 coarse bin


def _frames(geo):
    """Frame index of every sample and the number of frames."""
    k = np.rint((np.asarray(geo.t, float) - geo.t_lo) * geo.fps).astype(np.int64)
    k = np.clip(k, 0, None)
    return k, int(k.max()) + 1 if len(k) else 0


def _common_mode(geo, r, k, n):
    """Per axis (2, n): the score series s = sum w r and the weight W = sum w^2 per frame
    (an image displacement d adds W d to s)."""
    w = np.where(geo.valid, geo.weight, 0.0)
    s = np.zeros((2, n))
    W = np.zeros((2, n))
    for a in (0, 1):
        m = geo.axis == a
        s[a] = np.bincount(k[m], w[m] * r[m], n)
        W[a] = np.bincount(k[m], w[m] ** 2, n)
    return s, W


def _line_power(s, W, t, f):
    """chi^2 removed by a sine/cosine per axis at each frequency of `f` (m,) fitted to the
    common mode alone: sum over axes of b^T A^-1 b, b = sum s (sin, cos), A = sum W (..)(..)^T."""
    ph = 2 * np.pi * np.outer(f, t)
    c, sn = np.cos(ph), np.sin(ph)
    out = np.zeros(len(f))
    for a in (0, 1):
        b1, b2 = c @ s[a], sn @ s[a]
        a11, a22, a12 = (c * c) @ W[a], (sn * sn) @ W[a], (c * sn) @ W[a]
        det = a11 * a22 - a12 * a12
        ok = det > 1e-12 * np.maximum(a11 * a22, 1e-300)
        q = (a22 * b1 * b1 - 2 * a12 * b1 * b2 + a11 * b2 * b2) / np.where(ok, det, 1.0)
        out += np.where(ok, q, 0.0)
    return out


def find_line(geo, r, exclude=()):
    """(frequency, its common-mode power, number of independent frequencies searched) of
    the strongest line of the common image motion in residuals r, or None."""
    k, n = _frames(geo)
    if n < 16:
        return None
    s, W = _common_mode(geo, r, k, n)
    T = n / geo.fps
    f_lo, f_hi = MIN_CYCLES / T, F_MAX_NYQUIST * 0.5 * geo.fps
    m = PAD * (1 << int(math.ceil(math.log2(n))))
    f = np.fft.rfftfreq(m, 1.0 / geo.fps)
    P = np.abs(np.fft.rfft(s[0], m)) ** 2 + np.abs(np.fft.rfft(s[1], m)) ** 2
    use = (f >= f_lo) & (f <= f_hi)
    df = geo.fps / m
    for fe in exclude:  # a line already fitted (and its neighbourhood)
        use &= np.abs(f - fe) > 2 * PAD * df
    if not np.any(use):
        return None
    i = int(np.flatnonzero(use)[np.argmax(P[use])])
    t = np.arange(n) / geo.fps
    fine = np.linspace(f[i] - df, f[i] + df, REFINE)
    pw = _line_power(s, W, t, fine)
    j = int(np.argmax(pw))
    n_freq = max(int((f_hi - f_lo) * T), 1)  # independent frequencies (1/T apart)
    return float(fine[j]), float(pw[j]), n_freq


def _columns(geo, freqs):
    """Nuisance design (S, 4 L): per line and axis a sine and a cosine of time, each row
    weighted as its residual (zero where a sample is invalid)."""
    w = np.where(geo.valid, geo.weight, 0.0)
    t = np.asarray(geo.t, float)
    cols = []
    for f in freqs:
        ph = 2 * np.pi * f * (t - geo.t_lo)
        for a in (0, 1):
            on = (geo.axis == a) * w
            cols += [on * np.sin(ph), on * np.cos(ph)]
    return np.stack(cols, axis=1)


def _joint_fit(J, r, N):
    """One linear least-squares step of [J, N] on r: (delta, r2, model covariance with the
    nuisance carried)."""
    n_p = J.n_par if isinstance(J, RowChunks) else J.shape[1]
    JJ, JN = normal_of(J, N)
    Jr = normal_of(J, r)[1]
    A = np.block([[JJ, JN], [JN.T, N.T @ N]])
    b = np.r_[Jr, N.T @ r]
    M = pinv_factor(A, 1e-14)
    delta = -(M @ (M.T @ b))
    Jd = J.matvec(delta[:n_p]) if isinstance(J, RowChunks) else np.asarray(J) @ delta[:n_p]
    r2 = r + Jd + N @ delta[n_p:]
    return delta, r2, (M @ M.T)[:n_p, :n_p]


def image_motion(res, geo, J, r, *, alpha: float, sigma_estimated: bool):
    """The common image motion that holds the misfit of fit `res` (weighted residuals r,
    zero where invalid; J its Jacobian or time chunks), or None: {"lines": [{frequency_hz,
    amplitude_um: [x, y], dchi2, threshold}], "delta", "r2", "cov", "dchi2",
    "chi2_per_dof"}."""
    chi2 = float(r @ r)
    freqs, lines, fit = [], [], None
    cur = r
    for _ in range(MAX_LINES):
        found = find_line(geo, cur, exclude=freqs)
        if found is None:
            return None
        f, _, n_freq = found
        trial = freqs + [f]
        N = _columns(geo, trial)
        delta, r2, cov = _joint_fit(J, r, N)
        prev = float(cur @ cur)
        gain = prev - float(r2 @ r2)
        thr = float(stats.chi2.isf(FALSE_ALARM / n_freq, 4))
        if not gain > thr:
            return None  # no significant line (left): the motion does not hold the misfit
        freqs, cur, fit = trial, r2, (N, delta, r2, cov)
        lines.append({"frequency_hz": f, "dchi2": gain, "threshold": thr})
        dof = res.dof - N.shape[1]
        det = detect(geo, r2, dof, sigma_estimated=sigma_estimated, alpha=alpha)
        if det.consistent or not locate(geo, r2, det).parts:
            break
    else:
        return None
    N, delta, r2, cov = fit
    n_p = len(delta) - N.shape[1]
    for i, ln in enumerate(lines):  # amplitude of each line per axis, um (0-peak)
        a = delta[n_p + 4 * i: n_p + 4 * i + 4]
        ln["amplitude_um"] = [1000.0 * float(np.hypot(a[0], a[1])),
                              1000.0 * float(np.hypot(a[2], a[3]))]
    w = np.where(geo.valid, geo.weight, 0.0)
    motion = np.where(w > 0, (N @ delta[n_p:]) / np.where(w > 0, w, 1.0), 0.0)
    return {"lines": lines, "delta": delta[:n_p], "r2": r2, "cov": 0.5 * (cov + cov.T),
            "motion_mm": motion,
            "dchi2": chi2 - float(r2 @ r2),
            "chi2_per_dof": float(r2 @ r2) / max(res.dof - N.shape[1], 1)}


__all__ = ["image_motion", "find_line"]
