"""The exact Jacobian of a long recording, time chunk by time chunk (:class:`RowChunks`):
its rows, matrix-vector products and normal equations without the dense Jacobian; the
explanation engine's and the posterior's long-recording path.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ._chunk_prep import _prepare_jit, block_shared
from ._chunks import ChunkPlan, TimeBlocks, blocked_residuals, chunk_plan, time_blocks, trim_heap
from ._normal import _chunk_jit, _contract_jit, _factors_jit, _kinematic_positions
from ._residuals import Packing


class RowChunks:
    """The exact Jacobian (:func:`jacobian`'s values) of a chunkable problem, time chunk by
    time chunk: iterating yields (rows, J_rows) in numpy, rows the residual indices and
    J_rows their (len(rows), p) Jacobian rows; memory is one chunk's rows plus what the
    chunks share (linear in the samples). `r` holds the weighted residuals."""

    def __init__(self, flat, fixed: dict, lay, obs: dict, packing: Packing,
                 plan: ChunkPlan | None = None, blocks: TimeBlocks | None | bool = None):
        # long recordings (no plan given): one time block's shared buffers at a time
        # (:func:`time_blocks`; `blocks=False` forces one block)
        if blocks is None and plan is None:
            blocks = time_blocks(lay, obs)
        blocks = blocks or None
        self.flat, self.fixed, self.packing = jnp.asarray(flat), fixed, packing
        if blocks is None:
            plan = chunk_plan(lay) if plan is None else plan
            self._parts = [(lay, obs, plan, None)]
        else:
            self._parts = list(zip(blocks.lays, blocks.obss, blocks.plans, blocks.rows))
        self._cur = (None, None)
        # what the blocks share over the whole grid, once (None: one part, its own)
        self._shared = (None if blocks is None else
                        block_shared(self.flat, fixed, lay, packing, blocks.plans))
        self.n_rows = 2 * (int(lay.lug_t.shape[0]) + int(lay.body_t.shape[0]))
        if blocks is None:
            self._r = np.asarray(self._prep(0)["r"])
        else:  # on first use (a whole model evaluation; callers often hold r already)
            self._r = None
            self._r_args = (lay, obs, blocks)
        self.n_par = int(sum(packing.sizes))
        self._C = int(self._parts[0][2].rows.shape[0])  # chunks per part (one shape)
        self._rows, self._keep = [], []
        for lay_k, _, plan_k, glob in self._parts:
            rows = np.asarray(plan_k.rows)
            keep = np.asarray(plan_k.mask) > 0
            if glob is not None:  # block rows -> rows of the whole recording
                rows = glob[rows]
                keep &= rows >= 0
            self._rows.append(rows)
            self._keep.append(keep)
        self._kin_pos = _kinematic_positions(packing)

    @property
    def r(self) -> np.ndarray:
        """The weighted residuals at `flat` (S,)."""
        if self._r is None:
            lay, obs, blocks = self._r_args
            self._r = blocked_residuals(self.flat, self.fixed, lay, obs, self.packing, blocks)
        return self._r

    def _prep(self, k: int) -> dict:
        """The shared buffers of part k (the last part's are dropped)."""
        if self._cur[0] != k:
            self._cur = (None, None)
            trim_heap()
            lay_k, obs_k, plan_k, _ = self._parts[k]
            self._cur = (k, _prepare_jit(self.flat, self.fixed, lay_k, obs_k, self.packing,
                                         plan_k, None if self._shared is None
                                         else self._shared[k]))
        return self._cur[1]

    @property
    def plan(self) -> ChunkPlan:
        return self._parts[0][2]

    @property
    def n_chunks(self) -> int:
        return self._C * len(self._parts)

    def chunk(self, c: int):
        """(rows, J_rows) of chunk c, or None when it holds no rows."""
        k, j = divmod(c, self._C)
        keep = self._keep[k][j]
        if not keep.any():
            return None
        lay_k, _, pl, _ = self._parts[k]
        prep = self._prep(k)
        Jc = _chunk_jit(prep, lay_k, self.packing, pl.W, pl.rows[j], pl.mask[j], pl.ws[j],
                        prep["preX"][j], prep["preP"][j])
        return self._rows[k][j][keep], np.asarray(Jc)[keep]

    def __iter__(self):
        for c in range(self.n_chunks):
            got = self.chunk(c)
            if got is not None:
                yield got

    def matvec(self, x) -> np.ndarray:
        """J x, (S,)."""
        out = np.zeros(self.n_rows)
        for rows, Jc in self:
            out[rows] = Jc @ x
        return out

    def factors(self, c: int):
        """Chunk c as (rows, U, P, L, pos): its rows are U P^T on the kinematic columns
        plus L on the columns pos (see :func:`normal_equations`); None without rows."""
        k, j = divmod(c, self._C)
        keep = self._keep[k][j]
        if not keep.any():
            return None
        lay_k, _, pl, _ = self._parts[k]
        prep = self._prep(k)
        U, P, L, pos = _factors_jit(prep, lay_k, self.packing, pl, pl.rows[j], pl.mask[j],
                                    pl.ws[j], pl.cb[j], prep["preX"][j], prep["preP"][j])
        return (self._rows[k][j][keep], np.asarray(U)[keep], np.asarray(P),
                np.asarray(L)[keep], np.asarray(pos))

    def normal(self, V=None, with_A: bool = True):
        """(J^T J, J^T V) with V (S, m) (or None: J^T r; or a list of such: a list of
        J^T V_i); J^T J is None without with_A. From the chunks' factors (R w^2 + nk^2 per
        chunk, not R p^2), summed in one compiled pass per time block (:func:`contract`)
        with at most NORMAL_ENTRIES of V's block rows at a time."""
        A = np.zeros((self.n_par, self.n_par)) if with_A else None
        V = self.r[:, None] if V is None else V
        Vs = V if isinstance(V, list) else [V]  # several (S, m_i): J^T of each, no stacking
        # float32 columns (the explanation's stored differences) stay float32 here: each
        # block's rows are cast to float64 below, not the whole array at once
        Vs = [np.asarray(v) for v in Vs]
        Vs = [v if v.dtype in (np.float32, np.float64) else v.astype(float) for v in Vs]
        gs = [np.zeros((self.n_par,) + v.shape[1:]) for v in Vs]
        for k, (lay_k, _, plan_k, glob) in enumerate(self._parts):
            prep = self._prep(k)
            n_rows = int(prep["r"].shape[0])
            real = None if glob is None else glob >= 0
            want_A = with_A
            for g, v in zip(gs, Vs):
                m = v.shape[1] if v.ndim == 2 else 1
                v2 = v.reshape(len(v), m)
                step = max(1, NORMAL_ENTRIES // max(n_rows, 1))
                for j0 in range(0, m, step):
                    cols = v2[:, j0:j0 + step]
                    if glob is None:
                        vb = np.ascontiguousarray(cols.T, dtype=np.float64)
                    else:  # block rows; its padding rows (zero weight) get zeros
                        vb = np.zeros((cols.shape[1], n_rows))
                        vb[:, real] = cols[glob[real]].T
                    Ak, gk = _contract_jit(prep, lay_k, self.packing, plan_k, jnp.asarray(vb),
                                           want_A)
                    if want_A:
                        A += np.asarray(Ak)
                        want_A = False
                    g.reshape(self.n_par, m)[:, j0:j0 + step] += np.asarray(gk).T
            if want_A:  # no V at all
                Ak, _ = _contract_jit(prep, lay_k, self.packing, plan_k,
                                      jnp.zeros((1, n_rows)), True)
                A += np.asarray(Ak)
        return A, (gs if isinstance(V, list) else gs[0])


#: V entries (columns x a block's rows) RowChunks.normal hands to one compiled pass: 16 MB
NORMAL_ENTRIES = 2_000_000
