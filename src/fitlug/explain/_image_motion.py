"""A camera that shakes: a common image motion at a few frequencies, a nuisance kind.

A camera on a test rig vibrates with the floor or the motor: the whole image moves, every
marker by the same small displacement d(t), the lug markers in contact with the ground as
much as the body markers. No physics in MODEL.md's catalog moves a lug that stands on the
ground, so such a recording ends 'unexplained' (it is outside the catalog). Its located
misfit is coherent over the whole recording: the scores of the in-time sandwich cancel
from window to window, and the robust errors of explain._robust came out several times
too wide (bench_coverage's vibration row: rms z 0.59 for s0, 0.14 for k), while the base
fit's slip lay ~3 least-squares errors from the truth (the motion biases it).

A term is a line: the common mode (per frame and axis the weighted mean residual of all
markers, what a common displacement of the image leaves), its periodogram (zero-padded FFT
on the frame grid, x and y powers summed) between MIN_CYCLES periods per recording and
0.9 times the Nyquist frequency, the peak refined on a fine grid; its columns a sine and a
cosine per axis. :func:`fitlug.explain._nuisance.search` fits, tests and takes it out.
"""

from __future__ import annotations

import math

import numpy as np

MIN_CYCLES = 2.0  # a line needs two periods in the recording (slower trades with X(t))
F_MAX_NYQUIST = 0.9  # of the Nyquist frequency
PAD = 4  # zero padding of the periodogram
MAX_LINES = 3
REFINE = 41  # points of the fine grid over +-1 coarse bin
REFINE_STEPS = 4  # Gauss-Newton steps of the frequencies on the joint fit


def frames(geo):
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
    k, n = frames(geo)
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


class ImageMotion:
    """The nuisance kind of :func:`fitlug.explain._nuisance.search`: lines of a common
    image motion."""

    name = "image motion"
    per_term = 4
    max_terms = MAX_LINES

    @staticmethod
    def find(geo, r, exclude):
        found = find_line(geo, r, exclude=exclude)
        if found is None:
            return None
        f, _, n_freq = found
        return f, n_freq

    columns = staticmethod(_columns)

    @staticmethod
    def refine(geo, J, r, terms):
        """The frequencies by Gauss-Newton on the joint fit: the periodogram's peak is off
        by a few mHz (the model's own trade with the motion), and over a recording of a
        few seconds that leaves a coherent residue of a few um in every marker, enough
        to move the slip by an error or two."""
        from ._nuisance import joint_fit

        w = np.where(geo.valid, geo.weight, 0.0)
        dt = np.asarray(geo.t, float) - geo.t_lo
        f = np.asarray(terms, float)
        for _ in range(REFINE_STEPS):
            N = _columns(geo, f)
            delta, _, _ = joint_fit(J, r, N)
            a = delta[len(delta) - N.shape[1]:]
            D = np.zeros((len(dt), len(f)))
            for i, fi in enumerate(f):
                ph = 2 * np.pi * fi * dt
                for ax in (0, 1):
                    s_, c_ = a[4 * i + 2 * ax], a[4 * i + 2 * ax + 1]
                    on = (geo.axis == ax) * w
                    D[:, i] += on * 2 * np.pi * dt * (s_ * np.cos(ph) - c_ * np.sin(ph))
            step = joint_fit(J, r, np.hstack([N, D]))[0][-len(f):]
            step = np.clip(step, -0.5 / max(dt.max(), 1e-9), 0.5 / max(dt.max(), 1e-9))
            f = f + step
            if np.max(np.abs(step)) < 1e-7 * max(geo.fps, 1.0):
                break
        return [float(x) for x in f]

    @staticmethod
    def describe(terms, coef, geo=None):
        """One dict per line: frequency and 0-peak amplitude per axis (um)."""
        out = []
        for i, f in enumerate(terms):
            a = coef[4 * i: 4 * i + 4]
            out.append({"frequency_hz": float(f),
                        "amplitude_um": [1000.0 * float(np.hypot(a[0], a[1])),
                                         1000.0 * float(np.hypot(a[2], a[3]))]})
        return out

    @staticmethod
    def label(terms, geo=None):
        freqs = ", ".join(f"{f:.3g}" for f in terms)
        return (f"a common image motion at {freqs} Hz",
                "every marker, the lugs standing on the ground too, moves by one "
                f"displacement at {freqs} Hz: the camera moved (no catalog physics)")


__all__ = ["ImageMotion", "find_line", "frames"]
