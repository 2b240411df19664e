"""What every time chunk's Jacobian rows need, computed once per parameter vector
(:func:`_prepare`): the residuals and their derivatives along X and psi, the columns of
the few non-kinematic parameters, the banded derivatives of the node rates and Simpson
increments with respect to the kinematic columns (:func:`_kinematic_bands`) and their
prefix sums per chunk; and what the time blocks of one pass share over the whole grid
(:func:`block_shared`). The contraction of these buffers is :mod:`._normal`'s.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..model import CATALOG, KINEMATIC, positions
from ._chunks import ChunkPlan
from ._residuals import Packing, _residuals_from_nodes, _weighted


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


@eqx.filter_jit
def _prepare_compiled(flat, fixed, lay, obs, packing: Packing, plan: ChunkPlan, shared=None):
    return _prepare(flat, fixed, lay, obs, packing, plan, shared,
                    pass_shared=shared is not None)


def _prepare_jit(flat, fixed, lay, obs, packing: Packing, plan: ChunkPlan, shared=None):
    """:func:`_prepare`, compiled; a given `shared`'s arrays are passed through as they
    are (the same buffers), not returned by the compiled function."""
    prep = _prepare_compiled(flat, fixed, lay, obs, packing, plan, shared)
    return prep if shared is None else _with_shared(prep, shared)


def _hermite_weights(tau, h):
    t2, t3 = tau * tau, tau * tau * tau
    return (2 * t3 - 3 * t2 + 1, (t3 - 2 * t2 + tau) * h, -2 * t3 + 3 * t2, (t3 - t2) * h)
