"""The Jacobian of a long recording in normal form: J^T J, J^T r and J^T V accumulated over
time chunks (:class:`NormalJacobian`), the pseudo-inverse factor of a normal matrix
(:func:`pinv_factor`), and the float64 products with float32-stored columns (:func:`tdot`).
"""

from __future__ import annotations

import numpy as np

from ..fit._rowchunks import RowChunks


def normal_of(J, V=None):
    """(J^T J, J^T V) of a dense Jacobian or of its :class:`RowChunks` (V (S,) or (S, m))."""
    if isinstance(J, RowChunks):
        if V is None:
            return J.normal(np.zeros((J.n_rows, 0)))[0], None
        A, g = J.normal(V if np.ndim(V) == 2 else np.asarray(V)[:, None])
        return A, (g if np.ndim(V) == 2 else g[:, 0])
    return J.T @ J, (None if V is None else J.T @ V)


def pinv_factor(A, rcond: float) -> np.ndarray:
    """M with M M^T the pseudo-inverse of A (column-scaled eigen-decomposition, eigenvalues
    below rcond times the largest dropped): the normal-form twin of the `_basis` SVD."""
    d = np.sqrt(np.maximum(np.diag(A), 0.0))
    d = np.where(d > 0, d, 1.0)
    w, V = np.linalg.eigh(A / np.outer(d, d))
    keep = w > rcond * w.max()
    w, V = w[keep][::-1], V[:, keep][:, ::-1]
    return (V / np.sqrt(w)) / d[:, None]


