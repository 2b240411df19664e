"""The batched, jitted model passes the posterior's marginal is made of: the Jacobian, and
chi^2 with the products J_k^T r of the residuals with the nuisance Jacobians at the step
model's points (dense, in time chunks, or on one time block from node values).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from .. import _jaxconfig  # noqa: F401
from ..fit._normal import contract, normal_equations
from ..fit._residuals import _residuals_from_nodes, jacobian, residuals


@eqx.filter_jit
def _jacobian(flat, fixed, lay, obs, packing):
    return jacobian(flat, fixed, lay, obs, packing)  # structured: same values as jacfwd


def _jacobian_tuple(flat, fixed, lay, obs, packing):
    return (_jacobian(flat, fixed, lay, obs, packing),)


@eqx.filter_jit
def _project_dense(flats, fixed, lay, obs, packing, Jes):
    """(chi^2, J_k^T r) of a batch of parameter vectors: r's |r|^2 (m,) and its products
    with the nuisance Jacobians at the step model's points, Jes (K, N, n_eta) -> (m, K,
    n_eta)."""
    def one(f):
        r = residuals(packing.unpack(f, fixed), lay, obs)
        return jnp.sum(r * r), jnp.einsum("kni,n->ki", Jes, r)

    return jax.vmap(one)(flats)


def _project_dense_tuple(flats, fixed, lay, obs, Jes, packing):
    """:func:`_project_dense` with the static packing last, for :func:`fitlug._exported.call`
    (a new process then skips its tracing and lowering: ~0.3 s CPU on the bundled
    recording; the same numbers)."""
    return _project_dense(flats, fixed, lay, obs, packing, Jes)


@eqx.filter_jit
def _project_chunked(flats, pts, rest, fixed, lay, obs, packing, plan):
    """:func:`_project_dense` with each J_k^T r from time chunks (no dense Jacobian); pts
    (K, p): the parameter vectors whose Jacobians are contracted."""
    def res_of(f):
        return residuals(packing.unpack(f, fixed), lay, obs)

    R = jax.vmap(res_of)(flats)  # (m, N)
    B = [normal_equations(pts[k], fixed, lay, obs, packing, plan, v=R, with_A=False)[1]
         for k in range(pts.shape[0])]
    return jnp.sum(R * R, axis=1), jnp.stack(B, axis=1)[:, :, rest]


@eqx.filter_jit
def _chi2_flats(flats, fixed, lay, obs, packing):
    def one(f):
        r = residuals(packing.unpack(f, fixed), lay, obs)
        return jnp.sum(r * r)

    return jax.vmap(one)(flats)


def _chi2_flats_tuple(flats, fixed, lay, obs, packing):
    """(:func:`_chi2_flats`,) for :func:`fitlug._exported.call`."""
    return (_chi2_flats(flats, fixed, lay, obs, packing),)


@eqx.filter_jit
def _project_block(flats, nodes, rest, fixed, lay, obs, packing, plan, prep):
    """(chi^2, J_eta^T r) of a batch of parameter vectors on one time block (summed over
    the blocks), from their node values and the block's buffers at one of the step model's
    points (`prep`). One point at a time: the residuals are evaluated again per point,
    but the K points' buffers and contractions held together raised the 100 000-frame
    whole run's peak from 1.74 to 1.90 GiB for 6 % of its time."""
    def res_of(f, nd):
        return _residuals_from_nodes(f, fixed, lay, obs, packing, nd)

    R = jax.vmap(res_of)(flats, nodes)  # (m, N_block)
    _, b = contract(prep, lay, packing, plan, v=R, with_A=False)
    return jnp.sum(R * R, axis=1), b[:, rest]


@eqx.filter_jit
def _chi2_block(flats, nodes, fixed, lay, obs, packing):
    """chi^2 of a batch of parameter vectors on one time block, from their node values."""
    def one(f, nd):
        r = _residuals_from_nodes(f, fixed, lay, obs, packing, nd)
        return jnp.sum(r * r)

    return jax.vmap(one)(flats, nodes)
