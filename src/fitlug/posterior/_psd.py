"""Batched pseudo-inverse solves of symmetric positive semi-definite matrices (the exact
marginal's nuisance step, :mod:`._marginal`)."""

from __future__ import annotations

import numpy as np


def _eig_solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """A^+ b for symmetric PSD A (m, n, n), b (m, n): eigenvalues below 1e-12 of the
    largest do not act (zero, not inverted)."""
    lam, V = np.linalg.eigh(A)
    top = lam.max(axis=1, keepdims=True)
    inv = np.where(lam > 1e-12 * top, 1.0 / np.where(lam > 0, lam, 1.0), 0.0)
    y = inv * np.einsum("mkj,mk->mj", V, b)  # V^T b, scaled by the inverse
    return np.einsum("mij,mj->mi", V, y)


def _psd_solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """:func:`_eig_solve`'s A^+ b, by Cholesky where that is certain to be the same: where
    trace(A) trace(A^-1) < 1e12, every eigenvalue is above 1e-12 of the largest (lambda_min
    >= 1 / trace(A^-1), lambda_max <= trace(A)), so nothing is cut and A^+ = A^-1;
    trace(A^-1) = |L^-1|_F^2. The other matrices (not positive definite, or near the cut)
    go through the eigendecomposition. A batch of eigh was ~70 % of an exact-marginal
    evaluation (issue 43: the exact posterior's steps, the linearity check)."""
    m = len(A)
    out = np.empty_like(b)
    ok = np.zeros(m, bool)
    try:
        L = np.linalg.cholesky(A)
        good = np.ones(m, bool)
    except np.linalg.LinAlgError:  # one matrix or more is not positive definite
        L, good = np.zeros_like(A), np.zeros(m, bool)
        for i in range(m):
            try:
                L[i] = np.linalg.cholesky(A[i])
                good[i] = True
            except np.linalg.LinAlgError:
                pass
    if good.any():
        with np.errstate(all="ignore"):
            Li = np.linalg.inv(L[good])
            tr_inv = np.einsum("mij,mij->m", Li, Li)
            tr = np.trace(A[good], axis1=1, axis2=2)
            cert = np.isfinite(tr_inv) & (tr * tr_inv < 1e12)
            x = np.einsum("mji,mj->mi", Li, np.einsum("mij,mj->mi", Li, b[good]))
        idx = np.flatnonzero(good)[cert]
        out[idx] = x[cert]
        ok[idx] = True
    if not ok.all():
        out[~ok] = _eig_solve(A[~ok], b[~ok])
    return out
