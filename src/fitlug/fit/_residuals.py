"""The fit's residuals and their exact Jacobian, and how the free parameters pack into one
vector (:class:`Packing`).

:func:`residuals` are the weighted residuals (model - data) / sigma of a parameter dict;
:func:`jacobian` is their exact Jacobian computed through the model's structure (2-3x
faster than jacfwd); the start scaling, the covariance and the explanation engine use it.
:func:`_residuals_from_nodes` evaluates the residuals from the node values of an
integration done once (the long recordings' time blocks).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..model import CATALOG, KINEMATIC, positions, predict, predict_from_nodes, sampled_kinematics


def residuals(p: dict, lay, obs: dict):
    """Weighted residuals (model - data) / sigma, (2 S_l + 2 S_b,)."""
    return _weighted(predict(p, lay), obs)


_residuals_jit = jax.jit(residuals)


def residuals_host(p: dict, lay, obs: dict) -> np.ndarray:
    """:func:`residuals` as one compiled program, numpy out (for host code: called eagerly,
    each of the model's operations is a program of its own, compiled once per shape)."""
    return np.asarray(_residuals_jit(p, lay, obs))


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
    # a marker below the pitch line (lug_shear) trails by a shear that depends on where
    # its lug touched down, sigma0 included: then sigma0 goes forward with the rest
    sig_direct = "sigma0" in sl and not any(
        getattr(CATALOG[e], "lug_lag", None) is not None for e in lay.effects)
    rest = [k for k in packing.names if k not in KINEMATIC
            and (k != "sigma0" or not sig_direct)]
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
    if sig_direct:  # u = sigma0[i] + psi: dr/dsigma0_i is dr/dpsi on marker i's rows
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
    return _in_packed_order(blocks, order)


def _in_packed_order(blocks, order):
    """The column blocks (block b holds the packed columns order[b]) as one matrix in
    packed order, from contiguous slices: a gather of every column by a permutation cost
    XLA ~30 ms (half the Jacobian) on the bundled recording; the values are the same."""
    runs = []  # (packed start, block, first column in block, count)
    for b, idx in enumerate(order):
        idx = np.asarray(idx)
        j = 0
        while j < len(idx):
            k = j
            while k + 1 < len(idx) and idx[k + 1] == idx[k] + 1:
                k += 1
            runs.append((int(idx[j]), b, j, k - j + 1))
            j = k + 1
    runs.sort()
    if len(runs) == 1:
        return blocks[runs[0][1]]
    return jnp.concatenate([blocks[b][:, j:j + n] for _, b, j, n in runs], axis=1)


#: the base model's parameters in the order the problem's start dict holds them
_CANONICAL = ("v", "s0", "beta", "R", "D", "e", "x_off", "y_off", "sigma0", "cx", "cy")


class Packing(NamedTuple):
    """How a parameter dict maps to the free vector (static)."""

    names: tuple
    shapes: tuple

    @classmethod
    def of(cls, p: dict, free) -> "Packing":
        """The free parameters of `p`, the base model's in their canonical order (the
        problem's start's), then the effects' in `p`'s order: the same parameters give
        the same packing, and so the same compiled programs, whatever order a dict that
        went through another stage holds them in (a refit from a result's parameters
        packed beta first and compiled the solver again)."""
        free = set(free)
        base = tuple(k for k in _CANONICAL if k in p and k in free)
        names = base + tuple(k for k in p if k in free and k not in _CANONICAL)
        return cls(names, tuple(tuple(np.shape(p[k])) for k in names))

    @property
    def sizes(self):
        return [int(np.prod(s)) if s else 1 for s in self.shapes]

    def pack(self, p: dict):
        vals = [p[k] for k in self.names]
        if any(isinstance(v, jax.core.Tracer) for v in vals):
            return jnp.concatenate([jnp.ravel(jnp.asarray(v, float)) for v in vals])
        # concrete values: in numpy (jnp ops on a new recording's shapes compile each)
        return jax.device_put(np.concatenate([np.ravel(np.asarray(v, float)) for v in vals]))

    def unpack(self, flat, fixed: dict) -> dict:
        out = dict(fixed)
        i = 0
        if isinstance(flat, jax.Array) and not isinstance(flat, jax.core.Tracer):
            # concrete values: sliced in numpy (a jnp slice compiles a program for each
            # offset and length, per new recording), the same values, on the device
            a = np.asarray(flat)
            for k, shape, n in zip(self.names, self.shapes, self.sizes):
                out[k] = jax.device_put(a[i:i + n].reshape(shape))
                i += n
            return out
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


def _residuals_from_nodes(flat, fixed, lay, obs, packing: Packing, nodes):
    """:func:`residuals` of `flat` from the node values `nodes` of its integration."""
    return _weighted(predict_from_nodes(packing.unpack(flat, fixed), lay, nodes), obs)
