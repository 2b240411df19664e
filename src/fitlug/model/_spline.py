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


def banded(t: np.ndarray, breaks: np.ndarray, deriv: int = 0, degree: int = DEGREE):
    """The nonzero band of :func:`design`: (values (len(t), degree + 1), first column (len(t),)).

    ``design(t)[r, first[r] + q] == values[r, q]``; memory and time linear in len(t) whatever
    the number of knots (local Cox-de Boor recursion, derivative from the degree-1 lower basis).
    """
    t = np.clip(np.asarray(t, dtype=float), breaks[0], breaks[-1])
    knots = full_knots(breaks, degree)
    n = len(knots) - degree - 1
    span = np.clip(np.searchsorted(knots, t, side="right") - 1, degree, n - 1)
    order = degree - deriv
    N = _local_basis(t, knots, span, order)  # functions span-order .. span
    for p in range(order + 1, degree + 1):  # derivative recursion up to `degree`
        # B'_{k,p} = p (B_{k,p-1} / (t_{k+p} - t_k) - B_{k+1,p-1} / (t_{k+p+1} - t_{k+1}))
        k = span[:, None] - p + np.arange(p + 1)[None, :]  # functions span-p .. span
        lo = np.concatenate([np.zeros((len(t), 1)), N], axis=1)  # B_{k,p-1}
        hi = np.concatenate([N, np.zeros((len(t), 1))], axis=1)  # B_{k+1,p-1}
        d1 = _inv(knots[k + p] - knots[k])
        d2 = _inv(knots[k + p + 1] - knots[k + 1])
        N = p * (lo * d1 - hi * d2)
    return N, (span - degree).astype(np.int64)


def _local_basis(t, knots, span, p):
    """Nonzero B-splines of degree p at t (functions span-p .. span), (len(t), p + 1)."""
    m = len(t)
    N = np.zeros((m, p + 1))
    N[:, 0] = 1.0
    left = np.zeros((m, p + 1))
    right = np.zeros((m, p + 1))
    for j in range(1, p + 1):
        left[:, j] = t - knots[span + 1 - j]
        right[:, j] = knots[span + j] - t
        saved = np.zeros(m)
        for r in range(j):
            den = right[:, r + 1] + left[:, j - r]
            temp = N[:, r] * _inv(den)
            N[:, r] = saved + right[:, r + 1] * temp
            saved = left[:, j - r] * temp
        N[:, j] = saved
    return N


def fit_banded(t: np.ndarray, y: np.ndarray, breaks: np.ndarray) -> np.ndarray:
    """Least-squares spline coefficients of y(t), through banded normal equations
    (the same solution as lstsq on :func:`design`, in memory linear in len(t))."""
    from scipy.linalg import solveh_banded

    vals, first = banded(t, breaks)
    K = n_coefficients(breaks)
    w = DEGREE + 1
    ab = np.zeros((w, K))  # upper form: ab[w - 1 + i - j, j] = A[i, j], i <= j
    rhs = np.zeros(K)
    for a in range(w):
        np.add.at(rhs, first + a, vals[:, a] * y)
        for b in range(a, w):
            np.add.at(ab[w - 1 - (b - a)], first + b, vals[:, a] * vals[:, b])
    return solveh_banded(ab, rhs)


def _inv(d: np.ndarray) -> np.ndarray:
    out = np.zeros_like(d)
    np.divide(1.0, d, out=out, where=d > 0)
    return out
