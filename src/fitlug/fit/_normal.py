"""Long recordings: the normal equations accumulated in time chunks, bounded memory.

The dense Jacobian (2 S residuals x p parameters, and p grows with the duration through
the spline's knots) is never formed. One pass over time chunks of the residual rows builds
J^T J (p x p), J^T r and chi^2 (:func:`normal_equations`, by time blocks
:func:`normal_blocks`); a chunk's Jacobian rows need d(X, psi)/d theta only at the nodes
of its time window, which are the prefix sum up to the window's start (one dense vector
per chunk, from per-segment sums of the banded Simpson increments: :mod:`._chunk_prep`)
plus a local cumulative sum. The damped normal equations are then solved by a dense
Cholesky of the p x p matrix, in the same unit-column scaling as the optimistix path
(:func:`fitlug.fit._lsq._solve_chunked`). Also here: one chunk's Jacobian rows, dense
(:func:`_chunk_jacobian`) or as low-rank factors (:func:`_chunk_factors`), and J_a^T J_b
of two parameter vectors (:func:`contract_cross`).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._chunk_prep import _hermite_weights, _prepare, _rest_index, block_shared
from ._chunks import ChunkPlan, TimeBlocks, time_blocks, trim_heap
from ._residuals import Packing


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
def _factors_jit(prep, lay, packing: Packing, plan: ChunkPlan, rows, mask, ws, cb, pX, pP):
    return _chunk_factors(prep, lay, packing, plan, rows, mask, ws, cb, pX, pP)


@eqx.filter_jit
def _chunk_jit(prep, lay, packing: Packing, W: int, rows, mask, ws, pX, pP):
    return _chunk_jacobian(prep, lay, packing, W, rows, mask, ws, pX, pP)


@eqx.filter_jit
def _contract_jit(prep, lay, packing: Packing, plan: ChunkPlan, v, with_A: bool):
    return contract(prep, lay, packing, plan, v, with_A)


@eqx.filter_jit
def _normal_jit(flat, fixed, lay, obs, packing: Packing, plan: ChunkPlan, shared=None):
    return normal_equations(flat, fixed, lay, obs, packing, plan, shared=shared)
