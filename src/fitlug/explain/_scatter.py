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
