"""One compiled model for every candidate: the base model with ALL catalog effects active.

Compiling the fitter once per effect set costs seconds per candidate; here every
candidate is the same all-effects model (MODEL.md §3: an effect at its identity values
is no effect) with only its own parameters moved away from identity. What differs
between candidates is which parameters are free, so nothing is compiled twice.

The fit is Levenberg-Marquardt with exact residuals of the all-effects model. Its
Jacobian has two blocks: the parameters the starting fit had free, differentiated
exactly (forward mode) under the starting fit's own model, and the added effect
parameters by central differences of the all-effects model. The first block leaves
out the added effects' small change to the base derivatives (order epsilon of the
effect), so convergence is linear instead of quadratic for large effects; the
minimum it converges to is the same, since the residuals are exact. Each step tries
several damping values at once (one batched model evaluation).

Long recordings (the dense Jacobian above CHUNKED_ENTRIES entries, a base model the
chunked normal equations take: :func:`fitlug.fit._lsq.chunkable`) never form the
Jacobian: :meth:`Engine.jacobian` returns a :class:`NormalJacobian`, which holds J^T J
and J^T r accumulated over time chunks of the base block's rows
(:class:`fitlug.fit._lsq.RowChunks`) and the difference columns; the fit, the screening
(:mod:`._candidates`), the final polish, the robust errors and the systematics check use
it through J^T J and J^T v only. Same values as the dense path to rounding
(tests/test_scale.py); memory linear in the samples.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from .. import _jaxconfig  # noqa: F401
from ..fit import residuals
from ..fit._chunks import BLOCK_ENTRIES, chunkable, nodes_batch, time_blocks, trim_heap
from ..fit._lsq import LARGE_ENTRIES
from ..fit._residuals import Packing, jacobian
from ..fit._rowchunks import RowChunks
from ..model import CATALOG, param_names

COUPLED = ("s0", "beta", "R", "D", "e", "x_off", "y_off")
CHUNK = 8  # model evaluations per batched call (fixed, so one compilation serves all)
_BASE_STEPS = {"s0": 1e-5, "beta": 1e-9, "R": 1e-4, "D": 1e-4, "e": 1e-4, "x_off": 1e-4,
               "y_off": 1e-4}
#: an LM step of the search that gains less (in chi^2) than this, and under a quarter of
#: the step before, ends the fit (:meth:`Engine.fit`)
SETTLED_GAIN = 0.5
_LAMBDAS = np.array([0.0, 1e-6, 1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0])
#: dense Jacobian entries above which the engine works on chunked normal equations
CHUNKED_ENTRIES = LARGE_ENTRIES
#: residual entries per batched model evaluation (the batch shrinks on long recordings,
#: or, where time blocks apply, the samples' part runs in blocks of BLOCK_ENTRIES / CHUNK)
BATCH_ENTRIES = 4_000_000
#: residual entries a batch's output may hold on the blocked path (128 MB)
RESULT_ENTRIES = 16_000_000


def use_chunks(lay, packing, params) -> bool:
    """Whether a problem's Jacobian is handled in time chunks rather than formed."""
    n_res = 2 * (lay.lug_t.shape[0] + lay.body_t.shape[0])
    return (n_res * sum(packing.sizes) > CHUNKED_ENTRIES
            and chunkable(params, lay, packing))


def jacobian_of(flat, fixed, packing, lay, obs):
    """The dense Jacobian (numpy) of a problem, or its :class:`RowChunks` when long."""
    if use_chunks(lay, packing, {**fixed, **packing.unpack(jnp.asarray(flat), {})}):
        return RowChunks(jnp.asarray(flat), fixed, lay, obs, packing)
    return np.asarray(_jac_block(jnp.asarray(flat), fixed, packing, lay, obs))


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


