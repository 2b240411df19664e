"""Fitting many recordings of one rig with one compiled solver.

Every compiled program (the Levenberg-Marquardt solve, its Jacobian, the covariance) is
keyed by the shapes of its arrays and the layout's static fields, so recordings of one rig
that differ in length, number of samples or speed-spline knots each pay a compilation
(25-30 s cold). :func:`fit_many` gives each group of recordings that share the static
structure (markers of each role, lugs on the belt, frame rate, effects) common shapes,
rounded up to buckets so that later batches reuse the programs kept on disk:

- samples: the layout's lug and body samples are padded with weightless ones, pointing at
  one extra recording row whose position is NaN (so every later stage, the noise
  re-estimation and the glitch search included, sees a missing sample);
- integration grid: extended past the recording's end (nodes no sample reads);
- speed-spline knots: breakpoints inserted at the middle of the widest intervals inside
  the data, the start's speed carried over exactly (the old spline lies in the new
  space), so each fit is the recording's own model with a few more knots.

The results are then cut back to each recording's samples and grid: a FitResult of the
recording as :func:`fitlug.fit.fit` gives it, on the padded knots.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from ..model import _spline
from ..model._model import _speed_bases
from ._problem import Problem, build_problem

SAMPLE_BUCKET = 1024  # samples of each role, rounded up to a multiple
GRID_BUCKET = 256  # integration nodes
KNOT_BUCKET = 8  # speed-spline coefficients


def _up(n: int, b: int) -> int:
    return int(-(-max(n, 1) // b) * b)


def _signature(prob: Problem) -> tuple:
    lay = prob.lay
    return (lay.n_lug, lay.n_body, lay.n_belt, lay.n_contact, lay.L, round(lay.h, 12),
            lay.effects, prob.rec.sigma is None)


def _insert_breaks(br: np.ndarray, k_target: int, lo: float, hi: float) -> np.ndarray:
    """`br` with breakpoints inserted in the widest intervals inside [lo, hi] until the
    spline has k_target coefficients."""
    br = np.array(br, float)
    while _spline.n_coefficients(br) < k_target:
        mid = 0.5 * (br[1:] + br[:-1])
        width = np.where((mid > lo) & (mid < hi), np.diff(br), -1.0)
        i = int(np.argmax(width))
        br = np.insert(br, i + 1, mid[i])
    return br


def _speed_on(lay, c, t) -> np.ndarray:
    vals, first = _spline.banded(np.asarray(t), np.asarray(lay.breaks))
    c = np.asarray(c)
    return np.sum(vals * c[first[:, None] + np.arange(vals.shape[1])[None, :]], axis=1)


def pad_problem(prob: Problem, *, n_grid: int, n_coef: int, n_lug_samples: int,
                n_body_samples: int) -> Problem:
    """`prob` with the shapes given (see the module docstring); the fit is the same."""
    lay, rec, obs = prob.lay, prob.rec, dict(prob.obs)
    grid = np.asarray(lay.grid)
    t_lo, t_hi = float(np.min(rec.t)), float(np.max(rec.t))
    br = _insert_breaks(np.asarray(lay.breaks), n_coef, t_lo, t_hi)
    new_grid = grid[0] + lay.h * np.arange(n_grid)
    fine = np.linspace(grid[0], grid[-1], 8 * len(grid))
    v = _spline.fit_banded(fine, _speed_on(lay, prob.p0["v"], fine), br)
    lay = dataclasses.replace(lay, grid=jnp.asarray(new_grid), **_speed_bases(new_grid, lay.h, br))
    # one extra recording row, NaN: the padded samples point at it
    row = len(rec.t)
    extra = {"t": t_lo, "marker_index": prob.lug_ids[0] if prob.lug_ids else prob.body_ids[0],
             "x": np.nan, "y": np.nan, "sigma": np.nan, "frame": -1, "x_px": np.nan,
             "y_px": np.nan, "quality": np.nan}
    rec = rec.with_(**{k: np.r_[getattr(rec, k), np.asarray(v, getattr(rec, k).dtype)]
                       for k, v in extra.items() if getattr(rec, k) is not None})
    pads = {}
    for role, n, (tk, ik), keys in (("lug", n_lug_samples, ("lug_t", "lug_i"),
                                     ("lug_x", "lug_y", "lug_w")),
                                    ("body", n_body_samples, ("body_t", "body_j"),
                                     ("body_x", "body_y", "body_w"))):
        m = n - int(getattr(lay, tk).shape[0])
        pads[role] = m
        t0 = float(np.asarray(getattr(lay, tk))[0]) if getattr(lay, tk).shape[0] else t_lo
        pads[tk] = np.r_[np.asarray(getattr(lay, tk)), np.full(m, t0)]
        pads[ik] = np.r_[np.asarray(getattr(lay, ik)), np.zeros(m, np.int64)]
        for k in keys:
            obs[k] = jnp.asarray(np.r_[np.asarray(obs[k]), np.zeros(m)], float)
    lay = lay.with_times(pads["lug_t"], pads["lug_i"], pads["body_t"], pads["body_j"])
    p0 = {**prob.p0, "v": jnp.asarray(v)}
    return Problem(**{**prob.__dict__, "rec": rec, "lay": lay, "obs": obs, "p0": p0,
                      "lug_rows": np.r_[prob.lug_rows, np.full(pads["lug"], row)],
                      "body_rows": np.r_[prob.body_rows, np.full(pads["body"], row)]})


def unpad_result(res, orig: Problem):
    """`res` (a fit of a padded problem) on `orig`'s samples and grid."""
    prob = res.problem
    Sl, Sb = len(orig.lug_rows), len(orig.body_rows)
    Pl, Pb = len(prob.lug_rows), len(prob.body_rows)
    r = np.asarray(res.residuals)
    keep = np.r_[np.arange(Sl), Pl + np.arange(Sl), 2 * Pl + np.arange(Sb),
                 2 * Pl + Pb + np.arange(Sb)]
    lay = orig.lay.with_breaks(np.asarray(prob.lay.breaks))
    lay = dataclasses.replace(lay, n_belt=prob.lay.n_belt)
    obs = {k: (v[:Sl] if k.startswith("lug") else v[:Sb]) for k, v in prob.obs.items()}
    new = Problem(**{**prob.__dict__, "rec": orig.rec, "lay": lay, "obs": obs,
                     "lug_rows": orig.lug_rows, "body_rows": orig.body_rows,
                     "p0": {**orig.p0, "v": prob.p0["v"]}})
    return dataclasses.replace(res, problem=new, residuals=r[keep])


