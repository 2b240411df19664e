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
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx

from ..model import KINEMATIC, positions, predict, sampled_kinematics


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

    def fn(z, _):
        return r_of_flat(flat0 + z * scale)

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


def least_squares(p0: dict, free, lay, obs, *, max_steps: int = 200, rtol: float = 1e-8,
                  atol: float = 1e-6) -> LsqOutput:
    """Minimise |residuals|^2 over the `free` parameters of `p0` (others held fixed)."""
    packing = Packing.of(p0, free)
    fixed = {k: jnp.asarray(v, float) for k, v in p0.items() if k not in packing.names}
    flat, J, r, ok, steps = _solve(packing.pack(p0), fixed, lay, obs, packing, max_steps,
                                   rtol, atol)
    p = packing.unpack(flat, fixed)
    return LsqOutput(params=p, flat=np.asarray(flat), J=np.asarray(J), r=np.asarray(r),
                     converged=bool(ok), steps=int(steps), packing=packing)


def covariance(J: np.ndarray, rcond: float = 1e-12) -> np.ndarray:
    """(J^T J)^-1 with a pseudo-inverse for directions the data do not constrain."""
    s = 1.0 / np.maximum(np.sqrt(np.sum(J * J, 0)), 1e-300)
    A = (J * s).T @ (J * s)
    w, V = np.linalg.eigh(A)
    inv = np.where(w > rcond * w.max(), 1.0 / np.where(w > 0, w, 1.0), 0.0)
    return (V * inv) @ V.T * np.outer(s, s)