#: storage of the long recordings' difference columns (the engine's coupled and extra
#: columns F, the screened alternatives' columns C): float32, which halves their memory,
#: the largest share of an explanation's peak on 100 000 frames (9 columns of 2.8 M rows:
#: 200 -> 100 MB). Each difference is computed in float64 and rounded once when stored
#: (2-3e-8 relative: more than the central differences' own error on the base columns,
#: 1e-9 to 1e-11), and every product with them sums in float64 (:func:`tdot`). They only
#: steer the search (its screening and LM steps, each step judged on exact residuals);
#: the final fit's polish and errors use the exact Jacobian. Measured on a 30 000-frame
#: belt-sag recording against float64 storage (benchmarks/results/2026-11-26c): both
#: rounds' screened delta chi^2 of every catalog effect within 7e-5 relative (1e-4 in
#: chi^2), their starts within 4e-5, the sag's LM fit within 4e-6 in chi^2 of 8.4e5.
STORE = np.float32
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


@partial(jax.jit, static_argnames=("packing",))
def _res_batch(flats, packing, lay, obs):
    return jax.vmap(lambda f: residuals(packing.unpack(f, {}), lay, obs))(flats)


@partial(jax.jit, static_argnames=("packing",))
def _res_from_nodes(flats, nodes, packing, lay, obs):
    """:func:`_res_batch` of the samples of `lay` (a time block) from the node values."""
    from ..fit._residuals import _residuals_from_nodes

    return jax.vmap(lambda f, *nd: _residuals_from_nodes(f, {}, lay, obs, packing, nd))(
        flats, *nodes)


@partial(jax.jit, static_argnames=("packing",))
def _jac_block(flat, fixed, packing, lay, obs):
    return jacobian(flat, fixed, lay, obs, packing)  # structured: same values as jacfwd


@dataclass
class LMResult:
    theta: np.ndarray  # all-effects parameter vector
    r: np.ndarray  # weighted residuals
    chi2: float
    iterations: int
    converged: bool


