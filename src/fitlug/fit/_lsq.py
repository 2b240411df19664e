"""Weighted least squares with optimistix's Levenberg-Marquardt.

The free parameters are packed into one vector (:class:`fitlug.fit._residuals.Packing`)
and scaled so that every Jacobian column has unit norm at the start (LM's damping is
isotropic, and our parameters span 1e-9 (lens k1, per mm^2) to 1e2 (mm)); the trust region
starts at lambda = 1e-4 in those units. The damped step comes from the normal equations
(Cholesky), and the trust region accepts a step that ends the solve even when its
reduction ratio is rounding noise, and ends the solve where a nearly undamped step
changed chi^2 by rounding only (see :class:`._trust._RoundingAwareTrustRegion`). On the
reference recording: 6-7 steps a solve, 0.25 s warm, the same chi^2 to the last printed
digit as optimistix's stock LM (37 steps, 2 s). `throw=False` keeps the compiled
solver cacheable; the result code is checked here instead. Tolerances are in the
unit-column scale (a unit step moves the residual norm by about one sigma): atol 1e-6
stops far below any statistical relevance.

Long recordings (the dense Jacobian above LARGE_ENTRIES entries) never form J: their LM
(:func:`_solve_chunked`) runs on J^T J and J^T r accumulated in time chunks
(:func:`fitlug.fit._normal.normal_equations`), same optimum (1.7e-10 relative in the
parameters on the reference recording), memory linear in the samples. Above BLOCK_ROWS
residual rows the passes run by time blocks (:func:`fitlug.fit._chunks.time_blocks`): the
per-row buffers of one block at a time, the sums unchanged. Both solvers stay inside the
slip law's physical range (:func:`bound_residuals`).
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx

from .. import _exported
from . import _buckets
from ..model._physics import beta_max
from ._chunks import ChunkPlan, blocked_chi2, blocked_residuals, chunk_plan, chunkable, time_blocks
from ._normal import normal_blocks
from ._residuals import Packing, jacobian, residuals
from ._trust import _levenberg_marquardt, valid_dof


_START_GAIN = 100.0


def _column_scale(J):
    norms = jnp.sqrt(jnp.sum(J * J, axis=0))
    return jnp.where(norms > 0, 1.0 / jnp.where(norms > 0, norms, 1.0), 1.0)


def _with_structured_jacobian(fixed, lay, obs, packing: Packing):
    """f -> residuals of the free vector f, differentiated by the structured Jacobian.

    optimistix linearises the residual function at every step and materialises the
    Jacobian column by column (forward mode through the whole model, ~120 ms on the
    bundled recording's bucketed shapes); :func:`jacobian` gives the same matrix to
    rounding (3.6e-16 relative) at half that. The custom JVP makes the linearisation
    J(f) @ df, so materialising it is one product with the identity (exact: one nonzero
    term per entry)."""
    @jax.custom_jvp
    def r_of_flat(f):
        return residuals(packing.unpack(f, fixed), lay, obs)

    @r_of_flat.defjvp
    def _jvp(primals, tangents):
        (f,), (df,) = primals, tangents
        return r_of_flat(f), jacobian(f, fixed, lay, obs, packing) @ df

    return r_of_flat


@eqx.filter_jit
def _solve(flat0, fixed, lay, obs, mask, packing: Packing, max_steps: int, rtol: float,
           atol: float, gn_steps: int = 0):
    r_of_flat = _with_structured_jacobian(fixed, lay, obs, packing)

    # unit Jacobian columns, times _START_GAIN: optimistix's trust region starts at lambda = 1,
    # which is 1 / _START_GAIN^2 in unit columns (LM alone: mean 20 steps instead of 30 over
    # five recordings); tolerances kept in unit columns. `mask` (0: held at flat0) zeroes a
    # held element's column, which the damped normal equations leave at 0 (as a padded
    # bucket's): one program for every held set of this packing
    scale = _column_scale(jacobian(flat0, fixed, lay, obs, packing)) * _START_GAIN * mask
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
    solver = _levenberg_marquardt(rtol, atol, normal, dof=valid_dof(obs, mask))
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
    #: beta where the solver ended, before _onto_range (None: beta not fitted); see
    #: fitlug.fit._on_bound for what a projection by more than a hair means
    beta_solver: float | None = None


def least_squares(p0: dict, free, lay, obs, *, max_steps: int = 200, rtol: float = 1e-8,
                  atol: float = 1e-6, chunked: bool | None = None, hold=()) -> LsqOutput:
    """Minimise |residuals|^2 over the `free` parameters of `p0` (others held fixed).

    `hold`: names among `free` kept at their values in `p0`, in the compiled program of the
    fit that frees them (their columns masked: a new process loads one program, not two;
    the output's packing and J include them, J at the held values).

    Long recordings (dense Jacobian above LARGE_ENTRIES entries; `chunked` forces the
    choice) are solved on normal equations accumulated in time chunks: then the output's
    J is None and `normal` holds J^T J."""
    hold = [k for k in hold if k in free]
    packing = Packing.of(p0, free)
    fixed = {k: jnp.asarray(v, float) for k, v in p0.items() if k not in packing.names}
    n_res = 2 * (lay.lug_t.shape[0] + lay.body_t.shape[0])
    if chunked is None:
        chunked = n_res * sum(packing.sizes) > LARGE_ENTRIES
    if chunked and hold:  # the chunked solver is Python round kernels: no program to share
        return least_squares(p0, [k for k in free if k not in hold], lay, obs,
                             max_steps=max_steps, rtol=rtol, atol=atol, chunked=chunked)
    mask = np.concatenate([np.full(n, 0.0 if k in hold else 1.0)
                           for k, n in zip(packing.names, packing.sizes)])
    if chunked and chunkable(p0, lay, packing):
        flat, A, r, ok, steps = _solve_chunked(packing.pack(p0), fixed, lay, obs, packing,
                                               chunk_plan(lay), max_steps, rtol, 1e-9)
        b = _beta_of(np.asarray(flat), packing)
        flat = _onto_range(np.asarray(flat), packing)
        p = packing.unpack(flat, fixed)
        return LsqOutput(params=p, flat=flat, J=None, r=np.asarray(r),
                         converged=bool(ok), steps=int(steps), packing=packing,
                         normal=np.asarray(A), beta_solver=b)
    # through a module exported to disk: a new process skips the solver's tracing (~6 s);
    # on bucketed shapes (_buckets): a recording of a new length compiles nothing new
    pb = _buckets.pad(packing.pack(p0), fixed, lay, obs, packing)
    if pb is None:
        flat, J, r, ok, steps = _exported.call("lsq_solve", _solve,
                                               (packing, max_steps, rtol, atol),
                                               packing.pack(p0), fixed, lay, obs,
                                               jnp.asarray(mask))
    else:
        mask_b = np.ones(np.shape(pb.flat)[0])
        mask_b[pb.cols] = mask
        flat, J, r, ok, steps = _exported.call("lsq_solve", _solve,
                                               (pb.packing, max_steps, rtol, atol),
                                               pb.flat, pb.fixed, pb.lay, pb.obs,
                                               jnp.asarray(mask_b))
        flat, J, r = pb.flat_of(flat), pb.J_of(J), pb.r_of(r)
    # unpacked in numpy: jax slices compile once per (offset, size)
    b = _beta_of(np.asarray(flat), packing)
    flat = _onto_range(np.asarray(flat), packing)
    p = packing.unpack(flat, fixed)
    return LsqOutput(params=p, flat=flat, J=np.asarray(J), r=np.asarray(r),
                     converged=bool(ok), steps=int(steps), packing=packing, beta_solver=b)


def _beta_of(flat: np.ndarray, packing: Packing) -> float | None:
    """beta in the free vector `flat`, where the slip law's range applies (s0 and beta
    both fitted); else None."""
    if "beta" not in packing.names or "s0" not in packing.names:
        return None
    return float(flat[packing.slices()["beta"].start])


def _onto_range(flat: np.ndarray, packing: Packing) -> np.ndarray:
    """beta = ds/da onto its physical range beta >= 0 (k > 0; beta = 0 is the rigid limit).

    The solvers keep the range by a stiff one-sided penalty (bound_residuals), which a
    recording that does not fix beta (a cruise) balances a hair outside it: the issue saw
    beta = -9.7e-9. The projection moves beta by that hair (far inside its error), so
    that the least squares never reports a negative beta; its residuals and Jacobian are
    those of the solver's point. Where the hair is more than that (a gross misfit pulls
    beta far below 0) the caller refits with beta held at 0 (:mod:`._on_bound`)."""
    b = _beta_of(flat, packing)
    if b is not None and b < 0:
        flat = flat.copy()
        flat[packing.slices()["beta"].start] = 0.0
    return flat


#: the chunked path is used when the dense Jacobian would exceed this many entries
#: (32 MB; the reference recording has 0.9 M): below it the optimistix path is as fast
LARGE_ENTRIES = 4_000_000


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
