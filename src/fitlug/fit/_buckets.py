"""A fit's compiled programs called on bucketed shapes (issue 43, item 2).

:func:`pad` turns (free vector, fixed parameters, layout, observations, packing) into the
same problem on bucketed sizes (:func:`fitlug.model._buckets.bucket`: frames, samples of
each role, speed-spline knots, markers of each role), so that a recording of a new length
of a kind already seen runs the programs already compiled (in memory, in JAX's persistent
cache and as exported modules, :mod:`fitlug._exported`). What is padded contributes
exactly nothing:

- padded samples have weight 0: their residuals and Jacobian rows are exact zeros;
- padded speed coefficients, marker phases (sigma0) and body offsets (cx, cy) are read by
  no sample: their Jacobian columns are exact zeros; a Levenberg-Marquardt step leaves
  them at 0 (its normal equations decouple them: J^T r is 0 there) and they are cut out
  of every result (:meth:`Padded.flat_of`, :meth:`Padded.J_of`, :meth:`Padded.r_of`);
- padded grid nodes lie past the recording's end, where no sample reads them.

The numbers agree with the unpadded programs' to rounding (the sums' order changes with
their lengths; tests/test_buckets.py). FITLUG_NO_BUCKETS=1 turns it off.
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import dataclass

import jax
import numpy as np

from ..model._buckets import bucket, pad_layout, reads_grid
from ._residuals import Packing

#: parameters with one entry per speed coefficient, lug marker and body marker
_AXES = {"v": "n_coef", "sigma0": "n_lug", "cx": "n_body", "cy": "n_body"}


#: samples (both roles) above which nothing is padded: a long recording's passes run in
#: time blocks of one compiled shape already, its compiles are a small part of its run, and
#: a padded copy of its sample arrays would add to the memory its stages are held to
LONG_SAMPLES = 200_000
_FLOOR: dict = {}  # sizes at least this large (fit_many: one shape per group)


def enabled(lay=None) -> bool:
    """Whether to pad (FITLUG_NO_BUCKETS=1 turns it off; so does a long recording)."""
    if lay is not None and lay.lug_t.shape[0] + lay.body_t.shape[0] > LONG_SAMPLES:
        return False
    return os.environ.get("FITLUG_NO_BUCKETS") != "1"


@contextlib.contextmanager
def at_least(floor: dict):
    """Within the block, every size is at least floor's (:func:`sizes`' keys): the
    recordings of a batch share one shape (:func:`fitlug.fit.fit_many`)."""
    old = dict(_FLOOR)
    _FLOOR.update(floor)
    try:
        yield
    finally:
        _FLOOR.clear()
        _FLOOR.update(old)


@dataclass(frozen=True)
class Padded:
    """A problem on bucketed shapes, and where its real entries sit."""

    flat: object  # padded free vector (jnp)
    fixed: dict
    lay: object
    obs: dict
    packing: Packing
    cols: np.ndarray  # padded index of each real free parameter
    rows: np.ndarray  # padded index of each real residual row

    def flat_of(self, flat_b) -> np.ndarray:
        return np.asarray(flat_b)[self.cols]

    def J_of(self, J_b) -> np.ndarray:
        return np.asarray(J_b)[np.ix_(self.rows, self.cols)]

    def r_of(self, r_b) -> np.ndarray:
        return np.asarray(r_b)[self.rows]


def sizes(lay) -> dict:
    """The bucketed sizes of `lay`'s programs."""
    G = int(lay.grid.shape[0])
    out = {"n_grid": bucket(G), "n_coef": bucket(lay.n_coef),
           "n_lug_samples": bucket(lay.lug_t.shape[0]),
           "n_body_samples": bucket(lay.body_t.shape[0]),
           "n_lug": bucket(lay.n_lug), "n_body": bucket(lay.n_body)}
    out = {k: max(v, int(_FLOOR.get(k, 0))) for k, v in out.items()}
    if reads_grid(lay):
        out["n_grid"] = G
    return out


def _pad_param(v, n: int):
    v = np.asarray(v, float)
    return jax.device_put(np.concatenate([v, np.zeros(n - v.shape[0])]))


def pad(flat, fixed: dict, lay, obs: dict, packing: Packing) -> Padded | None:
    """The problem on bucketed shapes, or None (turned off, or a parameter whose shape is
    not the layout's count: then the caller runs the problem as it is)."""
    if not enabled(lay):
        return None
    sz = sizes(lay)
    p = packing.unpack(np.asarray(flat, float), {})
    both = {**fixed, **p}
    for k, axis in _AXES.items():
        if k in both and np.shape(both[k]) != (int(getattr(lay, axis)),):
            return None
    names, shapes, cols, at = [], [], [], 0
    new_p = {}
    for k, shape, n in zip(packing.names, packing.shapes, packing.sizes):
        if k in _AXES:
            nb = sz[_AXES[k]]
            new_p[k] = _pad_param(p[k], nb)
            shapes.append((nb,))
            cols.append(at + np.arange(n))
            at += nb
        else:
            new_p[k] = p[k]
            shapes.append(shape)
            cols.append(at + np.arange(n))
            at += n
        names.append(k)
    pk = Packing(tuple(names), tuple(shapes))
    fixed_b = {k: (_pad_param(v, sz[_AXES[k]]) if k in _AXES else v)
               for k, v in fixed.items()}
    Sl, Sb = int(lay.lug_t.shape[0]), int(lay.body_t.shape[0])
    Pl, Pb = sz["n_lug_samples"], sz["n_body_samples"]
    obs_b = {k: jax.device_put(np.concatenate([np.asarray(v, float),
                                            np.zeros((Pl if k.startswith("lug") else Pb)
                                                     - np.shape(v)[0])]))
             for k, v in obs.items()}
    rows = np.concatenate([np.arange(Sl), Pl + np.arange(Sl), 2 * Pl + np.arange(Sb),
                           2 * Pl + Pb + np.arange(Sb)])
    return Padded(flat=pk.pack(new_p), fixed=fixed_b, lay=pad_layout(lay, **sz), obs=obs_b,
                  packing=pk, cols=np.concatenate(cols) if cols else np.zeros(0, int),
                  rows=rows)


def pad_model(p: dict, lay, like=None):
    """(params, layout) of a model evaluation on bucketed shapes, or None (as :func:`pad`):
    the samples bucketed by their own counts, the rest by `like`'s (default `lay`: a
    layout of the same recording at other times, e.g. the report's curves, shares its
    grid, knots and markers). The outputs' first entries are the real samples'."""
    if not enabled(lay):
        return None
    sz = sizes(lay if like is None else like)
    for k, axis in _AXES.items():
        if k in p and np.shape(p[k]) != (int(getattr(lay, axis)),):
            return None
    sz.update(n_lug_samples=bucket(lay.lug_t.shape[0]),
              n_body_samples=bucket(lay.body_t.shape[0]))
    p_b = {k: (_pad_param(v, sz[_AXES[k]]) if k in _AXES else v) for k, v in p.items()}
    return p_b, pad_layout(lay, **sz)
