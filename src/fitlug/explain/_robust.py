"""Standard errors that stay honest when a mismatch is left unexplained.

Least-squares errors assume white residuals. When the residuals keep a systematic part
that no catalog effect explains, the slip can be biased by far more than those errors.
The cluster-robust (sandwich) covariance H^-1 (sum_g s_g s_g^T) H^-1 G/(G-1), with
H = J^T J and s_g = J_g^T r_g the score of cluster g, lets each cluster's residuals be
arbitrarily correlated: clusters by marker cover a misfit carried by a few markers
(one marker shifting on its lug), clusters by time block a misfit shared by all
markers at some times (a disturbance of the whole image). Each quantity takes the
largest of the least-squares, by-marker and by-time-block standard errors, and then
carries in quadrature the shift the misfit can cause through the speed profile
(:mod:`._speed`: a refit with a free speed spline), which no sandwich sees when the
misfit does not average out.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from ..fit import covariance as _covariance_dense
from ..fit._lsq import RowChunks, covariance_normal
from ..fit._result import compute_quantities
from ._engine import jacobian_of
from ._speed import speed_sensitivity
from ._table import Geometry

BLOCK_S = 0.5


def covariance(J) -> np.ndarray:
    """fitlug.fit.covariance of a dense Jacobian, or from J^T J of its time chunks."""
    if isinstance(J, RowChunks):
        return covariance_normal(J.normal(np.zeros((len(J.r), 0)))[0])
    return _covariance_dense(J)


def _sandwich(J, r, labels, Hinv):
    groups = np.unique(labels)
    G = len(groups)
    if G < 2:
        return None
    if isinstance(J, RowChunks):  # long recording: the scores summed chunk by chunk
        pos = np.searchsorted(groups, labels)
        scores = np.zeros((G, J.n_par))
        for rows, Jc in J:
            order = np.argsort(pos[rows], kind="stable")
            ps = pos[rows][order]
            starts = np.flatnonzero(np.r_[True, ps[1:] != ps[:-1]])
            scores[ps[starts]] += np.add.reduceat((Jc * r[rows, None])[order], starts, 0)
        S = scores.T @ scores
        return Hinv @ S @ Hinv * (G / (G - 1))
    S = np.zeros((J.shape[1], J.shape[1]))
    for g in groups:
        sel = labels == g
        s = J[sel].T @ r[sel]
        S += np.outer(s, s)
    return Hinv @ S @ Hinv * (G / (G - 1))


def robust_result(res, geo: Geometry):
    """A copy of `res` whose quantities carry cluster-robust standard errors.

    Returns (result, method) where method names the covariance that set the slip's error.
    result.robust records what the posterior needs to widen itself consistently:
    {"method", "clusters" (number of clusters of that covariance, None for least squares),
    "cov" (that covariance of the free parameters, packing order), "covs" (every robust
    covariance with its number of clusters),
    "naive_std" and "robust_std" (quantity -> standard error)}.
    """
    prob = res.problem
    fixed = {k: jnp.asarray(v, float) for k, v in res.params.items()
             if k not in res.packing.names}
    J = jacobian_of(res.flat, fixed, res.packing, prob.lay, prob.obs)  # or its time chunks
    r = np.where(geo.valid, np.asarray(res.residuals), 0.0)
    Hinv = covariance(J)
    blocks = np.floor((geo.t - geo.t_lo) / BLOCK_S).astype(int)
    covs = {"least squares": res.cov,
            "cluster-robust by marker": _sandwich(J, r, geo.marker, Hinv),
            "cluster-robust by time block": _sandwich(J, r, blocks, Hinv)}
    clusters = {"least squares": None,
                "cluster-robust by marker": int(len(np.unique(geo.marker[geo.valid]))),
                "cluster-robust by time block": int(len(np.unique(blocks[geo.valid])))}
    fixed_np = {k: v for k, v in res.params.items() if k not in res.packing.names}
    qs = {}
    for name, C in covs.items():
        if C is not None:
            qs[name] = compute_quantities(res.params, res.packing, res.flat, C, prob.lay,
                                          prob.rig.mass_kg, fixed_np,
                                          prob.rig.drawbar_pull_N)
    out = {}
    for k, est in res.quantities.items():
        best = max(qs, key=lambda n: (qs[n][k].std or 0.0))
        out[k] = dataclasses.replace(qs[best][k], ci95=None)  # interval from the new std
    method = cov_method = max(qs, key=lambda n: (qs[n]["slip"].std or 0.0))
    speed = speed_sensitivity(res)
    if speed is not None:
        for k, d in speed["shift"].items():
            if k in out and out[k].std is not None and np.isfinite(out[k].std):
                out[k] = dataclasses.replace(out[k], std=float(np.hypot(out[k].std, d)),
                                             ci95=None)
        method += " + speed-profile sensitivity"
    return _widened(res, out, method=cov_method, clusters=clusters[cov_method],
                    cov=covs[cov_method],
                    covs={n: (covs[n], clusters[n]) for n in qs if n != "least squares"},
                    speed_sensitivity=speed, label=method,
                    uncertainty_method=f"least squares, {method} errors (unexplained misfit)"
                    ), method


def _widened(res, out: dict, **info):
    """`res` with the quantities `out` and, in res.robust, what the posterior needs to
    widen itself consistently (`info` plus each quantity's naive and widened error)."""
    info.update(naive_std={k: e.std for k, e in res.quantities.items()},
                robust_std={k: e.std for k, e in out.items()})
    return dataclasses.replace(res, quantities=out, robust=info)


def nuisance_result(res, sysb: dict):
    """A copy of `res` whose quantities carry the tracker-systematics nuisance: each error
    is the larger of the least-squares one and the one with the nuisance fitted beside the
    model (sysb["_cov"], from explain._systematics)."""
    C = sysb.get("_cov")
    if C is None or not np.all(np.isfinite(C)):
        return res
    prob = res.problem
    fixed_np = {k: v for k, v in res.params.items() if k not in res.packing.names}
    q = compute_quantities(res.params, res.packing, res.flat, C, prob.lay, prob.rig.mass_kg,
                           fixed_np, prob.rig.drawbar_pull_N)
    out = {}
    for k, est in res.quantities.items():
        alt = q.get(k)
        if alt is not None and alt.std is not None and est.std is not None \
                and np.isfinite(alt.std) and alt.std > est.std:
            out[k] = dataclasses.replace(est, std=float(alt.std), ci95=None)
        else:
            out[k] = est
    method = "least squares with the tracker-systematics nuisance carried"
    return _widened(res, out, method=method, clusters=None, cov=0.5 * (C + C.T), covs={},
                    speed_sensitivity=None, label=method,
                    uncertainty_method=method + " (per-marker-per-segment offsets and speed "
                                                "terms fitted beside the model: a "
                                                "measurement floor)")