def fit_many(recordings, rig=None, *, effects=(), noise: dict | None = None,
             glitches: bool = True, **kw) -> list:
    """Fit many recordings of one rig, compiling the solver once per group of recordings
    that share their markers (and once more for later batches of similar sizes).

    Each recording is fitted as :func:`fitlug.fit.fit` fits it (noise re-estimation,
    glitches), on shapes padded to common sizes: a few more speed-spline knots than its
    own fit would place (inside the data), so its numbers agree with the one-by-one fit
    to well inside their errors, not bit for bit.

    Args:
        recordings: Recording objects (an iterable).
        rig: their Rig (default: the reference rig).
        effects, noise, glitches, **kw: as for :func:`fitlug.fit.fit`.

    Returns:
        One FitResult per recording, in order.

    Raises:
        InputError: a recording that cannot be fitted (naming it), before any fit runs.
        FitError: a fit that does not converge.
    """
    from ..io import Rig
    from ._fit import finish_fit, fit_problem

    rig = Rig.reference(assumed=True) if rig is None else rig
    recordings = list(recordings)
    probs = [build_problem(rec, rig, effects=effects, noise=noise) for rec in recordings]
    groups: dict = {}
    for i, p in enumerate(probs):
        groups.setdefault(_signature(p), []).append(i)
    out = [None] * len(probs)
    for idx in groups.values():
        g = [probs[i] for i in idx]
        shape = {
            "n_grid": _up(max(int(p.lay.grid.shape[0]) for p in g), GRID_BUCKET),
            "n_coef": _up(max(p.lay.n_coef for p in g), KNOT_BUCKET),
            "n_lug_samples": _up(max(int(p.lay.lug_t.shape[0]) for p in g), SAMPLE_BUCKET),
            "n_body_samples": _up(max(int(p.lay.body_t.shape[0]) for p in g), SAMPLE_BUCKET)}
        for i, prob in zip(idx, g):
            padded = pad_problem(prob, **shape)
            res = finish_fit(fit_problem(padded, **kw), prob, noise=noise, glitches=glitches,
                             **kw)
            out[i] = unpad_result(res, prob)
    return out