class NormalJacobian:
    """The engine's Jacobian [base block | difference columns] of a long recording in
    normal form: A = J^T J and J^T r, and J^T V of any residual-shaped columns V by a pass
    over the time chunks (:meth:`Jt`). The base block's rows come from `chunks`; `F` holds
    the difference columns (S, m) of the coupled parameters (they replace the base
    columns at `coupled_pos`) and of the extra parameters (appended)."""

    def __init__(self, chunks: RowChunks, F: np.ndarray, coupled_pos: list, r: np.ndarray):
        self.chunks, self.F, self.r = chunks, F, r
        n_cur = chunks.n_par
        nc = len(coupled_pos)
        self.n = n_cur + F.shape[1] - nc
        keep = np.ones(n_cur, bool)
        keep[coupled_pos] = False
        self.base_cols = np.flatnonzero(keep)  # full column j = base column j there
        # full column index of each F column
        self.f_cols = np.r_[np.asarray(coupled_pos, int), n_cur + np.arange(F.shape[1] - nc)]
        Ab, (JbF, Jbr) = chunks.normal([F, r[:, None]])
        JbW = np.hstack([JbF, Jbr])
        A = np.zeros((self.n, self.n))
        b, f = self.base_cols, self.f_cols
        A[np.ix_(b, b)] = Ab[np.ix_(b, b)]
        A[np.ix_(b, f)] = JbW[b, :F.shape[1]]
        A[np.ix_(f, b)] = JbW[b, :F.shape[1]].T
        A[np.ix_(f, f)] = tdot(F, F)
        self.A = A
        self.g = self._assemble(JbW[:, F.shape[1]:], tdot(F, r[:, None]))[:, 0]  # J^T r
        self.shape = (len(r), self.n)

    def normal(self) -> tuple:
        """(J^T J, J^T r)."""
        return self.A, self.g

    def release(self) -> None:
        """Drop the time chunks and the difference columns (memory linear in the samples),
        keeping J^T J and J^T r; :meth:`Jt` and :meth:`suffix_projections` are gone."""
        self.chunks = self.F = None

    def _assemble(self, JbV, FtV):
        out = np.zeros((self.n, JbV.shape[1]))
        out[self.base_cols] = JbV[self.base_cols]
        out[self.f_cols] = FtV
        return out

    def Jt(self, V) -> np.ndarray:
        """J^T V for V (S, m) (or (S,), or a list of (S, m_i): J^T of their columns side
        by side, without stacking them into one more (S, sum m_i) array)."""
        if isinstance(V, list):
            Vs = [np.asarray(v).reshape(len(v), -1) for v in V]
            _, JbVs = self.chunks.normal(Vs, with_A=False)
            return np.hstack([self._assemble(JbV, tdot(self.F, v)) for JbV, v in zip(JbVs, Vs)])
        V = np.asarray(V)  # chunks.normal and tdot cast block by block
        one = V.ndim == 1
        V2 = V[:, None] if one else V
        _, JbV = self.chunks.normal(V2, with_A=False)
        out = self._assemble(JbV, tdot(self.F, V2))
        return out[:, 0] if one else out

    def suffix_projections(self, d, t, tu, M) -> np.ndarray:
        """|M^T J^T (d 1[t >= tu_k])|^2 for every time tu_k (sorted unique times of the
        samples), streamed backwards over the time chunks (the chunks hold disjoint,
        increasing time ranges); (len(tu),)."""
        Mb, Mf = M[self.base_cols], M[self.f_cols]
        fi = np.searchsorted(tu, t)
        nf = len(tu)
        # the difference columns' part: per-frame sums of F d (small), projected per chunk
        # (a column at a time: F d and its sorted copy would be two more (S, m) arrays)
        Zf = np.zeros((nf, self.F.shape[1]))
        for j in range(self.F.shape[1]):
            Zf[:, j] = np.bincount(fi, weights=self.F[:, j] * d, minlength=nf)
        out = np.zeros(nf)
        carry = np.zeros(M.shape[1])
        ch = self.chunks
        done = nf
        # the base block's rows from the chunks' factors, J_c = U P^T (kinematic columns)
        # + L (columns pos): per-frame sums of d U and d L, then through M's rows (a
        # coupled column's rows zero: F holds it); R (2 + w) per chunk, not R p
        Mfull = np.zeros((ch.n_par, M.shape[1]))
        Mfull[self.base_cols] = Mb
        Mkin = Mfull[ch._kin_pos]
        for c in range(ch.n_chunks - 1, -1, -1):
            got = ch.factors(c)
            if got is None:
                continue
            rows, U, P, L, pos = got
            f = fi[rows]
            lo = int(f.min())
            if f.max() >= done:
                raise RuntimeError("time chunks out of order")
            Zc = Zf[lo:done] @ Mf
            dr = d[rows, None]
            Zc += _frame_sums(f - lo, np.hstack([U * dr, L * dr]), done - lo) @ np.vstack(
                [P.T @ Mkin, Mfull[pos]])
            S = np.cumsum(Zc[::-1], 0)[::-1] + carry
            out[lo:done] = np.sum(S * S, 1)
            carry = S[0]
            done = lo
        if done > 0:  # frames before the first chunk's rows: the difference columns only
            S = np.cumsum((Zf[:done] @ Mf)[::-1], 0)[::-1] + carry
            out[:done] = np.sum(S * S, 1)
        return out


#: rows per float64 block of :func:`tdot`
TDOT_ROWS = 131_072


def tdot(X, Y) -> np.ndarray:
    """X^T Y in float64 for X (S, m) and Y (S,) or (S, k) of float32 or float64 storage:
    summed over blocks of TDOT_ROWS rows, each cast to float64 (no float64 copy of a
    whole float32 array)."""
    X = np.asarray(X)
    Y = np.asarray(Y)
    if X.dtype == np.float64 and Y.dtype == np.float64:
        return X.T @ Y
    out = np.zeros((X.shape[1],) + Y.shape[1:])
    for i in range(0, X.shape[0], TDOT_ROWS):
        out += X[i:i + TDOT_ROWS].astype(np.float64).T @ Y[i:i + TDOT_ROWS].astype(np.float64)
    return out


def _frame_sums(fi, X, nf):
    """Sums of the rows of X per frame index fi, (nf, X.shape[1])."""
    out = np.zeros((nf, X.shape[1]))
    if len(fi) == 0:
        return out
    order = np.argsort(fi, kind="stable")
    fs = fi[order]
    starts = np.flatnonzero(np.r_[True, fs[1:] != fs[:-1]])
    out[fs[starts]] = np.add.reduceat(X[order], starts, axis=0)
    return out
