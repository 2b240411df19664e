"""Weighted least squares with optimistix's Levenberg-Marquardt.

The free parameters are packed into one vector and scaled so that every Jacobian column
has unit norm at the start (LM's damping is isotropic, and our parameters span 1e-9
(lens k1, per mm^2) to 1e2 (mm)); the trust region starts at lambda = 1e-4 in those units.
The damped step comes from the normal equations (Cholesky), and the trust region accepts a
step that ends the solve even when its reduction ratio is rounding noise (see
:class:`_RoundingAwareTrustRegion`). On the reference recording: 10 steps, 0.3-0.4 s warm,
8 s cold, the same chi^2 to the last printed digit as optimistix's stock LM (37 steps,
2 s). `throw=False` keeps the compiled solver cacheable; the result code is checked here
instead. Tolerances are in the unit-column scale (a unit step moves the residual norm by
about one sigma): atol 1e-6 stops far below any statistical relevance.

:func:`jacobian` is the exact Jacobian computed through the model's structure (2-3x faster
than jacfwd); the start scaling, the covariance and the explanation engine use it.

Long recordings (the dense Jacobian above LARGE_ENTRIES entries) never form J: their LM
runs on J^T J and J^T r accumulated in time chunks (:func:`normal_equations`), same
optimum (1.7e-10 relative in the parameters on the reference recording), memory linear
in the samples. Above BLOCK_ROWS residual rows the passes run by time blocks
(:func:`time_blocks`): the per-row buffers of one block at a time, the sums unchanged.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx

from ..model import (CATALOG, KINEMATIC, positions, predict, predict_from_nodes,
                     sampled_kinematics)
from .. import _exported
from ..model._physics import beta_max


def residuals(p: dict, lay, obs: dict):
    """Weighted residuals (model - data) / sigma, (2 S_l + 2 S_b,)."""
    return _weighted(predict(p, lay), obs)


def _weighted(pos, obs):
    lx, ly, bx, by = pos
    return jnp.concatenate([(lx - obs["lug_x"]) * obs["lug_w"], (ly - obs["lug_y"]) * obs["lug_w"],
                            (bx - obs["body_x"]) * obs["body_w"],
                            (by - obs["body_y"]) * obs["body_w"]])


def jacobian(flat, fixed: dict, lay, obs: dict, packing: "Packing"):
    """d residuals / d flat, exact, using the model's structure (same values as jacfwd).

    A sample's position depends on the speed-profile coefficients, s0 and beta only through
    its own X and psi (:func:`fitlug.model.sampled_kinematics`), and on sigma0 only through
    u = sigma0 + psi. So those columns (most of them: the spline has tens of coefficients)
    are d(X, psi)/d theta of the cheap first stage, times two per-residual derivatives
    dr/dX and dr/dpsi of the second; the few other parameters go forward through the whole
    model. 2.5-3x faster than jacfwd on the reference recording (28-35 ms against 88).
    """
    sl = packing.slices()
    kin = [k for k in packing.names if k in KINEMATIC]
    rest = [k for k in packing.names if k not in KINEMATIC and k != "sigma0"]
    p = packing.unpack(flat, fixed)
    n_l, n_b = lay.lug_t.shape[0], lay.body_t.shape[0]

    def stage2(Xl, psil, Xb, psib):
        return _weighted(positions(p, lay, Xl, psil, Xb, psib), obs)

    prim = sampled_kinematics(p, lay)
    one_l, one_b = jnp.ones(n_l), jnp.ones(n_b)
    zero_l, zero_b = jnp.zeros(n_l), jnp.zeros(n_b)
    _, dr_dX = jax.jvp(stage2, prim, (one_l, zero_l, one_b, zero_b))
    _, dr_dpsi = jax.jvp(stage2, prim, (zero_l, one_l, zero_b, one_b))
    blocks, order = [], []  # column blocks and the packed indices they hold
    if kin:
        idx = np.concatenate([np.arange(sl[k].start, sl[k].stop) for k in kin])
        dXl, dpl, dXb, dpb = jax.jacfwd(lambda sub: sampled_kinematics(
            {**p, **packing.unpack(flat.at[idx].set(sub), {})}, lay))(flat[idx])
        dX = jnp.concatenate([dXl, dXl, dXb, dXb])
        dP = jnp.concatenate([dpl, dpl, dpb, dpb])
        blocks.append(dr_dX[:, None] * dX + dr_dpsi[:, None] * dP)
        order.append(idx)
    if "sigma0" in sl:  # u = sigma0[i] + psi: dr/dsigma0_i is dr/dpsi on marker i's rows
        idx = np.arange(sl["sigma0"].start, sl["sigma0"].stop)
        onehot = (lay.lug_i[:, None] == jnp.arange(len(idx))[None, :]).astype(flat.dtype)
        onehot = jnp.concatenate([onehot, onehot, jnp.zeros((2 * n_b, len(idx)))])
        blocks.append(dr_dpsi[:, None] * onehot)
        order.append(idx)
    if rest:
        idx = np.concatenate([np.arange(sl[k].start, sl[k].stop) for k in rest])
        blocks.append(jax.jacfwd(
            lambda sub: residuals(packing.unpack(flat.at[idx].set(sub), fixed), lay, obs))(
                flat[idx]))
        order.append(idx)
    return jnp.concatenate(blocks, axis=1)[:, np.argsort(np.concatenate(order))]


class Packing(NamedTuple):
    """How a parameter dict maps to the free vector (static)."""

    names: tuple
    shapes: tuple

    @classmethod
    def of(cls, p: dict, free) -> "Packing":
        names = tuple(k for k in p if k in set(free))
        return cls(names, tuple(tuple(np.shape(p[k])) for k in names))

    @property
    def sizes(self):
        return [int(np.prod(s)) if s else 1 for s in self.shapes]

    def pack(self, p: dict):
        return jnp.concatenate([jnp.ravel(jnp.asarray(p[k], float)) for k in self.names])

    def unpack(self, flat, fixed: dict) -> dict:
        out = dict(fixed)
        i = 0
        for k, shape, n in zip(self.names, self.shapes, self.sizes):
            out[k] = flat[i:i + n].reshape(shape)
            i += n
        return out

    def slices(self) -> dict:
        out, i = {}, 0
        for k, n in zip(self.names, self.sizes):
            out[k] = slice(i, i + n)
            i += n
        return out


_START_GAIN = 100.0


class _RoundingAwareTrustRegion(optx.ClassicalTrustRegion):
    """optimistix's classical trust region, except that a step small enough to end the solve
    (inside the Cauchy tolerances in both y and the residuals) is accepted whatever its
    true/predicted reduction ratio. At the optimum that ratio is rounding noise, and the
    classical test rejects such steps at random, shrinking the region for many steps before
    an accepted one ends the solve (measured: up to 17 extra steps after converged
    Gauss-Newton steps). Any larger step is judged as before."""

    rtol: float = 1e-8
    atol: float = 1e-6

    def step(self, first_step, y, y_eval, f_info, f_eval_info, state):
        size, accept, result, new_state = super().step(first_step, y, y_eval, f_info,
                                                       f_eval_info, state)
        r0, r1 = f_info.residual, f_eval_info.residual
        small_y = jnp.max(jnp.abs(y_eval - y) / (self.atol + self.rtol * jnp.abs(y))) < 1
        small_r = jnp.max(jnp.abs(r1 - r0) / (self.atol + self.rtol * jnp.abs(r0))) < 1
        done = small_y & small_r & jnp.all(jnp.isfinite(r1))
        size = jnp.where(done & ~accept, state.step_size, size)
        return size, accept | done, result, type(new_state)(step_size=size)


def _levenberg_marquardt(rtol, atol, linear_solver):
    lm = optx.LevenbergMarquardt(rtol=rtol, atol=atol, linear_solver=linear_solver)
    return eqx.tree_at(lambda s: s.search, lm, _RoundingAwareTrustRegion(rtol=rtol, atol=atol))


def _column_scale(J):
    norms = jnp.sqrt(jnp.sum(J * J, axis=0))
    return jnp.where(norms > 0, 1.0 / jnp.where(norms > 0, norms, 1.0), 1.0)


@eqx.filter_jit
def _solve(flat0, fixed, lay, obs, packing: Packing, max_steps: int, rtol: float, atol: float,
           gn_steps: int = 0):
    def r_of_flat(f):
        return residuals(packing.unpack(f, fixed), lay, obs)

    # unit Jacobian columns, times _START_GAIN: optimistix's trust region starts at lambda = 1,
    # which is 1 / _START_GAIN^2 in unit columns (LM alone: mean 20 steps instead of 30 over
    # five recordings); tolerances kept in unit columns
    scale = _column_scale(jacobian(flat0, fixed, lay, obs, packing)) * _START_GAIN
    atol = atol / _START_GAIN

    bounded = "s0" in packing.names and "beta" in packing.names

    def fn(z, _):
        f = flat0 + z * scale
        r = r_of_flat(f)
        if not bounded:
            return r
        # the solver (not the returned residuals, J or chi^2) is kept inside the slip law's
        # physical range: see bound_residuals
        return jnp.concatenate([r, bound_residuals(packing.unpack(f, fixed))])

    # the damped Gauss-Newton step from the normal equations (Cholesky of J^T J + lambda I,
    # columns scaled to unit norm) costs half the QR of [J; sqrt(lambda) I] per step, same
    # optimum to the last digit of chi^2 (benchmarks/bench_fit.py)
    normal = lx.Normal(lx.Cholesky())
    z0 = jnp.zeros_like(flat0)
    n_gn = min(gn_steps, max_steps // 2)  # max_steps bounds both phases together
    # optional Gauss-Newton steps first (kept only if they lowered chi^2), for batches under
    # jax.vmap: from a data-derived start they converge in about 6 steps and, having no
    # accept/reject branches, batch well, where a vmapped LM runs every lane as long as the
    # slowest (benchmarks/bench_fit.py (b): 0.40 against 0.87 s per fit in chunks of 4).
    # Not the default: they cost 6 s more compilation, and a single LM fit is as fast.
    # Levenberg-Marquardt then converges from there and decides convergence
    z1, gn_done = z0, 0
    if n_gn > 0:
        gn = optx.least_squares(fn, optx.GaussNewton(rtol=rtol, atol=atol,
                                                     linear_solver=normal),
                                z0, max_steps=n_gn, throw=False)
        sq = lambda z: jnp.sum(fn(z, None) ** 2)  # noqa: E731
        better = jnp.all(jnp.isfinite(gn.value)) & (sq(gn.value) < sq(z0))
        z1, gn_done = jnp.where(better, gn.value, z0), gn.stats["num_steps"]
    solver = _levenberg_marquardt(rtol, atol, normal)
    sol = optx.least_squares(fn, solver, z1, max_steps=max_steps - n_gn, throw=False)
    flat = flat0 + sol.value * scale
    J = jacobian(flat, fixed, lay, obs, packing)
    r = r_of_flat(flat)
    ok = sol.result == optx.RESULTS.successful
    return flat, J, r, ok, gn_done + sol.stats["num_steps"]


class LsqOutput(NamedTuple):
    params: dict
    flat: np.ndarray
    J: np.ndarray
    r: np.ndarray
    converged: bool
    steps: int
    packing: Packing
    normal: np.ndarray | None = None  # J^T J, given when J is not (chunked solve)


def least_squares(p0: dict, free, lay, obs, *, max_steps: int = 200, rtol: float = 1e-8,
                  atol: float = 1e-6, chunked: bool | None = None) -> LsqOutput:
    """Minimise |residuals|^2 over the `free` parameters of `p0` (others held fixed).

    Long recordings (dense Jacobian above LARGE_ENTRIES entries; `chunked` forces the
    choice) are solved on normal equations accumulated in time chunks: then the output's
    J is None and `normal` holds J^T J."""
    packing = Packing.of(p0, free)
    fixed = {k: jnp.asarray(v, float) for k, v in p0.items() if k not in packing.names}
    n_res = 2 * (lay.lug_t.shape[0] + lay.body_t.shape[0])
    if chunked is None:
        chunked = n_res * sum(packing.sizes) > LARGE_ENTRIES
    if chunked and chunkable(p0, lay, packing):
        flat, A, r, ok, steps = _solve_chunked(packing.pack(p0), fixed, lay, obs, packing,
                                               chunk_plan(lay), max_steps, rtol, 1e-9)
        p = packing.unpack(flat, fixed)
        return LsqOutput(params=p, flat=np.asarray(flat), J=None, r=np.asarray(r),
                         converged=bool(ok), steps=int(steps), packing=packing,
                         normal=np.asarray(A))
    # through a module exported to disk: a new process skips the solver's tracing (~6 s)
    flat, J, r, ok, steps = _exported.call("lsq_solve", _solve,
                                           (packing, max_steps, rtol, atol),
                                           packing.pack(p0), fixed, lay, obs)
    flat = np.asarray(flat)  # unpacked in numpy: jax slices compile once per (offset, size)
    p = packing.unpack(flat, fixed)
    return LsqOutput(params=p, flat=flat, J=np.asarray(J), r=np.asarray(r),
                     converged=bool(ok), steps=int(steps), packing=packing)


def inverse_norms(n: np.ndarray) -> np.ndarray:
    """1 / n for the column scaling of a pseudo-inverse, 0 where a column is zero (a
    parameter that does not act here, e.g. an effect's at a degenerate state: it gets the
    pseudo-inverse's zero, not 0 * inf = NaN in every entry)."""
    return np.where(n > 0, 1.0 / np.where(n > 0, n, 1.0), 0.0)


def _physical(p) -> bool:
    """Whether the slip law of `p` lies in its physical range (the solver's bounds)."""
    if "s0" not in p or "beta" not in p:
        return True
    b = float(np.ravel(p["beta"])[0])
    return 0.0 <= b <= float(np.ravel(beta_max(p["s0"]))[0])


@eqx.filter_jit
def _residuals_jacobian(flat, fixed, lay, obs, packing: Packing):
    return residuals(packing.unpack(flat, fixed), lay, obs), jacobian(flat, fixed, lay, obs,
                                                                          packing)


def gauss_newton_polish(out: LsqOutput, lay, obs, *, tol: float, max_iter: int = 12,
                        rcond: float = 1e-12) -> tuple[LsqOutput, float]:
    """Undamped Gauss-Newton steps (pseudo-inverse, halved until chi^2 drops) from `out`.

    For a dense fit that Levenberg-Marquardt left unconverged at its step limit: in a long,
    nearly flat valley (a cruise-only recording, where the slip slope beta and the speed
    spline trade against s0) LM's damping crawls along the valley floor, while one full
    Gauss-Newton step of the nearly linear problem lands on its minimum. Returns the polished
    output (converged when the chi^2 a further full step could remove is below `tol`) and
    that remaining decrement."""
    fixed = {k: jnp.asarray(v, float) for k, v in out.params.items()
             if k not in out.packing.names}
    flat, J, r = np.asarray(out.flat, float), np.asarray(out.J, float), np.asarray(out.r, float)
    chi2, dec, steps = float(r @ r), np.inf, out.steps
    for it in range(max_iter + 1):
        d = inverse_norms(np.linalg.norm(J, axis=0))
        z = np.linalg.lstsq(J * d, r, rcond=rcond)[0]
        dec = float(((J * d).T @ r) @ z)
        if not np.isfinite(dec) or dec < tol or it == max_iter:
            break
        step, t, moved = -z * d, 1.0, False
        while t > 1.0 / 256:
            r_t, J_t = _residuals_jacobian(flat + t * step, fixed, lay, obs, out.packing)
            r_t = np.asarray(r_t)
            if (np.all(np.isfinite(r_t)) and float(r_t @ r_t) < chi2
                    and _physical(out.packing.unpack(jnp.asarray(flat + t * step), fixed))):
                flat, J, r, chi2, moved = flat + t * step, np.asarray(J_t), r_t, float(r_t @ r_t), True
                break
            t /= 2
        steps += 1
        if not moved:
            break
    p = out.packing.unpack(jnp.asarray(flat), fixed)
    return out._replace(params=p, flat=flat, J=J, r=r, steps=steps,
                        converged=bool(dec < tol)), dec


def covariance(J: np.ndarray, rcond: float = 1e-12) -> np.ndarray:
    """(J^T J)^-1 with a pseudo-inverse for directions the data do not constrain."""
    s = inverse_norms(np.sqrt(np.sum(J * J, 0)))
    A = (J * s).T @ (J * s)
    w, V = np.linalg.eigh(A)
    inv = np.where(w > rcond * w.max(), 1.0 / np.where(w > 0, w, 1.0), 0.0)
    return (V * inv) @ V.T * np.outer(s, s)


# ---------------------------------------------------------------------------------------
# Long recordings: the normal equations accumulated in time chunks, bounded memory.
#
# The dense Jacobian (2 S residuals x p parameters, and p grows with the duration through
# the spline's knots) is never formed. One pass over time chunks of the residual rows
# builds J^T J (p x p), J^T r and chi^2; a chunk's Jacobian rows need d(X, psi)/d theta only
# at the nodes of its time window, which are the prefix sum up to the window's start (one
# dense vector per chunk, from per-segment sums of the banded Simpson increments) plus a
# local cumulative sum. The damped normal equations are then solved by a dense Cholesky of
# the p x p matrix, in the same unit-column scaling as the optimistix path.
# ---------------------------------------------------------------------------------------

#: node intervals per time chunk, and the margin each chunk's window adds on both sides
#: (a time-mapped sample may move by a frame: substeps intervals)
CHUNK_INTERVALS = 1024
_MARGIN = 16
#: the chunked path is used when the dense Jacobian would exceed this many entries
#: (32 MB; the reference recording has 0.9 M): below it the optimistix path is as fast
LARGE_ENTRIES = 4_000_000


class ChunkPlan(eqx.Module):
    """Which residual rows each time chunk holds and where its node window starts."""

    rows: jax.Array  # (C, R) residual rows (padded with row 0)
    mask: jax.Array  # (C, R) 1.0 for real rows
    ws: jax.Array  # (C,) first node of each chunk's window
    l0: jax.Array  # () first grid interval of the plan's span (the prefix sums' part)
    lseg: jax.Array  # (span,) segment of interval l0 + i: window starts <= it (C + 1: before
    #                  the first window, already in the prefix at ws[0])
    cb: jax.Array  # (C,) first spline coefficient of each chunk's band
    W: int = eqx.field(static=True)  # nodes per window
    BW: int = eqx.field(static=True)  # spline coefficients a window's rows touch locally


_MMAP_THRESHOLD = 1 << 20
_heap_set = False


def return_freed_memory() -> None:
    """Make glibc serve blocks of 1 MiB and more by mmap, so that they go back to the
    system when freed (process-wide, once; nothing elsewhere than glibc).

    A long recording's passes allocate and free tens to hundreds of MB per call (XLA's
    temporaries, the chunk buffers, the engine's residual batches); with glibc's adaptive
    threshold those end up in the heap once one of them has been freed, and the heap's
    fragments stay resident: measured on the 10 000-frame explanation, the peak fell from
    1.25 to 1.01 GB with this threshold (MALLOC_MMAP_THRESHOLD_). Called by every
    chunked path (:func:`chunk_plan`)."""
    global _heap_set
    if _heap_set:
        return
    _heap_set = True
    try:
        import ctypes

        libc = ctypes.CDLL(None)
        libc.mallopt(-3, _MMAP_THRESHOLD)  # M_MMAP_THRESHOLD
    except (OSError, AttributeError, TypeError):  # not glibc: leave the allocator alone
        pass


_libc = None


def trim_heap() -> None:
    """Hand the heap's free pages back to the system (glibc's malloc_trim(0), every arena),
    between the time blocks of a long recording's passes: blocks under the mmap threshold
    (:func:`return_freed_memory`), XLA's worker threads' among them, stay resident in the
    arenas' free lists otherwise. A few ms a call; nothing where the C library is not
    glibc. Measured on the 30 000-frame explanation of a belt sag: peak 1.03 against
    1.06 GiB with the calls switched off (benchmarks/results/2026-11-25/trim*_ee_30k.log)."""
    global _libc
    try:
        if _libc is None:
            import ctypes

            _libc = ctypes.CDLL(None)
        _libc.malloc_trim(0)
    except (OSError, AttributeError, TypeError):
        pass


def chunk_plan(lay, chunk: int = CHUNK_INTERVALS, margin: int = _MARGIN) -> ChunkPlan:
    """Time chunks of a layout's residual rows ([lug x, lug y, body x, body y])."""
    return_freed_memory()
    a = _plan_arrays(lay, chunk, margin)
    return _padded_plan(a, *a["rows"].shape)


def _plan_arrays(lay, chunk: int, margin: int) -> dict:
    """:func:`chunk_plan`'s arrays (numpy): chunks numbered from the first one holding a
    row (a time block's first chunk may lie far into the grid)."""
    return_freed_memory()
    grid = np.asarray(lay.grid)
    G = grid.shape[0]
    lt, bt = np.asarray(lay.lug_t), np.asarray(lay.body_t)
    t_row = np.concatenate([lt, lt, bt, bt])
    i0 = np.clip(np.floor((t_row - grid[0]) / lay.h).astype(np.int64), 0, G - 2)
    cid = i0 // chunk
    c0 = int(cid.min()) if len(cid) else 0
    cid = cid - c0
    C = int(cid.max()) + 1 if len(cid) else 1
    W = int(min(chunk + 2 * margin + 2, G))
    ws = np.clip((c0 + np.arange(C)) * chunk - margin, 0, G - W)
    counts = np.bincount(cid, minlength=C)
    R = max(int(counts.max()), 1)
    order = np.argsort(cid, kind="stable")
    starts = np.r_[0, np.cumsum(counts)[:-1]]
    pos = np.arange(len(order)) - starts[cid[order]]
    rows = np.zeros((C, R), np.int64)
    mask = np.zeros((C, R))
    rows[cid[order], pos] = order
    mask[cid[order], pos] = 1.0
    # the band of spline coefficients whose increments fall inside each window (the
    # rest of a row's kinematic derivative is the window's prefix: rank two per chunk)
    K = int(lay.n_coef)
    b = int(np.asarray(lay.Bn).shape[1])
    jn, jm = np.asarray(lay.jn), np.asarray(lay.jm)
    lo = np.minimum(jn[ws], jm[np.minimum(ws, G - 2)])
    hi = np.maximum(jn[ws + W - 1], jm[np.minimum(ws + W - 2, G - 2)]) + b - 1
    lo, hi = np.clip(lo, 0, K - 1), np.clip(hi, 0, K - 1)
    BW = int(min(K, max(int(np.max(hi - lo)) + 1, 1)))
    return {"rows": rows, "mask": mask, "ws": ws, "G": G, "W": W, "BW": BW, "lo": lo, "K": K}


def _span(a: dict) -> int:
    """Grid intervals from a plan's first window start to its last (>= 1)."""
    return max(int(a["ws"][-1] - a["ws"][0]), 1)


def _padded_plan(a: dict, C: int, R: int, BW: int | None = None,
                 span: int | None = None) -> ChunkPlan:
    """A :class:`ChunkPlan` of the arrays `a` padded to C chunks of R rows (padding: no
    rows, windows at the last chunk's), its prefix sums over `span` intervals from its first
    window (the longest of the time blocks': one shape for all)."""
    c, r = a["rows"].shape
    rows = np.zeros((C, R), np.int64)
    mask = np.zeros((C, R))
    rows[:c, :r], mask[:c, :r] = a["rows"], a["mask"]
    ws = np.r_[a["ws"], np.full(C - c, a["ws"][-1])]
    lo = np.r_[a["lo"], np.full(C - c, a["lo"][-1])]
    n_int = a["G"] - 1
    span = min(_span(a) if span is None else span, n_int)
    l0 = int(np.clip(a["ws"][0], 0, n_int - span))  # the span inside the grid
    k = l0 + np.arange(span)
    lseg = np.where(k < a["ws"][0], C + 1, np.searchsorted(a["ws"], k, side="right"))
    BW = a["BW"] if BW is None else BW
    cb = np.clip(lo, 0, a["K"] - BW)
    return ChunkPlan(rows=jnp.asarray(rows), mask=jnp.asarray(mask), ws=jnp.asarray(ws),
                     l0=jnp.asarray(l0), lseg=jnp.asarray(lseg), cb=jnp.asarray(cb),
                     W=a["W"], BW=BW)


#: residual rows per time block of a chunked pass: the pass's per-row buffers (residuals,
#: their X/psi derivatives, the non-kinematic columns and their temporaries: ~30 doubles
#: a row) are built one block at a time, so its memory stops growing with the recording
#: (250 000 rows: ~60 MB of them; 500 000 before, whose passes stood out in the RSS trace
#: of a 100 000-frame explanation)
BLOCK_ROWS = 250_000
#: residual entries (rows x lanes, or rows x parameter vectors) of one time block's batched
#: model evaluation (the explanation engine's candidates, the posterior's exact chi^2):
#: XLA's temporaries there are ~10-15 doubles per entry (memray, 30 000 frames: 385 MB at
#: 8 lanes x 420 000 rows), so 1 M entries hold them near 100 MB at any length
BLOCK_ENTRIES = 1_000_000


class TimeBlocks(NamedTuple):
    """A recording's samples cut in time into blocks of equal shape (padded with samples of
    zero weight), each a problem of its own on the same grid: the Jacobian rows of a sample
    depend on its own time and marker only, so J^T J, J^T r and chi^2 are the sums of the
    blocks'. lays/obss/plans: one per block; rows: each block's rows in the full residual
    vector (-1 for padding)."""

    lays: list
    obss: list
    plans: list
    rows: list


def time_blocks(lay, obs: dict, max_rows: int | None = None,
                chunk: int = CHUNK_INTERVALS, margin: int = _MARGIN,
                plans: bool = True) -> TimeBlocks | None:
    """:class:`TimeBlocks` of at most about `max_rows` (default BLOCK_ROWS) residual rows,
    or None when the recording fits in one (or a block would hold no lug or no body
    sample). plans=False leaves the chunk plans out (`plans` None each: for a model
    evaluation by blocks, which needs none; ~2 doubles a residual row less)."""
    max_rows = BLOCK_ROWS if max_rows is None else max_rows
    lt, bt = np.asarray(lay.lug_t), np.asarray(lay.body_t)
    S_l, S_b = len(lt), len(bt)
    n_res = 2 * (S_l + S_b)
    nb = -(-n_res // max(int(max_rows), 1))
    if nb <= 1:
        return None
    t_all = np.sort(np.concatenate([lt, bt]))
    cuts = t_all[(np.arange(1, nb) * len(t_all)) // nb]
    bl, bb = np.searchsorted(cuts, lt, side="right"), np.searchsorted(cuts, bt, side="right")
    idx_l = [np.flatnonzero(bl == k) for k in range(nb)]
    idx_b = [np.flatnonzero(bb == k) for k in range(nb)]
    if any(len(a) == 0 for a in idx_l + idx_b):
        return None
    nl, nbd = max(map(len, idx_l)), max(map(len, idx_b))
    lug_keys, body_keys = ("lug_x", "lug_y", "lug_w"), ("body_x", "body_y", "body_w")
    lays, obss, rows, raw = [], [], [], []
    for il, ib in zip(idx_l, idx_b):
        # padding: the block's last sample again, with zero weight (rows of zeros)
        pl, pb = np.r_[il, np.full(nl - len(il), il[-1])], np.r_[ib, np.full(nbd - len(ib), ib[-1])]
        real_l, real_b = np.arange(nl) < len(il), np.arange(nbd) < len(ib)
        lay_k = lay.with_times(lay.lug_t[pl], lay.lug_i[pl], lay.body_t[pb], lay.body_j[pb])
        ob = {k: obs[k][pl] for k in lug_keys}
        ob.update({k: obs[k][pb] for k in body_keys})
        ob["lug_w"] = jnp.where(jnp.asarray(real_l), ob["lug_w"], 0.0)
        ob["body_w"] = jnp.where(jnp.asarray(real_b), ob["body_w"], 0.0)
        lays.append(lay_k)
        obss.append(ob)
        rr = np.concatenate([np.where(real_l, pl, -1), np.where(real_l, S_l + pl, -1),
                             np.where(real_b, 2 * S_l + pb, -1),
                             np.where(real_b, 2 * S_l + S_b + pb, -1)])
        rows.append(rr)
        if plans:
            raw.append(_plan_arrays(lay_k, chunk, margin))
    if not plans:
        return TimeBlocks(lays, obss, [None] * nb, rows)
    # one shape for every block's plan (one compilation serves them all)
    C = max(a["rows"].shape[0] for a in raw)
    R = max(a["rows"].shape[1] for a in raw)
    BW = max(a["BW"] for a in raw)
    span = max(_span(a) for a in raw)
    plans = [_padded_plan(a, C, R, BW, span) for a in raw]
    return TimeBlocks(lays, obss, plans, rows)


def normal_blocks(flat, fixed: dict, lay, obs: dict, packing: Packing, plan: ChunkPlan,
                  blocks: TimeBlocks | None = None) -> tuple:
    """(J^T J, J^T r, chi^2) in numpy from :func:`normal_equations`, one time block at a
    time when the recording has several (:func:`time_blocks`; pass them when known)."""
    blocks = time_blocks(lay, obs) if blocks is None else blocks
    if blocks is None:
        A, g, c2 = _normal_jit(jnp.asarray(flat), fixed, lay, obs, packing, plan)
        return np.array(A), np.array(g), float(c2)
    A = g = None
    c2 = 0.0
    shared = block_shared(flat, fixed, lay, packing, blocks.plans)
    for lay_k, ob_k, plan_k, sh_k in zip(blocks.lays, blocks.obss, blocks.plans, shared):
        trim_heap()
        Ak, gk, ck = _normal_jit(jnp.asarray(flat), fixed, lay_k, ob_k, packing, plan_k, sh_k)
        A = np.array(Ak) if A is None else A + np.asarray(Ak)
        g = np.array(gk) if g is None else g + np.asarray(gk)
        c2 += float(ck)
    return A, g, c2


def chunkable(p: dict, lay, packing: Packing) -> bool:
    """Whether the chunked normal equations apply: speed spline, s0, beta and sigma0 free,
    and no belt-locked speed modulation (which makes psi's ODE non-local in theta)."""
    from ..model._model import _hook

    return (all(k in packing.names for k in ("v", "s0", "beta", "sigma0"))
            and not _hook(lay, "speed"))


def _kinematic_bands(p: dict, lay):
    """Banded derivatives of the node rates and of the Simpson increments with respect to
    the kinematic columns (K spline coefficients, then s0, then beta).

    Returns (rate bands at nodes for X and psi, increment bands per interval for X and
    psi); a band is (values (n, b), columns (n, b)), repeated columns add up."""
    from ..model._model import _rates, ctx_of, speed_basis_values

    ctx = ctx_of(p, lay)
    K = lay.n_coef
    c = p["v"]
    v0n, a0n, v0m, a0m = speed_basis_values(lay, c)

    def partials(v0, a0):
        def F(v, a, s0, beta):
            return _rates({**p, "s0": s0, "beta": beta}, lay, ctx, v, a, None)[1]

        args = (v0, a0, p["s0"], p["beta"])
        out = []
        for k in range(4):
            tang = [jnp.zeros_like(x) for x in args]
            tang[k] = jnp.ones_like(args[k])
            out.append(jax.jvp(F, args, tuple(tang))[1])
        return out  # dF/dv0, dF/da0, dF/ds0, dF/dbeta (per node)

    def bands(B, dB, first, v0, a0):
        Fv, Fa, Fs, Fb = partials(v0, a0)
        n = B.shape[0]
        cols = jnp.concatenate([first[:, None] + jnp.arange(B.shape[1])[None, :],
                                jnp.full((n, 1), K), jnp.full((n, 1), K + 1)], axis=1)
        zx = jnp.zeros((n, 2))
        bx = jnp.concatenate([B, zx], axis=1)
        bp = jnp.concatenate([Fv[:, None] * B + Fa[:, None] * dB, Fs[:, None], Fb[:, None]],
                             axis=1)
        return bx, bp, cols

    nx, npsi, ncol = bands(lay.Bn, lay.dBn, lay.jn, v0n, a0n)
    mx, mpsi, mcol = bands(lay.Bm, lay.dBm, lay.jm, v0m, a0m)
    h6 = lay.h / 6.0
    icol = jnp.concatenate([ncol[:-1], mcol, ncol[1:]], axis=1)
    ix = h6 * jnp.concatenate([nx[:-1], 4.0 * mx, nx[1:]], axis=1)
    ipsi = h6 * jnp.concatenate([npsi[:-1], 4.0 * mpsi, npsi[1:]], axis=1)
    return (nx, npsi, ncol), (ix, ipsi, icol)


def _scatter_rows(vals, cols, width):
    """Dense (n, width) matrix of banded rows."""
    n = vals.shape[0]
    return jnp.zeros((n, width), vals.dtype).at[jnp.arange(n)[:, None], cols].add(vals)


def normal_equations(flat, fixed: dict, lay, obs: dict, packing: Packing, plan: ChunkPlan,
                     v=None, with_A: bool = True, shared: dict | None = None):
    """(J^T J, J^T r, chi^2) of the weighted residuals, in memory linear in the samples and
    without the dense Jacobian; J is the same exact Jacobian as :func:`jacobian`.

    With `v` (a residual-shaped vector, or (m, N) for m of them) the second output is J^T v
    instead ((p,) or (m, p)); with_A=False skips J^T J (returned as None). `shared`: the
    plan's :func:`block_shared` dict when `lay` is one time block of a longer recording."""
    prep = _prepare(flat, fixed, lay, obs, packing, plan, shared)
    A, g = contract(prep, lay, packing, plan, v, with_A)
    return A, g, jnp.sum(prep["r"] ** 2)


def _kinematic_positions(packing: Packing) -> np.ndarray:
    """Packed indices of the kinematic columns: the speed spline's coefficients, s0, beta."""
    sl = packing.slices()
    return np.r_[np.arange(sl["v"].start, sl["v"].stop), sl["s0"].start, sl["beta"].start]


def _gram_add(A, fa, fb, pos, kin_pos):
    """A + J_a^T J_b of one chunk, J = U P^T (kinematic columns) + L (columns `pos`),
    from the factors fa = (U_a, P_a, L_a) and fb; with fa = fb, the chunk's J^T J."""
    (Ua, Pa, La), (Ub, Pb, Lb) = fa, fb
    A = A.at[pos[:, None], pos[None, :]].add(La.T @ Lb)
    A = A.at[kin_pos[:, None], pos[None, :]].add(Pa @ (Ua.T @ Lb))
    A = A.at[pos[:, None], kin_pos[None, :]].add((Pb @ (Ub.T @ La)).T)
    return A.at[kin_pos[:, None], kin_pos[None, :]].add(Pa @ (Ua.T @ Ub) @ Pb.T)


def contract(prep: dict, lay, packing: Packing, plan: ChunkPlan, v=None, with_A: bool = True):
    """(J^T J, J^T v) from one plan's :func:`_prepare` buffers (`v`: residual-shaped, (N,)
    or (m, N); None: the residuals), chunk by chunk; J^T J is None without with_A. The
    buffers at one parameter vector serve any number of vectors `v`."""
    r = prep["r"]
    n_par = int(sum(packing.sizes))
    kin_pos = jnp.asarray(_kinematic_positions(packing))

    # a chunk's rows are J_c = U P^T (on the kinematic columns) + L (on w local columns):
    # U (R, 2) = (dr/dX, dr/dpsi), P (nk, 2) the window's prefix derivatives, L the band
    # of spline coefficients inside the window, s0, beta, sigma0 and the other parameters.
    # J_c^T J_c then costs R w^2 + nk^2 instead of R p^2 (p grows with the duration).
    def chunk(carry, xs):
        A, g = carry
        U, P, L, pos = _chunk_factors(prep, lay, packing, plan, *xs)
        rows, mask = xs[0], xs[1]
        if with_A:
            A = _gram_add(A, (U, P, L), (U, P, L), pos, kin_pos)
        vc = (r[rows] if v is None else v[..., rows]) * mask
        g = g.at[..., pos].add(vc @ L)
        g = g.at[..., kin_pos].add((vc @ U) @ P.T)
        return (A, g), None

    g0 = jnp.zeros(n_par) if v is None else jnp.zeros(v.shape[:-1] + (n_par,))
    init = (jnp.zeros((n_par, n_par)) if with_A else jnp.zeros(()), g0)
    (A, g), _ = jax.lax.scan(chunk, init, (plan.rows, plan.mask, plan.ws, plan.cb,
                                           prep["preX"], prep["preP"]))
    return (A if with_A else None), g


def contract_cross(prep_a: dict, prep_b: dict, lay, packing: Packing, plan: ChunkPlan):
    """J_a^T J_b, J_a and J_b the Jacobians whose :func:`_prepare` buffers (of one plan,
    at two parameter vectors) are given: :func:`contract`'s J^T J with the two factors
    taken from different vectors, chunk by chunk (same values as the dense product)."""
    n_par = int(sum(packing.sizes))
    kin_pos = jnp.asarray(_kinematic_positions(packing))

    def chunk(A, xs):
        rows, mask, ws, cb, pXa, pPa, pXb, pPb = xs
        *fa, pos = _chunk_factors(prep_a, lay, packing, plan, rows, mask, ws, cb, pXa, pPa)
        *fb, _ = _chunk_factors(prep_b, lay, packing, plan, rows, mask, ws, cb, pXb, pPb)
        return _gram_add(A, fa, fb, pos, kin_pos), None

    A, _ = jax.lax.scan(chunk, jnp.zeros((n_par, n_par)),
                        (plan.rows, plan.mask, plan.ws, plan.cb, prep_a["preX"],
                         prep_a["preP"], prep_b["preX"], prep_b["preP"]))
    return A


@eqx.filter_jit
def contract_cross_jit(prep_a, prep_b, lay, packing: Packing, plan: ChunkPlan):
    return contract_cross(prep_a, prep_b, lay, packing, plan)


def _window_nodes(prep: dict, lay, rows, ws, W: int, nk: int, cb=None, BW: int | None = None):
    """d(X, psi)/d theta (kinematic columns) at the W nodes of a chunk's window, summed from
    the window's first node (the prefix before it is the caller's), their time derivatives
    at the nodes, and each row's window interval and Hermite weights:
    ((DX, DP, VX, VP), il, (w00, w10, w01, w11)).

    With `cb` and `BW` the columns are the window's band only (spline coefficients
    cb..cb+BW-1, then s0 and beta: BW + 2), which hold every nonzero of the window (see
    :func:`_plan_arrays`): W (BW + 2) entries instead of W nk, nk growing with the
    recording's duration."""
    sl_n = lambda a: jax.lax.dynamic_slice_in_dim(a, ws, W, 0)  # noqa: E731
    sl_i = lambda a: jax.lax.dynamic_slice_in_dim(a, ws, W - 1, 0)  # noqa: E731
    icol, ncol = sl_i(prep["icol"]), sl_n(prep["ncol"])
    if cb is not None:  # global kinematic column -> column of the band
        K = nk - 2

        def local(c):
            return jnp.where(c >= K, c - K + BW, c - cb)

        icol, ncol, nk = local(icol), local(ncol), BW + 2
    zero = jnp.zeros((1, nk))
    DX = jnp.concatenate([zero, jnp.cumsum(_scatter_rows(sl_i(prep["ix"]), icol, nk), 0)])
    DP = jnp.concatenate([zero, jnp.cumsum(_scatter_rows(sl_i(prep["ipsi"]), icol, nk), 0)])
    VX = _scatter_rows(sl_n(prep["nx"]), ncol, nk)
    VP = _scatter_rows(sl_n(prep["npsi"]), ncol, nk)
    u = (prep["t_row"][rows] - lay.grid[0]) / lay.h
    ig = jnp.clip(jnp.floor(u).astype(int), 0, lay.grid.shape[0] - 2)
    il = jnp.clip(ig - ws, 0, W - 2)
    weights = tuple(w[:, None] for w in _hermite_weights(u - ig, lay.h))
    return (DX, DP, VX, VP), il, weights


def _chunk_factors(prep: dict, lay, packing: Packing, plan: ChunkPlan, rows, mask, ws, cb,
                   pX, pP):
    """One chunk's Jacobian rows as U P^T on the kinematic columns plus L on the columns
    `pos` (see :func:`normal_equations`); the same values as :func:`_chunk_jacobian`."""
    sl = packing.slices()
    K = lay.n_coef
    nk = K + 2
    W, BW = plan.W, plan.BW
    rest_idx = _rest_index(packing)
    kin_pos = jnp.asarray(_kinematic_positions(packing))
    sig_pos = jnp.asarray(np.arange(sl["sigma0"].start, sl["sigma0"].stop))
    n_sig = sig_pos.shape[0]
    cols = jnp.concatenate([cb + jnp.arange(BW), jnp.array([K, K + 1])])  # band, s0, beta
    (DX, DP, VX, VP), il, (w00, w10, w01, w11) = _window_nodes(prep, lay, rows, ws, W, nk,
                                                               cb, BW)
    # the Hermite weights of the two node values add up to one: the prefix factors out
    lX = w00 * DX[il] + w10 * VX[il] + w01 * DX[il + 1] + w11 * VX[il + 1]
    lP = w00 * DP[il] + w10 * VP[il] + w01 * DP[il + 1] + w11 * VP[il + 1]
    aX, aP = prep["dr_dX"][rows] * mask, prep["dr_dpsi"][rows] * mask
    U = jnp.stack([aX, aP], 1)
    P = jnp.stack([pX - prep["refX"], pP - prep["refP"]], 1)
    Lk = aX[:, None] * lX + aP[:, None] * lP
    Ls = (prep["sig_col"][rows][:, None] == jnp.arange(n_sig)[None, :]) * (
        prep["sig_val"][rows] * mask)[:, None]
    blocks = [Lk, Ls]
    pos = [kin_pos[cols], sig_pos]
    if len(rest_idx):
        blocks.append(prep["J_rest"][:, rows].T * mask[:, None])
        pos.append(jnp.asarray(rest_idx))
    return U, P, jnp.concatenate(blocks, 1), jnp.concatenate(pos)


def _node_params(lay, packing: Packing) -> list:
    """The free non-kinematic parameters that reach the node values of
    :func:`fitlug.model.integrate` (a replacing slip law's: the chunked path has no speed
    hook); every other non-kinematic parameter acts on the samples alone."""
    names = []
    for e in lay.effects:
        if CATALOG[e].slip is not None:
            names += [k for k in CATALOG[e].defaults if k in packing.names]
    return names


def _shared(flat, fixed: dict, lay, packing: Packing, starts) -> dict:
    """What the time blocks of one pass share, over the whole grid, computed once per
    parameter vector (not once per block: a block's own work is then linear in its rows,
    and the pass linear in the recording): the node values of X and psi and their tangents
    along the node parameters (:func:`_node_params`), the banded kinematic derivatives, the
    gauge's derivative and the prefix sums of the increments at each block's first window
    start `starts` ((nb,), sorted): "preX0"/"preP0" (nb, nk)."""
    from ..model._model import integrate

    p = packing.unpack(flat, fixed)
    nk = lay.n_coef + 2
    G = lay.grid.shape[0]
    nodes = integrate(p, lay)
    names = _node_params(lay, packing)
    if names:
        sl = packing.slices()
        idx = np.array([sl[k].start for k in names])
        E = jnp.zeros((len(idx), flat.shape[0])).at[np.arange(len(idx)), idx].set(1.0)
        node_tan = jax.lax.map(lambda e: jax.jvp(
            lambda f: integrate(packing.unpack(f, fixed), lay), (flat,), (e,))[1], E)
    else:
        node_tan = tuple(jnp.zeros((0, G)) for _ in range(4))
    (nx, npsi, ncol), (ix, ipsi, icol) = _kinematic_bands(p, lay)
    # prefix sums of the increments before each block's first window
    gseg = jnp.searchsorted(jnp.asarray(starts), jnp.arange(G - 1), side="right")
    nb = starts.shape[0]
    seg_rows = gseg[:, None] * nk + icol
    segX = jnp.zeros((nb + 1) * nk).at[seg_rows].add(ix).reshape(nb + 1, nk)
    segP = jnp.zeros((nb + 1) * nk).at[seg_rows].add(ipsi).reshape(nb + 1, nk)
    # the gauge X(t_ref) = psi(t_ref) = 0: derivative of the value at t_ref
    u0 = (lay.t_ref - lay.grid[0]) / lay.h
    i0 = jnp.clip(jnp.floor(u0).astype(int), 0, G - 2)
    below = (jnp.arange(G - 1) < i0).astype(flat.dtype)[:, None]
    X0 = jnp.zeros(nk).at[icol].add(ix * below)
    P0 = jnp.zeros(nk).at[icol].add(ipsi * below)
    inc0X = jnp.zeros(nk).at[icol[i0]].add(ix[i0])
    inc0P = jnp.zeros(nk).at[icol[i0]].add(ipsi[i0])
    vX = [jnp.zeros(nk).at[ncol[i]].add(nx[i]) for i in (i0, i0 + 1)]
    vP = [jnp.zeros(nk).at[ncol[i]].add(npsi[i]) for i in (i0, i0 + 1)]
    tau0 = u0 - i0
    hw0 = _hermite_weights(tau0, lay.h)
    refX = hw0[0] * X0 + hw0[1] * vX[0] + hw0[2] * (X0 + inc0X) + hw0[3] * vX[1]
    refP = hw0[0] * P0 + hw0[1] * vP[0] + hw0[2] * (P0 + inc0P) + hw0[3] * vP[1]
    return {"nodes": nodes, "node_tan": node_tan, "nx": nx, "npsi": npsi, "ncol": ncol,
            "ix": ix, "ipsi": ipsi, "icol": icol, "refX": refX, "refP": refP,
            "preX0": jnp.cumsum(segX, 0)[:-1], "preP0": jnp.cumsum(segP, 0)[:-1]}


@eqx.filter_jit
def _shared_jit(flat, fixed, lay, packing: Packing, starts):
    return _shared(flat, fixed, lay, packing, starts)


def block_shared(flat, fixed: dict, lay, packing: Packing, plans) -> list:
    """:func:`_shared` of the whole recording `lay` once, handed to each of `plans` (its
    time blocks', in time order) with its own prefix: one dict per plan."""
    starts = jnp.asarray(np.array([int(pl.ws[0]) for pl in plans]))
    sh = _shared_jit(jnp.asarray(flat), fixed, lay, packing, starts)
    return [{**sh, "preX0": sh["preX0"][k], "preP0": sh["preP0"][k]}
            for k in range(len(plans))]


def _prepare(flat, fixed: dict, lay, obs: dict, packing: Packing, plan: ChunkPlan,
             shared: dict | None = None, pass_shared: bool = False) -> dict:
    """What every time chunk's Jacobian rows need (all of it linear in the samples): the
    residuals, their derivatives along X and psi, the columns of the few non-kinematic
    parameters, the banded kinematic derivatives and their prefix sums per chunk.
    `shared`: :func:`block_shared`'s dict of this plan (computed here when None: `lay` is
    then the whole recording's). pass_shared: leave shared's arrays (_SHARED_KEYS) out of
    the result (the caller adds them: :func:`_prepare_jit`)."""
    from ..model._model import _true_times, sampled_from_nodes

    if shared is None:
        shared = _shared(flat, fixed, lay, packing, plan.ws[:1])
        shared = {**shared, "preX0": shared["preX0"][0], "preP0": shared["preP0"][0]}
    p = packing.unpack(flat, fixed)
    n_par = flat.shape[0]
    nk = lay.n_coef + 2
    n_l, n_b = lay.lug_t.shape[0], lay.body_t.shape[0]
    nodes = shared["nodes"]

    def stage2(Xl, psil, Xb, psib):
        return _weighted(positions(p, lay, Xl, psil, Xb, psib), obs)

    prim = sampled_from_nodes(p, lay, nodes)
    one_l, one_b = jnp.ones(n_l), jnp.ones(n_b)
    zero_l, zero_b = jnp.zeros(n_l), jnp.zeros(n_b)
    r, dr_dX = jax.jvp(stage2, prim, (one_l, zero_l, one_b, zero_b))
    _, dr_dpsi = jax.jvp(stage2, prim, (zero_l, one_l, zero_b, one_b))
    tl, tb = _true_times(p, lay, lay.lug_t), _true_times(p, lay, lay.body_t)
    t_row = jnp.concatenate([tl, tl, tb, tb])
    sig_col = jnp.concatenate([lay.lug_i, lay.lug_i, jnp.zeros(2 * n_b, lay.lug_i.dtype)])
    sig_val = jnp.concatenate([dr_dpsi[:2 * n_l], jnp.zeros(2 * n_b)])

    # the remaining parameters: one forward derivative each through the samples' model,
    # the node values' tangent given (zero but for a replacing slip law's parameters)
    rest_idx = _rest_index(packing)

    def res_of(f, nd):
        return _residuals_from_nodes(f, fixed, lay, obs, packing, nd)

    if len(rest_idx):
        sl = packing.slices()
        node_idx = [sl[k].start for k in _node_params(lay, packing)]
        plain = np.array([i for i in rest_idx if i not in node_idx], np.int64)
        cols, order = [], []
        if len(plain):
            E = jnp.zeros((len(plain), n_par)).at[np.arange(len(plain)), plain].set(1.0)
            zero_nodes = tuple(jnp.zeros_like(a) for a in nodes)
            cols.append(jax.lax.map(
                lambda e: jax.jvp(res_of, (flat, nodes), (e, zero_nodes))[1], E))
            order.append(plain)
        if node_idx:
            ni = np.array(node_idx, np.int64)
            E = jnp.zeros((len(ni), n_par)).at[np.arange(len(ni)), ni].set(1.0)
            cols.append(jax.lax.map(
                lambda a: jax.jvp(res_of, (flat, nodes), (a[0], a[1]))[1],
                (E, shared["node_tan"])))
            order.append(ni)
        J_rest = jnp.concatenate(cols, 0)  # (n_rest, N): no transposed copy of it
        perm = np.argsort(np.concatenate(order))  # back to rest_idx's (packed) order
        if not np.array_equal(perm, np.arange(len(perm))):
            J_rest = J_rest[perm]
    else:
        J_rest = jnp.zeros((0, r.shape[0]))

    # prefix sums of the increments at every window start: the prefix at the first window
    # (shared) plus per-segment sums over the plan's own span of intervals, cumulated
    C = plan.ws.shape[0]
    span = plan.lseg.shape[0]
    icol = jax.lax.dynamic_slice_in_dim(shared["icol"], plan.l0, span, 0)
    seg_rows = plan.lseg[:, None] * nk + icol
    segX = jnp.zeros((C + 2) * nk).at[seg_rows].add(
        jax.lax.dynamic_slice_in_dim(shared["ix"], plan.l0, span, 0)).reshape(C + 2, nk)
    segP = jnp.zeros((C + 2) * nk).at[seg_rows].add(
        jax.lax.dynamic_slice_in_dim(shared["ipsi"], plan.l0, span, 0)).reshape(C + 2, nk)
    preX = shared["preX0"] + jnp.cumsum(segX[:C + 1], 0)[:-1]  # (C, nk)
    preP = shared["preP0"] + jnp.cumsum(segP[:C + 1], 0)[:-1]
    own = {"r": r, "dr_dX": dr_dX, "dr_dpsi": dr_dpsi, "t_row": t_row, "sig_col": sig_col,
           "sig_val": sig_val, "J_rest": J_rest, "preX": preX, "preP": preP}
    return own if pass_shared else _with_shared(own, shared)


#: what a time block's prepared buffers take from :func:`block_shared` unchanged (the
#: whole grid's banded derivatives): a compiled :func:`_prepare` returning them would hand
#: back COPIES of them (XLA outputs are new buffers), ~115 MB at 100 000 frames
_SHARED_KEYS = ("nx", "npsi", "ncol", "ix", "ipsi", "icol", "refX", "refP")


def _with_shared(own: dict, shared: dict) -> dict:
    """A time block's own prepared buffers with :func:`block_shared`'s arrays beside them."""
    return {**own, **{k: shared[k] for k in _SHARED_KEYS}}


def _rest_index(packing: Packing) -> np.ndarray:
    sl = packing.slices()
    rest = [k for k in packing.names if k not in KINEMATIC and k != "sigma0"]
    return (np.concatenate([np.arange(sl[k].start, sl[k].stop) for k in rest])
            if rest else np.zeros(0, np.int64))


def _chunk_jacobian(prep: dict, lay, packing: Packing, W: int, rows, mask, ws, pX, pP):
    """The Jacobian rows (R, p) of one time chunk (rows `rows`, zero where mask is 0)."""
    sl = packing.slices()
    n_par = sum(packing.sizes)
    nk = lay.n_coef + 2
    rest_idx = _rest_index(packing)
    kin_pos = _kinematic_positions(packing)
    sig_pos = jnp.asarray(np.arange(sl["sigma0"].start, sl["sigma0"].stop))
    (DX, DP, VX, VP), il, (w00, w10, w01, w11) = _window_nodes(prep, lay, rows, ws, W, nk)
    DX, DP = pX + DX, pP + DP
    dX = w00 * DX[il] + w10 * VX[il] + w01 * DX[il + 1] + w11 * VX[il + 1] - prep["refX"]
    dP = w00 * DP[il] + w10 * VP[il] + w01 * DP[il + 1] + w11 * VP[il + 1] - prep["refP"]
    kin = prep["dr_dX"][rows][:, None] * dX + prep["dr_dpsi"][rows][:, None] * dP
    Rn = rows.shape[0]
    Jc = jnp.zeros((Rn, n_par)).at[:, kin_pos].set(kin)
    Jc = Jc.at[jnp.arange(Rn), sig_pos[prep["sig_col"][rows]]].add(prep["sig_val"][rows])
    if len(rest_idx):
        Jc = Jc.at[:, rest_idx].set(prep["J_rest"][:, rows].T)
    return Jc * mask[:, None]


@eqx.filter_jit
def _prepare_compiled(flat, fixed, lay, obs, packing: Packing, plan: ChunkPlan, shared=None):
    return _prepare(flat, fixed, lay, obs, packing, plan, shared,
                    pass_shared=shared is not None)


def _prepare_jit(flat, fixed, lay, obs, packing: Packing, plan: ChunkPlan, shared=None):
    """:func:`_prepare`, compiled; a given `shared`'s arrays are passed through as they
    are (the same buffers), not returned by the compiled function."""
    prep = _prepare_compiled(flat, fixed, lay, obs, packing, plan, shared)
    return prep if shared is None else _with_shared(prep, shared)


@eqx.filter_jit
def _factors_jit(prep, lay, packing: Packing, plan: ChunkPlan, rows, mask, ws, cb, pX, pP):
    return _chunk_factors(prep, lay, packing, plan, rows, mask, ws, cb, pX, pP)


@eqx.filter_jit
def _chunk_jit(prep, lay, packing: Packing, W: int, rows, mask, ws, pX, pP):
    return _chunk_jacobian(prep, lay, packing, W, rows, mask, ws, pX, pP)


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


@eqx.filter_jit
def _contract_jit(prep, lay, packing: Packing, plan: ChunkPlan, v, with_A: bool):
    return contract(prep, lay, packing, plan, v, with_A)


def _hermite_weights(tau, h):
    t2, t3 = tau * tau, tau * tau * tau
    return (2 * t3 - 3 * t2 + 1, (t3 - 2 * t2 + tau) * h, -2 * t3 + 3 * t2, (t3 - t2) * h)


@eqx.filter_jit
def _normal_jit(flat, fixed, lay, obs, packing: Packing, plan: ChunkPlan, shared=None):
    return normal_equations(flat, fixed, lay, obs, packing, plan, shared=shared)


@eqx.filter_jit
def _chi2_jit(flat, fixed, lay, obs, packing: Packing):
    r = residuals(packing.unpack(flat, fixed), lay, obs)
    return jnp.sum(r * r)


@eqx.filter_jit
def _residuals_jit(flat, fixed, lay, obs, packing: Packing):
    return residuals(packing.unpack(flat, fixed), lay, obs)


@eqx.filter_jit
def _nodes_jit(flat, fixed, lay, packing: Packing):
    from ..model._model import integrate

    return integrate(packing.unpack(flat, fixed), lay)


@eqx.filter_jit
def nodes_batch(flats, fixed, lay, packing: Packing):
    """integrate()'s node values (X, psi, dX/dt, dpsi/dt) for a batch of parameter vectors
    (m, p) over the whole grid: 4 x (m, G)."""
    from ..model._model import integrate

    return jax.vmap(lambda f: integrate(packing.unpack(f, fixed), lay))(flats)


def _residuals_from_nodes(flat, fixed, lay, obs, packing: Packing, nodes):
    """:func:`residuals` of `flat` from the node values `nodes` of its integration."""
    return _weighted(predict_from_nodes(packing.unpack(flat, fixed), lay, nodes), obs)


@eqx.filter_jit
def _block_residuals_jit(flat, fixed, lay, obs, packing: Packing, nodes):
    return _residuals_from_nodes(flat, fixed, lay, obs, packing, nodes)


@eqx.filter_jit
def _block_chi2_jit(flat, fixed, lay, obs, packing: Packing, nodes):
    r = _residuals_from_nodes(flat, fixed, lay, obs, packing, nodes)
    return jnp.sum(r * r)


def blocked_residuals(flat, fixed, lay, obs, packing: Packing,
                      blocks: TimeBlocks | None) -> np.ndarray:
    """The weighted residuals (numpy) of the whole recording, one time block's model
    evaluation at a time (:func:`time_blocks`; the model's per-row temporaries of one
    block, the node values integrated once over the whole grid); the whole recording at
    once when `blocks` is None."""
    if blocks is None:
        return np.asarray(_residuals_jit(jnp.asarray(flat), fixed, lay, obs, packing))
    flat = jnp.asarray(flat)
    nodes = _nodes_jit(flat, fixed, lay, packing)
    out = np.zeros(2 * (lay.lug_t.shape[0] + lay.body_t.shape[0]))
    for lay_k, ob_k, rows_k in zip(blocks.lays, blocks.obss, blocks.rows):
        rk = np.asarray(_block_residuals_jit(flat, fixed, lay_k, ob_k, packing, nodes))
        real = rows_k >= 0
        out[rows_k[real]] = rk[real]
    return out


def blocked_chi2(flat, fixed, lay, obs, packing: Packing, blocks: TimeBlocks | None) -> float:
    """chi^2 of the weighted residuals, by time blocks as :func:`blocked_residuals` (the
    blocks' padding rows have zero weight and add nothing)."""
    if blocks is None:
        return float(_chi2_jit(jnp.asarray(flat), fixed, lay, obs, packing))
    flat = jnp.asarray(flat)
    nodes = _nodes_jit(flat, fixed, lay, packing)
    return float(sum(float(_block_chi2_jit(flat, fixed, lay_k, ob_k, packing, nodes))
                     for lay_k, ob_k in zip(blocks.lays, blocks.obss)))


def _solve_chunked(flat0, fixed, lay, obs, packing: Packing, plan: ChunkPlan, max_steps: int,
                   rtol: float, atol: float):
    """Levenberg-Marquardt on the chunked normal equations (Nielsen's damping update), in
    unit-column scaling from the start; ends on an accepted step below atol (unit columns)
    or rtol relative to the parameters, or one that no longer lowers chi^2 beyond rounding.

    The iteration runs in Python around three compiled kernels (normal equations, chi^2,
    residuals): each step costs a pass over the recording, so the loop's overhead is
    nothing, and one compilation of the pass serves every step. Returns
    (flat, J^T J, r, converged, steps)."""
    flat = np.asarray(flat0, float)
    bounded = "s0" in packing.names and "beta" in packing.names

    def bound(f):  # the physical range, as _solve keeps it (zero inside)
        pr, pj = _bound_jit(jnp.asarray(f), fixed, packing)
        return np.asarray(pr), np.asarray(pj)

    blocks = time_blocks(lay, obs)  # long recordings: one block's buffers at a time

    def ne(f):
        A, g, c2 = normal_blocks(f, fixed, lay, obs, packing, plan, blocks)
        if bounded:
            pr, pj = bound(f)
            A += pj.T @ pj
            g += pj.T @ pr
            c2 += float(pr @ pr)
        return A, g, c2

    def chi2(f):
        c2 = blocked_chi2(f, fixed, lay, obs, packing, blocks)
        if bounded:
            c2 += float(np.sum(bound(f)[0] ** 2))
        return c2

    A, g, c2 = ne(flat)
    d = np.sqrt(np.maximum(np.diag(A), 0.0))
    s = np.where(d > 0, 1.0 / np.where(d > 0, d, 1.0), 1.0)
    lam, nu, done, k = 1e-4, 2.0, False, 0
    eye = np.eye(len(flat))
    while not done and k < max_steps:
        k += 1
        As = A * np.outer(s, s)
        gs = g * s
        try:
            L = np.linalg.cholesky(As + lam * eye)
            dz = -_cho_solve(L, gs)
        except np.linalg.LinAlgError:
            lam, nu = lam * nu, nu * 2.0
            continue
        new = flat + dz * s
        c2n = chi2(new)
        pred = -(2.0 * gs @ dz + dz @ As @ dz)
        actual = c2 - c2n
        rho = actual / pred if pred > 0 else -1.0
        finite = np.isfinite(c2n) and np.all(np.isfinite(dz))
        small = np.max(np.abs(dz) / (atol + rtol * np.abs(flat / s))) < 1.0
        noise = abs(actual) <= 1e-13 * c2
        accept = finite and (rho > 1e-4 or small or (noise and np.max(np.abs(dz)) < 1e-3))
        if accept:
            flat = new
            done = bool(small or noise)
            lam *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            nu = 2.0
            A, g, c2 = ne(flat)
        else:
            lam, nu = lam * nu, nu * 2.0
    if bounded:  # J^T J of the data alone, as returned by the dense solver
        pj = bound(flat)[1]
        A -= pj.T @ pj
    r = blocked_residuals(flat, fixed, lay, obs, packing, blocks)
    return flat, A, r, done, k


def bound_residuals(p: dict):
    """The stiff one-sided penalties that keep the solvers inside the slip law's physical
    range, the posterior's prior (0 < beta <= beta_max(s0)): zero inside it, so that a
    recording that fixes beta fits exactly as without them."""
    b, bm = p["beta"], beta_max(p["s0"])
    ref = jnp.abs(bm) + 1e-12
    return jnp.concatenate([jnp.ravel(1e3 * jax.nn.relu(b - bm) / ref),
                            jnp.ravel(1e3 * jax.nn.relu(-b) / ref)])


@eqx.filter_jit
def _bound_jit(flat, fixed, packing: Packing):
    """bound_residuals of the free vector and their Jacobian (2, n), for the chunked solver."""
    def f(x):
        return bound_residuals(packing.unpack(x, fixed))

    return f(flat), jax.jacfwd(f)(flat)


def _cho_solve(L, b):
    from scipy.linalg import solve_triangular

    return solve_triangular(L.T, solve_triangular(L, b, lower=True), lower=False)


def covariance_normal(A: np.ndarray, rcond: float = 1e-12) -> np.ndarray:
    """:func:`covariance` from the normal matrix J^T J instead of J (same pseudo-inverse)."""
    A = np.asarray(A)
    s = inverse_norms(np.sqrt(np.maximum(np.diag(A), 0.0)))
    As = A * np.outer(s, s)
    w, V = np.linalg.eigh(As)
    inv = np.where(w > rcond * w.max(), 1.0 / np.where(w > 0, w, 1.0), 0.0)
    return (V * inv) @ V.T * np.outer(s, s)