class Engine:
    """Residuals, Jacobians and fits of any effect set on one recording.

    `res`: the fit explanation starts from (its model and free parameters form the base
    block). Parameter vectors `theta` are in the all-effects packing (`self.names`).
    """

    def __init__(self, res):
        self.res = res
        prob = res.problem
        self.prob_all, p_all = prob.with_effects(tuple(CATALOG), res.params)
        self.lay_all = self.prob_all.lay
        self.obs = prob.obs
        self.packing = Packing.of(p_all, param_names(self.lay_all))
        self.theta0 = np.asarray(self.packing.pack(p_all))
        self.slices = self.packing.slices()
        self.n_body = prob.lay.n_body
        self.n_data = prob.n_valid
        # base block: the starting fit's free parameters under its own model
        self.cur_packing = res.packing
        self.cur_fixed_names = [k for k in res.params if k not in res.packing.names]
        self.cur_idx = np.concatenate([np.arange(self.slices[k].start, self.slices[k].stop)
                                       for k in res.packing.names])
        self.cur_positions = {k: sl.start for k, sl in res.packing.slices().items()
                              if sl.stop - sl.start == 1}
        self.evaluations = 0
        n_res = 2 * (self.obs["lug_w"].shape[0] + self.obs["body_w"].shape[0])
        self.n_res = n_res
        self.batch = int(max(1, min(CHUNK, BATCH_ENTRIES // max(n_res, 1))))
        self.blocks = None
        if self.batch < CHUNK:
            # long recordings: the batch stays CHUNK wide (the integration's sequential
            # scan over the grid costs about as much for one lane as for eight) as long as
            # its residual vectors stay under RESULT_ENTRIES; the samples' part of the
            # model, whose temporaries grow with the samples, runs by time blocks
            blocks = time_blocks(self.lay_all, self.obs, max_rows=BLOCK_ENTRIES // CHUNK,
                                 plans=False)
            if blocks is not None:
                self.blocks = blocks
                self.batch = int(max(1, min(CHUNK, RESULT_ENTRIES // max(n_res, 1))))
        self.chunked = use_chunks(prob.lay, res.packing, res.params)
        # the all-effects packing's entries that the starting model lacks (the catalog's
        # effects it does not hold): at their identity values the all-effects model IS the
        # starting model, whose analytic columns are then exact
        self.other_idx = np.concatenate(
            [np.arange(sl.start, sl.stop) for k, sl in self.slices.items()
             if k not in res.params] or [np.zeros(0, int)]).astype(int)

    # ---- parameter bookkeeping -------------------------------------------------------
    def index(self, name: str) -> int:
        sl = self.slices[name]
        if sl.stop - sl.start != 1:
            raise ValueError(f"parameter {name!r} is not a scalar")
        return sl.start

    def get(self, theta, name):
        v = theta[self.slices[name]]
        return float(v[0]) if len(v) == 1 else v

    def with_values(self, theta, values: dict) -> np.ndarray:
        th = np.array(theta, float)
        for k, v in values.items():
            th[self.slices[k]] = v
        return th

    def params(self, theta) -> dict:
        """Parameter dict (numpy) of a vector."""
        return {k: np.asarray(theta[sl]).reshape(s)
                for (k, sl), s in zip(self.slices.items(), self.packing.shapes)}

    def free_names(self, effect_id: str) -> list[str]:
        """An effect's parameters fitted here (gauge, discrete and unidentifiable ones held)."""
        cls = CATALOG[effect_id]
        names = [k for k in cls.defaults if k not in cls.fixed_in_fit]
        if effect_id == "body_bounce" and self.n_body < 2:
            names.remove("bounce_B")  # MODEL.md §3: B = 0 with one body marker
        return names

    def n_free(self, effect_id: str) -> int:
        return CATALOG[effect_id].n_free(self.n_body)

    def field(self) -> tuple:
        """((x_min, x_max), (y_min, y_max)) of the valid samples, mm: the field of view."""
        xs, ys = [], []
        for role in ("lug", "body"):
            ok = np.asarray(self.obs[role + "_w"]) > 0
            xs.append(np.asarray(self.obs[role + "_x"])[ok])
            ys.append(np.asarray(self.obs[role + "_y"])[ok])
        x, y = np.concatenate(xs), np.concatenate(ys)
        return (float(x.min()), float(x.max())), (float(y.min()), float(y.max()))

    # ---- evaluation --------------------------------------------------------------------
    def residuals(self, thetas) -> np.ndarray:
        """Weighted residuals of the all-effects model, (B, S) for (B, P) vectors."""
        thetas = np.atleast_2d(np.asarray(thetas, float))
        out = np.empty((len(thetas), self.n_res))  # written in place: no stacked copy
        B = self.lanes
        for i in range(0, len(thetas), B):
            blk = thetas[i:i + B]
            pad = np.vstack([blk, np.repeat(blk[-1:], B - len(blk), 0)])
            if self.blocks is None:
                out[i:i + len(blk)] = np.asarray(_res_batch(
                    jnp.asarray(pad), self.packing, self.lay_all, self.obs))[:len(blk)]
            else:
                self._blocked_residuals(jnp.asarray(pad), out[i:i + len(blk)])
            self.evaluations += len(blk)
        return out

    def _blocked_residuals(self, pad, out) -> None:
        """:func:`_res_batch` on a long recording, written into `out` (its first rows):
        one integration for the batch, the samples by time blocks."""
        trim_heap()
        nodes = nodes_batch(pad, {}, self.lay_all, self.packing)
        n = out.shape[0]
        for lay_k, obs_k, rows_k in zip(self.blocks.lays, self.blocks.obss, self.blocks.rows):
            rk = np.asarray(_res_from_nodes(pad, nodes, self.packing, lay_k, obs_k))
            real = rows_k >= 0
            out[:, rows_k[real]] = rk[:n, real]

    def chi2_best(self, thetas) -> tuple:
        """(chi^2 of each vector (inf where not finite), index of the lowest, its residuals),
        one batch of residual vectors in memory at a time."""
        c2 = np.empty(len(thetas))
        k, best = 0, None
        B = self.batch
        for i in range(0, len(thetas), B):
            R = self.residuals(thetas[i:i + B])
            c = np.einsum("ij,ij->i", R, R)
            c2[i:i + len(R)] = np.where(np.isfinite(c), c, np.inf)
            j = i + int(np.argmin(c2[i:i + len(R)]))
            if best is None or c2[j] < c2[k]:
                k, best = j, R[j - i].copy()
        return c2, k, best

    def base_jacobian(self, theta) -> np.ndarray:
        """Jacobian of the starting model wrt its free parameters at theta, (S, n).

        Exact for the starting model; an added effect that maps the time stamps
        (frame_drop) is applied to the sample times first, since a 10 ms shift changes the
        fine speed-spline columns by tens of percent after the lost frame.
        """
        flat, fixed, lay = self._base_problem(theta)
        return np.asarray(_jac_block(flat, fixed, self.cur_packing, lay, self.obs))

    def base_chunks(self, theta) -> RowChunks:
        """:meth:`base_jacobian` as time chunks of rows (long recordings)."""
        flat, fixed, lay = self._base_problem(theta)
        return RowChunks(flat, fixed, lay, self.obs, self.cur_packing)

    def _base_problem(self, theta):
        flat = self._tangent_law(np.asarray(theta[self.cur_idx], float), theta)
        flat = jnp.asarray(flat)
        fixed = {k: jnp.asarray(self.get(theta, k), float) for k in self.cur_fixed_names}
        lay = self.res.problem.lay
        maps = [c for e, c in CATALOG.items()
                if c.time_map is not None and e not in self.res.effects]
        if maps:
            p = {k: jnp.asarray(v) for k, v in self.params(theta).items()}
            lt, bt = lay.lug_t, lay.body_t
            for c in maps:
                lt, bt = c.time_map(p, lt), c.time_map(p, bt)
            lay = lay.with_times(lt, lay.lug_i, bt, lay.body_j)
        return flat, fixed, lay

    def _tangent_law(self, flat, theta):
        """The starting model's linear slip law put on the tangent of an added lug_sliding
        at the steady state (s0 -> S, beta -> B = beta / (1 - z0), z0 = mu s0): its
        columns of the speed spline (and of everything whose change moves the slip
        through the acceleration) then carry the slope ds/da the all-effects model has
        there. Left at the law's own s0 and beta they are 1 - z0 of it, a factor 4 at
        F0/F_max = 0.75, and the fit crawls (issue 32). s0 and beta's own columns are the
        all-effects model's differences anyway (COUPLED)."""
        if "lug_sliding" in self.res.effects or "slide_mu" not in self.slices:
            return flat
        mu = self.get(theta, "slide_mu")
        pos = self.cur_positions
        if mu == 0 or "s0" not in pos or "beta" not in pos:
            return flat
        s0, beta = flat[pos["s0"]], flat[pos["beta"]]
        z = mu * s0
        if not 0 < z < 1:
            return flat
        out = flat.copy()
        out[pos["s0"]] = -np.log1p(-z) / mu
        out[pos["beta"]] = beta / (1.0 - z)
        return out

    @property
    def lanes(self) -> int:
        """Parameter vectors per batched model evaluation. A long recording's blocks write
        residuals and differences into the caller's arrays block by block, so its batch
        keeps CHUNK lanes whatever the results' cap (RESULT_ENTRIES) makes of self.batch,
        which caps the residual vectors held at once elsewhere."""
        return CHUNK if self.blocks is not None else self.batch

    def effects_active(self, theta) -> bool:
        """Whether theta moves any effect the starting model lacks off its identity."""
        i = self.other_idx
        return bool(np.any(np.asarray(theta)[i] != self.theta0[i]))

    def step_of(self, name: str) -> float:
        for cls in CATALOG.values():
            if name in cls.scales:
                return 1e-2 * cls.scales[name]
        return _BASE_STEPS.get(name, 1e-6)

    def fd_columns(self, specs, theta, dtype=np.float64) -> np.ndarray:
        """Central-difference columns (S, len(specs)); spec = (settings dict, param name).

        dtype: the columns' storage (:data:`STORE`: float32 on long recordings; each
        difference is computed in float64 and rounded once when stored)."""
        n_res = len(self.obs["lug_w"]) * 2 + len(self.obs["body_w"]) * 2
        if not specs:
            return np.zeros((n_res, 0), dtype)
        out = np.empty((n_res, len(specs)), dtype)
        per = max(1, self.lanes // 2)  # columns per batched evaluation
        for j0 in range(0, len(specs), per):
            pts, hs = [], []
            for settings, name in specs[j0:j0 + per]:
                th = self.with_values(theta, settings)
                h = self.step_of(name)
                i = self.index(name)
                for sgn in (1.0, -1.0):
                    t2 = th.copy()
                    t2[i] += sgn * h
                    pts.append(t2)
                hs.append(h)
            if self.blocks is not None:
                # long recordings: the differences written block by block, never the
                # batch's (2 per, S) residual vectors (180 MB at 100 000 frames)
                self._blocked_differences(np.array(pts), hs, out[:, j0:j0 + len(hs)])
                continue
            R = self.residuals(np.array(pts))
            for k in range(len(hs)):
                out[:, j0 + k] = (R[2 * k] - R[2 * k + 1]) / (2 * hs[k])
        return out

    def _blocked_differences(self, pts, hs, out) -> None:
        """Central differences (R(+h) - R(-h)) / 2h of the pairs of vectors `pts` (one
        batch) into the columns of `out`, one time block at a time."""
        pad = jnp.asarray(np.vstack([pts, np.repeat(pts[-1:], CHUNK - len(pts), 0)]))
        trim_heap()
        nodes = nodes_batch(pad, {}, self.lay_all, self.packing)
        h2 = 2.0 * np.asarray(hs, float)
        for lay_k, obs_k, rows_k in zip(self.blocks.lays, self.blocks.obss, self.blocks.rows):
            rk = np.asarray(_res_from_nodes(pad, nodes, self.packing, lay_k, obs_k))
            real = rows_k >= 0
            d = (rk[0:2 * len(hs):2] - rk[1:2 * len(hs):2])[:, real] / h2[:, None]
            out[rows_k[real], :] = d.T
        self.evaluations += len(pts)

    def jacobian(self, theta, extra: list[str], r=None):
        """[base block | columns of the `extra` scalar parameters] at theta.

        The base block's scalar physics and geometry columns (s0, beta, R, D, e, x_off,
        y_off) are replaced by differences of the all-effects model: an effect such as
        lug_sliding changes them by tens of percent, the spline and offset columns by
        at most the effect's relative size.

        Where theta holds every effect the starting model lacks at its identity value
        (the first round's screening), the all-effects model is the starting model and its
        analytic columns stay (no differences: on a long recording 7 columns of S doubles,
        160 MB at 100 000 frames).

        Long recordings (self.chunked): a :class:`NormalJacobian` (J^T J, J^T r with `r`
        the residuals at theta, computed when not given), never the dense matrix.
        """
        coupled = [k for k in COUPLED if k in self.cur_packing.names] \
            if self.effects_active(theta) else []
        if self.chunked:
            F = self.fd_columns([({}, k) for k in coupled + list(extra)], theta, STORE)
            if r is None:
                r = self.residuals(theta)[0]
            return NormalJacobian(self.base_chunks(theta), F,
                                  [self.cur_positions[k] for k in coupled], np.asarray(r))
        Jb = np.array(self.base_jacobian(theta))
        cols = self.fd_columns([({}, k) for k in coupled + list(extra)], theta)
        pos = self.cur_positions
        for i, k in enumerate(coupled):
            Jb[:, pos[k]] = cols[:, i]
        return np.hstack([Jb, cols[:, len(coupled):]])

    # ---- fitting -----------------------------------------------------------------------
    def fit(self, theta0, extra: list[str], *, r0=None, max_iter: int = 30,
            tol: float = 1e-3, give_up=None) -> LMResult:
        """Levenberg-Marquardt over the base block plus the scalar parameters `extra`.

        Stops when an accepted step lowers chi^2 by less than `tol` (+1e-10 chi^2), or
        when a nearly linear step (gain within 10 % of the prediction) gains less than 1,
        or when a step gains less than SETTLED_GAIN and under a quarter of the step
        before (the steps converging geometrically: what is left is under a third of the
        last gain, < 0.2 in chi^2, nothing to the search's criterion on Delta BIC; the
        final fit polishes the chosen model anyway), or when `give_up(chi2,
        predicted_decrease)` says the fit cannot win anyway.

        The second-to-last rule matters on long recordings: there the Gauss-Newton model
        of the phase-like parameters (slip, slip law) overestimates the curvature (along
        the first step of a belt sag's fit at 100 000 frames, chi^2's curvature is 0.86
        of J^T J's), each step gains ~1.25 times its prediction and the steps converge
        linearly (~0.1 per step): 8 steps at 100 000 frames against 3 at 30 000, the last
        two for a gain of 0.2 (benchmarks/results/2026-11-26).
        """
        theta = np.array(theta0, float)
        idx = np.r_[self.cur_idx, [self.index(k) for k in extra]].astype(int)
        r = self.residuals(theta)[0] if r0 is None else np.asarray(r0)
        chi2 = float(r @ r)
        converged = False
        it = 0
        lam_scale = 1.0
        stale = True
        prev_gain = np.inf
        for it in range(1, max_iter + 1):
            if stale:
                if self.chunked:
                    # only J^T J and J^T r are needed: the chunks and the difference
                    # columns (tens of doubles per residual) go before the next step's
                    A, g = self.jacobian(theta, extra, r).normal()
                else:
                    J = self.jacobian(theta, extra)
                    A = J.T @ J
                    g = J.T @ r
                d = np.sqrt(np.diag(A))
                d = np.where(d > 0, d, 1.0)
                w, V = np.linalg.eigh(A / np.outer(d, d))
                gs = V.T @ (g / d)
                stale = False
                ok_w = w > 1e-13 * max(w.max(), 1e-300)
                predicted = float(np.sum(gs[ok_w] ** 2 / w[ok_w]))
                if give_up is not None and give_up(chi2, predicted):
                    break
            tol_w = 1e-13 * max(w.max(), 1e-300)
            trials = []
            for lam in _LAMBDAS * lam_scale:
                den = w + lam
                step = -(V @ np.where(den > tol_w, gs / np.where(den > tol_w, den, 1.0), 0.0)) / d
                t2 = theta.copy()
                t2[idx] += step
                trials.append(t2)
            c2, k, r_k = self.chi2_best(np.array(trials))
            if c2[k] >= chi2:
                lam_scale *= 100.0
                if lam_scale > 1e6:
                    converged = True  # no direction lowers chi^2: at the minimum
                    break
                continue
            gain = chi2 - float(c2[k])
            theta, r, chi2 = trials[k], r_k, float(c2[k])
            stale = True
            lam_scale = max(lam_scale * (0.3 if k <= 2 else 1.0), 1e-3)
            linear = k == 0 and abs(gain - predicted) < 0.1 * predicted
            settled = gain < SETTLED_GAIN and gain < 0.25 * prev_gain
            if gain < tol + 1e-10 * chi2 or (linear and gain < 1.0) or settled:
                converged = True
                break
            prev_gain = gain
        return LMResult(theta=theta, r=r, chi2=chi2, iterations=it, converged=converged)


# ---------------------------------------------------------------------------------------
# The screening of :mod:`._candidates` on a NormalJacobian (long recordings): the same
# Gauss-Newton step per effect, with the projections orthogonal to J's columns written
# through J^T J's pseudo-inverse M M^T (the `_basis` eigen-decomposition of the same
# column-scaled normal matrix): x_perp . y_perp = x.y - (M^T J^T x).(M^T J^T y).
# ---------------------------------------------------------------------------------------
def screen_normal(engine, theta, r, NJ: NormalJacobian, effects, extra_names, geo) -> dict:
    """:func:`fitlug.explain._candidates.screen` for a :class:`NormalJacobian`."""
    from ._candidates import Screened, alternatives

    M = pinv_factor(NJ.A, 1e-12)
    qr = M.T @ NJ.g  # M^T J^T r
    idx = np.r_[engine.cur_idx, [engine.index(k) for k in extra_names]].astype(int)

    def gn_start(th, JtC, beta):
        delta = -(M @ (qr + M.T @ (JtC @ beta)))  # -J^+ (r + C beta)
        out = th.copy()
        out[idx] += delta
        return out

    def project(C, JtC):
        Q = M.T @ JtC
        gram = tdot(C, C) - Q.T @ Q  # Cp^T Cp
        rhs = tdot(C, r) - Q.T @ qr  # Cp^T r_perp
        return gram, rhs

    out = {}
    for eid in effects:
        if eid == "frame_drop":
            out[eid] = _screen_frame_drop_normal(engine, theta, r, NJ, M, qr, geo, gn_start,
                                                 project)
            continue
        best = None
        for alt, th, C, JtC in _alternative_columns(engine, NJ, theta,
                                                    alternatives(eid, engine, theta)):
            gram, rhs = project(C, JtC)
            norms = np.sqrt(np.maximum(np.diag(gram), 0.0))
            ok = norms > 1e-9 * max(norms.max(), 1e-300)
            if not ok.any():
                continue
            beta = np.zeros(C.shape[1])
            beta[ok] = np.linalg.lstsq(gram[np.ix_(ok, ok)], -rhs[ok], rcond=None)[0]
            d = float(beta @ gram @ beta)
            if best is None or d > best[0]:
                best = (d, alt, th, JtC, beta)
        if best is None:
            out[eid] = Screened(eid, 0.0, theta.copy(), theta.copy(), "no signature")
            continue
        d, alt, th, JtC, beta = best
        start = gn_start(th, JtC, beta)
        start = engine.with_values(start, alt.start(beta))
        out[eid] = Screened(eid, d, start, th, alt.label)
    # the screening is the normal Jacobian's last use in a round: its chunks and columns
    # would otherwise stay resident through the round's candidate fits
    NJ.release()
    return out


def _alternative_columns(engine, NJ, theta, alts, per_pass: int = 4):
    """(alternative, its settings vector, columns C, J^T C) for each alternative; J^T C of
    a few alternatives' columns per pass over the time chunks."""
    group = []

    def flush():
        JtC = NJ.Jt([g[2] for g in group])  # no stacked copy of the group's columns
        k = 0
        for alt, th, C in group:
            yield alt, th, C, JtC[:, k:k + C.shape[1]]
            k += C.shape[1]

    for alt in alts:
        th = engine.with_values(theta, alt.settings)
        group.append((alt, th, engine.fd_columns(alt.columns, th, STORE)))
        if sum(g[2].shape[1] for g in group) >= per_pass:
            yield from flush()
            group = []
    if group:
        yield from flush()


def _screen_frame_drop_normal(engine, theta, r, NJ, M, qr, geo, gn_start, project):
    from ._candidates import Screened, frame_drop_tstar

    t_star, jump = frame_drop_tstar(
        engine, theta, r, geo,
        lambda d, order, suffix, tu: NJ.suffix_projections(d, geo.t, tu, M))  # |U^T d_k|^2
    th = engine.with_values(theta, {"drop_tstar": t_star})
    C = engine.fd_columns([({}, "drop_dt")], th)
    JtC = NJ.Jt(C)
    gram, rhs = project(C, JtC)
    beta = np.linalg.lstsq(gram, -rhs, rcond=None)[0]
    start = gn_start(th, JtC, beta)
    start = engine.with_values(start, {"drop_dt": float(beta[0])})
    return Screened("frame_drop", float(beta @ gram @ beta), start, th, f"t*={t_star:.4f} s",
                    {"t_star_s": t_star, "jump_score": jump})


# ---------------------------------------------------------------------------------------
# Gauss-Newton steps and covariances of a fixed-effect-set problem (the final polish):
# dense on short recordings, from the chunked normal equations on long ones.
# ---------------------------------------------------------------------------------------
def gauss_newton_step(flat, fixed, packing, lay, obs, r) -> tuple:
    """(undamped Gauss-Newton step, its predicted chi^2 decrease) at `flat`, residuals r:
    the minimum-norm step of the column-scaled Jacobian (singular values below 1e-12 of
    the largest dropped), or of its chunked normal equations on a long recording."""
    J = jacobian_of(flat, fixed, packing, lay, obs)
    if isinstance(J, RowChunks):
        A, g = normal_of(J, np.asarray(r))
        M = pinv_factor(A, 1e-14)
        q = M.T @ g
        return -(M @ q), float(q @ q)
    d = np.sqrt(np.sum(J * J, 0))
    d = np.where(d > 0, d, 1.0)
    Js = J / d
    U, s, Vt = np.linalg.svd(Js, full_matrices=False)
    keep = s > 1e-12 * s.max()
    ur = U[:, keep].T @ r
    step = -(Vt[keep].T @ (ur / s[keep])) / d
    return step, float(ur @ ur)


def covariance_of(flat, fixed, packing, lay, obs) -> np.ndarray:
    """fitlug.fit.covariance of the problem's Jacobian (from J^T J on long recordings)."""
    from ..fit._covariance import covariance, covariance_normal

    J = jacobian_of(flat, fixed, packing, lay, obs)
    if isinstance(J, RowChunks):
        return covariance_normal(normal_of(J)[0])
    return covariance(J)
