"""A family term as a linear extension of a converged fit, and the catalog's criterion.

At the least-squares minimum of the fit (weighted residuals r, Jacobian J) a term that adds
columns B (d residual / d coefficient, weighted) is fitted jointly with every parameter of
the fit by one Gauss-Newton step of the extended model: with Q an orthonormal basis of J's
columns, B_perp = B - Q Q^T B carries what the fit cannot absorb, the coefficients are
c = -B_perp^+ r and chi^2 falls by |B_perp c|^2. That is exact for a term linear in its
coefficients (a shape at a fixed frequency); a free frequency is scanned and refined around
its seed (:func:`best_frequency`). The coefficients' covariance (B_perp^T B_perp)^-1 is the
marginal one: it carries the fit's own parameters' uncertainty, and the fit's parameters'
covariance gains K Cov(c) K^T, K = J^+ B (the block inverse), which is how the term's
uncertainty reaches the slip (:mod:`._extend`).

The criterion is the catalog's (fitlug.explain): Delta BIC = -Delta chi^2 + k ln N below
-10 (a free frequency counts as a parameter), and a strong misfit must lose at least 30 %
of its excess chi^2.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .._criterion import BIC_THRESHOLD, MIN_SHARE_REMOVED  # the catalog's


@dataclass
class Fitted:
    """One linear term fitted at the minimum of a fit."""

    B: np.ndarray  # (S, m) weighted columns
    c: np.ndarray  # coefficients
    cov: np.ndarray  # their marginal covariance
    dchi2: float  # chi^2 removed
    k: int  # parameters counted by the criterion (coefficients + a free frequency)
    delta_bic: float
    #: an exact term's own parameters after its refit (:func:`._exact.refine`), by the
    #: index of its term among the kept ones: {i: free}
    free: dict = field(default_factory=dict)


class Projector:
    """The fit's Jacobian J (valid rows, columns scaled to unit norm) through its small
    normal matrix: every product a term needs is J^T B, B^T B and J^T r (k x m, m x m),
    so nothing of the long matrices is factorised (a frequency scan calls :meth:`gain`
    a hundred times). Pseudo-inverses drop directions below 1e-7 of the largest singular
    value (the columns are scaled, so only true degeneracies fall there)."""

    def __init__(self, J: np.ndarray, r: np.ndarray, valid: np.ndarray):
        self.valid = valid
        Jv = J[valid]
        d = np.sqrt(np.sum(Jv * Jv, 0))
        self.d = np.where(d > 0, d, 1.0)
        self.Js = Jv / self.d
        self.Hinv = _pinv(self.Js.T @ self.Js)
        self.r = r[valid]
        self.Jr = self.Js.T @ self.r
        self.n = int(valid.sum())
        self.lnN = math.log(max(self.n, 2))

    def with_residuals(self, r: np.ndarray) -> "Projector":
        """The same Jacobian with other residuals r (full rows)."""
        out = object.__new__(Projector)
        out.__dict__.update(self.__dict__)
        out.r = r[self.valid]
        out.Jr = self.Js.T @ out.r
        return out

    def with_columns(self, B: np.ndarray, r_new: np.ndarray) -> "Projector":
        """The projector of the fit extended by columns B (full rows), residuals r_new."""
        return Projector(np.hstack([self._full(self.Js * self.d), B]), r_new, self.valid)

    def _full(self, Av: np.ndarray) -> np.ndarray:
        out = np.zeros((len(self.valid), Av.shape[1]))
        out[self.valid] = Av
        return out

    def _normal(self, B: np.ndarray):
        """(G, g, JB): the normal matrix and gradient of B's coefficients with the fit's
        parameters eliminated (B_perp^T B_perp, B_perp^T r), and J_s^T B."""
        Bv = B[self.valid]
        rows = np.flatnonzero(np.any(Bv != 0, 1))
        if len(rows) > 0.5 * len(Bv):  # most rows: no copy of the long matrix
            Bs, Js, rs = Bv, self.Js, self.r
        else:
            Bs, Js, rs = Bv[rows], self.Js[rows], self.r[rows]
        JB = Js.T @ Bs
        HJB = self.Hinv @ JB
        G = Bs.T @ Bs - JB.T @ HJB
        g = Bs.T @ rs - HJB.T @ self.Jr
        return 0.5 * (G + G.T), g, JB

    def gain(self, B: np.ndarray) -> float:
        """chi^2 removed by columns B (full rows), the fit's parameters free."""
        G, g, _ = self._normal(B)
        return float(g @ _pinv(G) @ g)

    def fit(self, B: np.ndarray, n_extra: int = 0, rank: bool = False) -> Fitted:
        """The term of columns B fitted jointly with the fit (see the module). `rank`: the
        criterion counts the directions the data see (the rank of B_perp), not B's columns
        (a warp or a time map whose lowest orders the fit's own parameters already are)."""
        G, g, _ = self._normal(B)
        cov, n_seen = _pinv(G, with_rank=True) if rank else (_pinv(G), B.shape[1])
        c = -cov @ g
        dchi2 = float(g @ cov @ g)
        k = (n_seen if rank else B.shape[1]) + n_extra
        return Fitted(B=B, c=c, cov=cov, dchi2=dchi2, k=k,
                      delta_bic=-dchi2 + k * self.lnN)

    def solve(self, Y: np.ndarray) -> np.ndarray:
        """J^+ Y for full-row Y (S,) or (S, m), in the fit's parameter units."""
        Yv = Y[self.valid]
        out = self.Hinv @ (self.Js.T @ Yv)
        return out / (self.d if out.ndim == 1 else self.d[:, None])

    def moved(self, B: np.ndarray, c: np.ndarray) -> np.ndarray:
        """The residuals' change when the term (B, c) and the fit's parameters move together:
        (I - J J^+)(r + B c) - r, full rows."""
        out = np.zeros(len(self.valid))
        y = self.r + B[self.valid] @ c
        out[self.valid] = y - self.Js @ (self.Hinv @ (self.Js.T @ y)) - self.r
        return out


