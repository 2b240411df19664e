"""The error of a mean read off a few samples (the straight runs' readings)."""

from __future__ import annotations

import numpy as np


def t_over_z(dof: int) -> float:
    """Two-sided 95 % Student t over the normal's 1.96: a scatter read off a few samples
    (contact times, the top run's visits in explain._straight) widened by it holds its
    95 % interval as a known sigma would (2.19 at 2 degrees of freedom, 1.15 at 9)."""
    from scipy.special import stdtrit

    return float(stdtrit(max(int(dof), 1), 0.975)) / 1.959963984540054


def batch_mean_std(values) -> float:
    """The error of the mean of a few batch values (the slip over each contact time):
    their standard error, times :func:`t_over_z`."""
    v = np.asarray(values, float)
    return float(np.std(v, ddof=1) / np.sqrt(len(v)) * t_over_z(len(v) - 1))


def _line(t, x, ta, tb):
    """(t, x, [slope, intercept]) of the finite samples x(t) over [ta, tb] and their
    least-squares line, or None with fewer than eight of them."""
    t, x = np.asarray(t, float), np.asarray(x, float)
    m = (t >= ta) & (t <= tb) & np.isfinite(x)
    if np.sum(m) < 8:
        return None
    return t[m], x[m], np.polyfit(t[m], x[m], 1)


def about_line(t, x, ta, tb) -> float:
    """The scatter (std) of samples x(t) about their straight line over [ta, tb]; 0 with
    fewer than eight finite samples there."""
    fit = _line(t, x, ta, tb)
    if fit is None:
        return 0.0
    tm, xm, coef = fit
    return float(np.std(xm - np.polyval(coef, tm)))


def line_slope(t, x, ta, tb) -> float | None:
    """The slope of the least-squares line through samples x(t) over [ta, tb] (x's units
    per second), or None with fewer than eight finite samples there. Where x surges about
    its line, the slope moves far less with the span's ends than the travel between them
    does: the ends weigh as much as the middle in a difference, a surge's swing at either
    end entering whole."""
    fit = _line(t, x, ta, tb)
    return None if fit is None else float(fit[2][0])
