"""Layouts padded to bucketed shapes, which the model reads exactly as the originals
(issue 43, item 2: a recording of a new length compiles nothing new).

A compiled program is keyed by the shapes of its arrays and the layout's static fields, so
every recording with its own number of frames, samples, knots or markers used to compile
the model's programs afresh. :func:`bucket` rounds a size up to one of four steps per
octave (4, 5, 6, 7, 8, 10, 12, ..., at most 25 % more), and :func:`pad_layout` gives a
layout those sizes without changing a single model value at its real samples:

- grid nodes past the recording's end whose speed basis is zero (no sample's Hermite
  interval reaches them: the grid ends 3 frames past the last sample, and the cumulative
  sums only run forward);
- samples at a real sample's time and marker (their weights, set by the caller, are 0);
- speed-spline coefficients and markers that no sample reads (n_coef, n_lug, n_body: the
  caller pads the parameter vectors with values that nothing reads).

A layout whose effects read the whole integration grid (a ``lug_lag`` or ``memory`` hook)
keeps its grid.
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np

from ._model import Layout
from .effects import CATALOG

STEPS = 4  # sizes per octave


def bucket(n: int) -> int:
    """The smallest q 2^e >= n with q in {STEPS, ..., 2 STEPS - 1} (n itself below STEPS)."""
    n = int(n)
    if n <= STEPS:
        return max(n, 0)
    e = 0
    while (2 * STEPS) << e <= n:
        e += 1
    q = -(-n // (1 << e))  # ceil(n / 2^e), in STEPS .. 2 STEPS
    return q << e


#: hooks whose effects read the integration's nodes as a whole (a search over the belt
#: travel; a memory solved along it): their layouts keep their own grid
GRID_HOOKS = ("lug_lag", "memory")


def reads_grid(lay: Layout) -> bool:
    """Whether an effect of the layout reads the whole integration grid (GRID_HOOKS)."""
    return any(getattr(CATALOG[e], h, None) is not None for e in lay.effects
               for h in GRID_HOOKS)


def _rows(a, n: int, fill=0):
    a = np.asarray(a)
    pad = np.full((n - a.shape[0],) + a.shape[1:], fill, a.dtype)
    return jax.device_put(np.concatenate([a, pad]))


def pad_layout(lay: Layout, *, n_grid: int, n_coef: int, n_lug_samples: int,
               n_body_samples: int, n_lug: int, n_body: int) -> Layout:
    """`lay` with the sizes given (each at least the layout's own; see the module
    docstring). The padded samples sit at the first real sample's time and marker."""
    grid = np.asarray(lay.grid)
    G = grid.shape[0]
    if n_grid != G and reads_grid(lay):
        raise ValueError("a layout whose effects read the grid keeps its grid")
    ext = grid[-1] + float(lay.h) * np.arange(1, n_grid - G + 1)
    br = np.asarray(lay.breaks)
    br = np.concatenate([br, np.full(n_coef - lay.n_coef, br[-1] if len(br) else 0.0)])
    t0 = float(np.asarray(lay.t_ref))
    lug_t0 = float(np.asarray(lay.lug_t)[0]) if lay.lug_t.shape[0] else t0
    body_t0 = float(np.asarray(lay.body_t)[0]) if lay.body_t.shape[0] else t0
    return dataclasses.replace(
        lay, grid=jax.device_put(np.concatenate([grid, ext])),
        Bn=_rows(lay.Bn, n_grid), dBn=_rows(lay.dBn, n_grid), jn=_rows(lay.jn, n_grid),
        Bm=_rows(lay.Bm, n_grid - 1), dBm=_rows(lay.dBm, n_grid - 1),
        jm=_rows(lay.jm, n_grid - 1),
        lug_t=_rows(lay.lug_t, n_lug_samples, lug_t0),
        lug_i=_rows(lay.lug_i, n_lug_samples, np.asarray(lay.lug_i)[0]
                    if lay.lug_i.shape[0] else 0),
        body_t=_rows(lay.body_t, n_body_samples, body_t0),
        body_j=_rows(lay.body_j, n_body_samples, np.asarray(lay.body_j)[0]
                     if lay.body_j.shape[0] else 0),
        breaks=jax.device_put(br), n_coef=int(n_coef), n_lug=int(n_lug), n_body=int(n_body))