def _pinv(A: np.ndarray, with_rank: bool = False):
    """Pseudo-inverse of a symmetric positive semi-definite matrix (diagonal scaled first;
    eigenvalues below 1e-14 of the largest dropped), and with `with_rank` its rank."""
    out = np.zeros_like(A)
    live = np.flatnonzero(np.diag(A) > 1e-300)  # a column no datum touches: no direction
    if live.size == 0:
        return (out, 0) if with_rank else out
    As = A[np.ix_(live, live)]
    d = np.sqrt(np.diag(As))
    w, V = np.linalg.eigh(As / np.outer(d, d))
    # counting the rank: a direction the fit's own parameters all but hold (a gauge, or
    # one that only the slip's small dependence on the acceleration breaks) is left out
    # below 1e-7 of the largest (else it takes a coefficient far past where the linear
    # step holds), not only at round-off
    keep = w > (1e-7 if with_rank else 1e-14) * max(w.max(), 1e-300)
    out[np.ix_(live, live)] = (V[:, keep] / w[keep]) @ V[:, keep].T / np.outer(d, d)
    return (out, int(keep.sum())) if with_rank else out


def best_frequency(proj: Projector, columns, f0: float, span: float, T: float,
                   max_grid: int = 301):
    """The frequency in [f0 - span, f0 + span] (Hz, f > 0) whose columns `columns(f)`
    remove the most chi^2: a grid scan in steps of 0.2 / T (T: the recording's duration,
    s; a fifth of the spectral resolution), then golden-section refinement between the
    best point's neighbours. Returns (f, gain)."""
    lo = max(f0 - span, 1e-3)
    n_grid = int(min(max(2 * span * T / 0.2, 11), max_grid)) | 1
    grid = np.linspace(lo, f0 + span, n_grid)
    gains = np.array([proj.gain(columns(f)) for f in grid])
    i = int(np.argmax(gains))
    a, b = grid[max(i - 1, 0)], grid[min(i + 1, n_grid - 1)]
    g = (math.sqrt(5) - 1) / 2
    x1, x2 = b - g * (b - a), a + g * (b - a)
    f1, f2 = proj.gain(columns(x1)), proj.gain(columns(x2))
    for _ in range(18):
        if f1 > f2:
            b, x2, f2 = x2, x1, f1
            x1 = b - g * (b - a)
            f1 = proj.gain(columns(x1))
        else:
            a, x1, f1 = x1, x2, f2
            x2 = a + g * (b - a)
            f2 = proj.gain(columns(x2))
    best = max(((x1, f1), (x2, f2), (grid[i], gains[i])), key=lambda q: q[1])
    return float(best[0]), float(best[1])


def distinct(seeds, rel: float, most: int = 3) -> list:
    """The finite frequencies of `seeds`, in order, each more than `rel` (relative) from
    every one kept before it; at most `most`."""
    seeds = [f for f in seeds if np.isfinite(f)]
    return [f for i, f in enumerate(seeds)
            if all(abs(f - g) > rel * g for g in seeds[:i])][:most]


def best_of_seeds(proj: Projector, columns, seeds, rel_span: float, T: float) -> float:
    """The frequency that :func:`best_frequency` finds around each seed f0 (within
    max(2 / T, rel_span f0)) that removes the most chi^2."""
    return max((best_frequency(proj, columns, f0, max(2.0 / T, rel_span * f0), T)
                for f0 in seeds), key=lambda q: q[1])[0]


def peak_frequency(t: np.ndarray, r: np.ndarray, f_max: float, T: float) -> float:
    """The strongest line of series r(t) (irregular samples allowed) between 2/T and
    f_max: the periodogram of a sine-cosine fit on a grid of 1/(4T)."""
    f = np.arange(2.0 / T, f_max, 0.25 / T)
    if len(t) < 8 or f.size == 0:
        return float("nan")
    p = np.zeros(f.size)
    for i0 in range(0, f.size, 256):
        fi = f[i0:i0 + 256]
        ph = 2 * np.pi * np.outer(t, fi)
        p[i0:i0 + 256] = np.abs(r @ np.exp(-1j * ph)) ** 2
    return float(f[int(np.argmax(p))])


def chooses(fitted: Fitted, excess: float, strong: bool, c_corr: float = 1.0) -> str | None:
    """None when the term earns its place by the catalog's criterion, else why not.
    `c_corr`: the correlation of the residuals with the term in (explain._correlated):
    the chi^2 it removes is deflated by it first (a tracker's correlated error)."""
    if fitted.delta_bic >= BIC_THRESHOLD:
        return f"delta BIC {fitted.delta_bic:.1f} is not below {BIC_THRESHOLD:g}"
    dbic_c = fitted.delta_bic + fitted.dchi2 * (1.0 - 1.0 / max(c_corr, 1.0))
    if dbic_c >= BIC_THRESHOLD:
        return (f"delta BIC {dbic_c:.1f} with the chi2 it removes deflated by the "
                f"residuals' correlation ({c_corr:.3g}, what a tracker's correlated error "
                f"makes) is not below {BIC_THRESHOLD:g}")
    removed = fitted.dchi2 / max(excess, fitted.dchi2) if fitted.dchi2 > 0 else 0.0
    if strong and removed < MIN_SHARE_REMOVED:
        return (f"removes {100 * removed:.0f} % of the excess chi2 (needs "
                f"{100 * MIN_SHARE_REMOVED:.0f} %)")
    return None
