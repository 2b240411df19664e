"""Cubic B-spline design matrices for the speed profile v(t) (numpy, built once per layout).

The speed v(t) = sum_k c_k B_k(t); its derivative a(t) = sum_k c_k B_k'(t). Knots are
chosen by :func:`fitlug.model.place_knots` (see its docstring for why they are adaptive).
"""

from __future__ import annotations

import numpy as np

DEGREE = 3


def full_knots(breaks: np.ndarray, degree: int = DEGREE) -> np.ndarray:
    """Clamped knot vector from strictly increasing break points."""
    b = np.asarray(breaks, dtype=float)
    return np.r_[np.repeat(b[0], degree), b, np.repeat(b[-1], degree)]


def n_coefficients(breaks: np.ndarray, degree: int = DEGREE) -> int:
    return len(breaks) + degree - 1


def design(t: np.ndarray, breaks: np.ndarray, deriv: int = 0, degree: int = DEGREE) -> np.ndarray:
    """Matrix (len(t), n_coefficients) of B-spline basis values (or `deriv`-th derivatives) at t.

    Times outside [breaks[0], breaks[-1]] are clamped to the ends.
    """
    t = np.clip(np.asarray(t, dtype=float), breaks[0], breaks[-1])[:, None]
    knots = full_knots(breaks, degree)
    n = len(knots) - degree - 1
    m = len(knots) - 1
    B = np.zeros((t.shape[0], m))
    idx = np.clip(np.searchsorted(knots, t[:, 0], side="right") - 1, degree, n - 1)
    B[np.arange(t.shape[0]), idx] = 1.0
    for p in range(1, degree + 1):
        k = B.shape[1]
        d1 = _inv(knots[p:p + k - 1] - knots[:k - 1])
        d2 = _inv(knots[p + 1:p + k] - knots[1:k])
        if p <= degree - deriv:  # Cox-de Boor
            B = (t - knots[:k - 1]) * d1 * B[:, :-1] + (knots[p + 1:p + k] - t) * d2 * B[:, 1:]
        else:  # derivative recursion for the last `deriv` orders
            B = p * (d1 * B[:, :-1] - d2 * B[:, 1:])
    return B[:, :n]


def _inv(d: np.ndarray) -> np.ndarray:
    out = np.zeros_like(d)
    np.divide(1.0, d, out=out, where=d > 0)
    return out
