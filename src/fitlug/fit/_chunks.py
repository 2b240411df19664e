"""Long recordings cut in time: the chunk plans of the normal equations' passes
(:class:`ChunkPlan`), the time blocks a pass runs by (:class:`TimeBlocks`), the model
evaluated one time block at a time (:func:`blocked_residuals`, :func:`blocked_chi2`), the
test of whether the chunked path applies (:func:`chunkable`), the size thresholds, and the
memory handling of the long passes (:func:`return_freed_memory`, :func:`trim_heap`).
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._residuals import Packing, _residuals_from_nodes, residuals


#: node intervals per time chunk, and the margin each chunk's window adds on both sides
#: (a time-mapped sample may move by a frame: substeps intervals)
CHUNK_INTERVALS = 1024
_MARGIN = 16


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
    i0 = np.clip(np.floor((t_row - grid[0]) / float(lay.h)).astype(np.int64), 0, G - 2)
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


def chunkable(p: dict, lay, packing: Packing) -> bool:
    """Whether the chunked normal equations apply: speed spline, s0, beta and sigma0 free,
    no belt-locked speed modulation (which makes psi's ODE non-local in theta) and no lug
    marker below the pitch line away from h = 1 (its lag reads where its lug touched
    down)."""
    from ..model._model import _hook

    return (all(k in packing.names for k in ("v", "s0", "beta", "sigma0"))
            and not _hook(lay, "speed") and not _remembering(p, lay)
            and not _lagging(p, lay))


def _remembering(p: dict, lay) -> bool:
    """Whether the slip's memory (lug_memory, lambda above its identity threshold) makes
    the belt travel at a time depend on the motion a contact length before: not local."""
    from ..model._model import _hook
    from ..model.effects._lug_memory import LAMBDA_MIN

    mem = _hook(lay, "memory")
    if not mem:
        return False
    try:
        return float(np.asarray(sum(f(p) for f in mem))) > LAMBDA_MIN
    except (TypeError, ValueError):  # a traced value: cannot tell, so not chunkable
        return True


def _lagging(p: dict, lay) -> bool:
    """Whether a lug marker below the pitch line (lug_shear at h != 1) makes a sample's
    position depend on the motion where its lug touched down: not local in time."""
    from ..model._model import _hook

    if not _hook(lay, "lug_lag"):
        return False
    try:
        return float(np.asarray(p.get("shear_h", 1.0))) != 1.0
    except (TypeError, ValueError):  # a traced value: cannot tell, so not chunkable
        return True


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
