"""Weighted least squares with optimistix's Levenberg-Marquardt.

The free parameters are packed into one vector and scaled so that every Jacobian column
has unit norm at the start (LM's damping is isotropic, and our parameters span 1e-9
(lens k1, per mm^2) to 1e2 (mm)). `throw=False` keeps the compiled solver cacheable;
the result code is checked here instead. Tolerances are in those scaled units (a unit
step moves the residual norm by about one sigma): atol 1e-6 stops far below any
statistical relevance, and halves the steps of 1e-9 with the same optimum.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from ..model import predict


def residuals(p: dict, lay, obs: dict):
    """Weighted residuals (model - data) / sigma, (2 S_l + 2 S_b,)."""
    lx, ly, bx, by = predict(p, lay)
    return jnp.concatenate([(lx - obs["lug_x"]) * obs["lug_w"], (ly - obs["lug_y"]) * obs["lug_w"],
                            (bx - obs["body_x"]) * obs["body_w"],
                            (by - obs["body_y"]) * obs["body_w"]])


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


def _column_scale(J):
    norms = jnp.sqrt(jnp.sum(J * J, axis=0))
    return jnp.where(norms > 0, 1.0 / jnp.where(norms > 0, norms, 1.0), 1.0)


@eqx.filter_jit
def _solve(flat0, fixed, lay, obs, packing: Packing, max_steps: int, rtol: float, atol: float):
    def r_of_flat(f):
        return residuals(packing.unpack(f, fixed), lay, obs)

    scale = _column_scale(jax.jacfwd(r_of_flat)(flat0))

    def fn(z, _):
        return r_of_flat(flat0 + z * scale)

    solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol)
    sol = optx.least_squares(fn, solver, jnp.zeros_like(flat0), max_steps=max_steps,
                             throw=False)
    flat = flat0 + sol.value * scale
    J = jax.jacfwd(r_of_flat)(flat)
    r = r_of_flat(flat)
    ok = sol.result == optx.RESULTS.successful
    return flat, J, r, ok, sol.stats["num_steps"]


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
