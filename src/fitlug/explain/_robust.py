"""Standard errors that stay honest when a mismatch is left unexplained.

Least-squares errors assume white residuals. When the residuals keep a systematic part
that no catalog effect explains, the slip can be biased by far more than those errors.
The robust (sandwich) covariance H^-1 Omega H^-1, with H = J^T J and Omega an estimate of
the variance of the total score J^T r, lets the residuals be correlated in two ways:

- by marker: Omega = sum_g s_g s_g^T G/(G-1), s_g = J_g^T r_g the score of marker g
  (cluster-robust; covers a misfit carried by a few markers, e.g. one marker shifting on
  its lug, however long it lasts);
- in time: Omega = 4/3 sum_w s_w s_w^T G/(G-1), s_w the score of the samples in a Hann
  window w of WINDOW_S, the windows overlapping by half (a Welch-type long-run variance
  of the score; covers a misfit shared by all markers at some times, a disturbance of the
  whole image). The two window families sum to one at every time (sin^2 + cos^2), and
  their squared weights average 3/4, hence 4/3. Rectangular blocks of the same length,
  used before, hold less of a disturbance correlated over a few frames (0.46 against
  0.64 of the true variance: tests/test_uncertainty.py). A disturbance coherent over the
  whole recording (a camera vibration at one frequency) is the opposite case: its scores
  cancel from window to window, which no local estimate sees, and the errors of k and
  C_rr it affects little come out several times too wide.

First, though, a measurement nuisance that holds the whole misfit (a camera that shook,
a marker knocked on its lug: :mod:`._nuisance`) is taken out of the data and the model
refitted (:func:`taken_out`); no sandwich is needed then. Otherwise each quantity takes
the largest of the least-squares, by-marker and in-time standard
errors (the largest of three noisy variance estimates is also what covers the small
number of clusters: bench_coverage's out-of-catalog rows), and then carries in quadrature
the shift the misfit can cause through the speed profile (:mod:`._speed`: a refit with a
free speed spline), which no sandwich sees when the misfit does not average out.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from ..fit import covariance as _covariance_dense
from ..fit._covariance import covariance_normal
from ..fit._rowchunks import RowChunks
from ..fit._result import compute_quantities
from ._criterion import GROSS_CHI2
from ._detect import ALPHA
from ._engine import jacobian_of
from ._image_motion import ImageMotion
from ._marker_shift import MarkerShift
from ._nuisance import holds, search
from ._speed import cannot_hold, speed_sensitivity
from ._straight import far_from_data, straight_runs_slip
from ._table import Geometry

WINDOW_S = 0.5  # s, the Hann windows of the in-time sandwich
TIME = f"robust in time (Hann windows of {WINDOW_S:g} s)"
NUISANCES = (ImageMotion, MarkerShift)


def covariance(J) -> np.ndarray:
    """fitlug.fit.covariance of a dense Jacobian, or from J^T J of its time chunks."""
    if isinstance(J, RowChunks):
        return covariance_normal(J.normal(np.zeros((J.n_rows, 0)))[0])
    return _covariance_dense(J)


def _scores(J, r, labels, weights=None) -> np.ndarray:
    """(G, p): sum over the rows of each cluster of weight * J_row * r_row, the clusters
    being the distinct `labels` (rows with r = 0 add nothing)."""
    groups, pos = np.unique(labels, return_inverse=True)
    w = r if weights is None else r * weights
    scores = np.zeros((len(groups), J.n_par if isinstance(J, RowChunks) else J.shape[1]))
    if isinstance(J, RowChunks):  # long recording: the scores summed chunk by chunk
        for rows, Jc in J:
            _add_by(scores, pos[rows], Jc * w[rows, None])
    else:
        _add_by(scores, pos, np.asarray(J) * w[:, None])
    return scores


def _add_by(out, pos, X):
    order = np.argsort(pos, kind="stable")
    ps = pos[order]
    if not len(ps):
        return
    starts = np.flatnonzero(np.r_[True, ps[1:] != ps[:-1]])
    out[ps[starts]] += np.add.reduceat(X[order], starts, 0)


def _sandwich(J, r, labels, Hinv):
    """Cluster-robust covariance, clusters = distinct labels (None below 2 clusters)."""
    scores = _scores(J, r, labels)
    scores = scores[np.any(scores != 0, axis=1)]  # clusters with no valid sample
    G = len(scores)
    if G < 2:
        return None
    return Hinv @ (scores.T @ scores) @ Hinv * (G / (G - 1))


def windows_in_time(t, t_lo: float, window_s: float = WINDOW_S):
    """The two half-overlapping families of Hann windows: [(labels, weights), ...] with
    the weights of a sample summing to one over the families."""
    ph = (np.asarray(t, float) - t_lo) / window_s
    out = []
    for off in (0.0, 0.5):
        q = ph + off
        g = np.floor(q)
        out.append((g.astype(int), np.sin(np.pi * (q - g)) ** 2))
    return out


def _in_time(J, r, t, t_lo: float, Hinv, window_s: float = WINDOW_S):
    """Robust covariance for a misfit correlated in time (all markers together), from the
    scores of half-overlapping Hann windows; (cov, number of windows of one family)."""
    meat, G = 0.0, None
    for labels, w in windows_in_time(t, t_lo, window_s):
        sc = _scores(J, r, labels, w)
        sc = sc[np.any(sc != 0, axis=1)]
        meat = meat + sc.T @ sc
        G = len(sc) if G is None else min(G, len(sc))
    if not G or G < 2:
        return None, G
    return Hinv @ meat @ Hinv * (4.0 / 3.0) * (G / (G - 1)), G


def robust_result(res, geo: Geometry, alpha: float = ALPHA):
    """A copy of `res` whose quantities carry cluster-robust standard errors.

    Returns (result, method) where method names the covariance that set the slip's error.
    result.robust records what the posterior needs to widen itself consistently:
    {"method", "clusters" (number of clusters of that covariance, None for least squares),
    "cov" (that covariance of the free parameters, packing order), "covs" (every robust
    covariance with its number of clusters),
    "naive_std" and "robust_std" (quantity -> standard error)}.
    """
    prob = res.problem
    J, r = _jacobian_residuals(res, geo)
    sig_est = prob.noise_source in ("differences", "residual differences")
    for kind in NUISANCES:  # a measurement nuisance that holds the whole misfit: taken out
        try:
            found = search(kind, res, geo, J, r, alpha=alpha, sigma_estimated=sig_est)
        except Exception:  # noqa: BLE001 - a failed search leaves the sandwich errors
            found = None
        done = taken_out(res, geo, found) if found is not None else None
        if done is not None:
            return done
    why: list = []  # the straight runs' reason for giving no reading
    straight = straight_headline(res, why)
    # where the slip is read off the straight runs and no speed profile can hold the misfit
    # (the body's own y floors it), the free-speed refit would only widen the geometry's
    # errors: not made (15 s of an engine recording's 60)
    speed = None if straight is not None and cannot_hold(res) else speed_sensitivity(res)
    if speed is not None and holds(geo, speed["_fit"].residuals, speed["_fit"].dof,
                                   alpha=alpha, sigma_estimated=sig_est):
        return _free_speed_result(res, geo, speed)
    out, sandwich = _sandwiches(res, geo, J, r)
    method = sandwich["method"]
    if speed is not None:
        for k, d in speed["shift"].items():
            if k in out and out[k].std is not None and np.isfinite(out[k].std):
                out[k] = dataclasses.replace(out[k], std=float(np.hypot(out[k].std, d)),
                                             ci95=None)
        method += " + speed-profile sensitivity"
    if straight is not None:
        out = _with_straight(out, straight, res)
        how = (f"the belt's clock against the body, {straight['passages']} passages of "
               f"{straight['visits']} lug markers" if straight.get("method") == "belt clock"
               else f"top run against body, {straight['visits']} top-run visits")
        label = (f"the slip read off the straight runs ({how}; the model does not describe "
                 f"the path: chi2/dof {res.chi2_per_dof:.0f}); other quantities: {method}")
        return _widened(res, out, **sandwich, speed_sensitivity=_public(speed), label=label,
                        headline="straight runs", straight_runs=straight,
                        slip_term={"replace": True, "value": straight["slip"],
                                   "std": straight["std"]},
                        uncertainty_method=label), label
    far = far_from_data(res, why) if straight is None else None
    if far:  # no slip where the model misses the markers by a tenth of a pitch
        from ..fit import Estimate

        out = {k: Estimate(None, None, reason=far) if k in SLIP_LAW + ("slip", "delta_l_mm")
               else e for k, e in out.items()}
    return _widened(res, out, **sandwich, speed_sensitivity=_public(speed), label=method,
                    uncertainty_method=f"least squares, {method} errors (unexplained misfit)",
                    **({"far_from_data": far} if far else {})), method


def straight_headline(res, why: list | None = None) -> dict | None:
    """The straight runs' slip (explain._straight) when `res` misfits grossly, else None
    (`why`: a list that gets the reason where they give no reading)."""
    if not (res.chi2_per_dof > GROSS_CHI2):
        return None
    try:
        return straight_runs_slip(res, why=why)
    except Exception:  # noqa: BLE001 - no reading: the model's robust errors stand
        return None


#: the slip law's quantities: a model that does not describe the path cannot fix them (on
#: the engine's recordings its C_rr came out 0.004 +- 0.00001 for 0.1), so where the slip
#: is read off the straight runs they are reported not identifiable
SLIP_LAW = ("stiffness_N_per_mm", "rolling_resistance", "k_over_m", "traction_N", "beta",
            "s0_linear")


def _with_straight(out: dict, st: dict, res) -> dict:
    """`out` with the slip (and delta_l_mm = s L / (n - 1)) from the straight runs, and the
    slip law's quantities (SLIP_LAW) not identifiable."""
    from ..fit import Estimate
    from ..model import delta_l

    out = dict(out)
    why = (f"the model does not describe the path (chi2/dof {res.chi2_per_dof:.0f}): its slip "
           "law's parameters are a compromise; only the slip is read, off the straight runs")
    for k in SLIP_LAW:
        if k in out:
            out[k] = Estimate(None, None, reason=why)
    out["slip"] = Estimate(st["slip"], st["std"])
    lay = res.problem.lay
    if "delta_l_mm" in out:
        out["delta_l_mm"] = Estimate(delta_l(st["slip"], float(lay.n_contact), float(lay.L)),
                                     delta_l(st["std"], float(lay.n_contact), float(lay.L)))
    return out


def _jacobian_residuals(res, geo):
    """The Jacobian of fit `res` (dense, or its time chunks) and its weighted residuals,
    zero where a sample is invalid."""
    prob = res.problem
    fixed = {k: jnp.asarray(v, float) for k, v in res.params.items()
             if k not in res.packing.names}
    J = jacobian_of(res.flat, fixed, res.packing, prob.lay, prob.obs)
    return J, np.where(geo.valid, np.asarray(res.residuals), 0.0)


def _sandwiches(res, geo, J, r):
    """Each quantity of `res` with the largest of its least-squares, by-marker and
    in-time errors, and what res.robust records of them: (quantities, {"method" (the
    covariance that set the slip's error), "clusters", "cov" (that covariance), "covs"
    (every robust one with its number of clusters)})."""
    prob = res.problem
    Hinv = covariance(J)
    in_time, n_win = _in_time(J, r, geo.t, geo.t_lo, Hinv)
    # r is zero where a sample is invalid: a marker without a valid sample is no cluster
    covs = {"least squares": res.cov,
            "cluster-robust by marker": _sandwich(J, r, geo.marker, Hinv),
            TIME: in_time}
    clusters = {"least squares": None,
                "cluster-robust by marker": int(len(np.unique(geo.marker[geo.valid]))),
                TIME: n_win}
    fixed_np = {k: v for k, v in res.params.items() if k not in res.packing.names}
    qs = {}
    for name, C in covs.items():
        if C is not None:
            qs[name] = compute_quantities(res.params, res.packing, res.flat, C, prob.lay,
                                          prob.rig.mass_kg, fixed_np,
                                          prob.rig.drawbar_pull_N)
    out = {}
    for k in res.quantities:
        best = max(qs, key=lambda n: (qs[n][k].std or 0.0))
        out[k] = dataclasses.replace(qs[best][k], ci95=None)  # interval from the new std
    name = max(qs, key=lambda n: (qs[n]["slip"].std or 0.0))
    return out, {"method": name, "clusters": clusters[name], "cov": covs[name],
                 "covs": {n: (covs[n], clusters[n]) for n in qs if n != "least squares"}}


def _public(speed):
    return None if speed is None else {k: v for k, v in speed.items() if k != "_fit"}


def _free_speed_result(res, geo, speed):
    """The refit with a free speed profile (explain._speed) as the headline, where it
    holds the whole misfit: the misfit was a motion the adaptive profile must not follow
    (a speed modulation at a free frequency). Its errors: the largest of its least-squares
    and sandwich (by marker, in time) ones and the base fit's least-squares ones. On
    bench_coverage's speed_mod recordings the base fit's slip lay 6-13 errors off and the
    sandwich plus the shift in quadrature held the truth in 48 of 48, every z near +1 (the
    shift, not the noise, set the error); the free fit's least-squares errors alone held
    it in 44 of 50 (rms z 1.18: the free profile, 4 breakpoints a period at 8 Hz, leaves a
    little of the motion, below detection)."""
    res2 = speed["_fit"]
    out, sandwich = _sandwiches(res2, geo, *_jacobian_residuals(res2, geo))
    out = _larger(out, res.quantities)
    label = (f"the model with a free speed profile (breakpoints {speed['spacing_s']:g} s "
             f"apart), which holds the whole misfit: least squares, {sandwich['method']} "
             "errors")
    pub = {**_public(speed), "headline": True}
    return _widened(res2, out, **sandwich, speed_sensitivity=pub, label=label,
                    headline="free speed profile",
                    uncertainty_method=label + " (unexplained misfit: a motion of the drive)"
                    ), label


def _widened(res, out: dict, **info):
    """`res` with the quantities `out` and, in res.robust, what the posterior needs to
    widen itself consistently (`info` plus each quantity's naive and widened error)."""
    info.update(naive_std={k: e.std for k, e in res.quantities.items()},
                robust_std={k: e.std for k, e in out.items()})
    return dataclasses.replace(res, quantities=out, robust=info)


def _larger(quantities: dict, alt: dict) -> dict:
    """Each estimate of `quantities` with the larger of its error and alt's."""
    out = {}
    for k, est in quantities.items():
        a = alt.get(k)
        if a is not None and a.std is not None and est.std is not None \
                and np.isfinite(a.std) and a.std > est.std:
            out[k] = dataclasses.replace(est, std=float(a.std), ci95=None)
        else:
            out[k] = est
    return out


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
    out = _larger(res.quantities, q)
    method = "least squares with the tracker-systematics nuisance carried"
    return _widened(res, out, method=method, clusters=None, cov=0.5 * (C + C.T), covs={},
                    speed_sensitivity=None, label=method,
                    uncertainty_method=method + " (per-marker-per-segment offsets and speed "
                                                "terms fitted beside the model: a "
                                                "measurement floor)")


def taken_out(res, geo, found: dict):
    """The fit of `res`'s recording with a measurement nuisance (explain._nuisance.search's
    `found`) taken out of the data and the model refitted (the located misfit removed),
    its errors the larger of the refit's least-squares ones and those with the nuisance's
    own uncertainty carried (the model's covariance with the nuisance fitted beside it);
    (result, method) as robust_result's, or None when the refit fails."""
    from ..fit import fit_problem

    prob = res.problem
    m = found["displacement_mm"]  # of every sample, in the residuals' order
    S_l, S_b = len(prob.lug_rows), len(prob.body_rows)
    obs = dict(prob.obs)
    for key, (a, b) in zip(("lug_x", "lug_y", "body_x", "body_y"),
                           ((0, S_l), (S_l, 2 * S_l), (2 * S_l, 2 * S_l + S_b),
                            (2 * S_l + S_b, 2 * S_l + 2 * S_b))):
        # residual = (model - obs) w, and the nuisance adds w m to it: obs - m is the
        # image without it
        obs[key] = jnp.asarray(np.asarray(obs[key]) - m[a:b], float)
    prob2 = dataclasses.replace(prob, obs=obs)
    try:
        res2 = fit_problem(prob2, res.params, free=list(res.packing.names), max_steps=100,
                           params=getattr(res, "constraints", None),
                           require_convergence=False)
    except Exception:  # noqa: BLE001 - a failed refit leaves the robust errors to decide
        return None
    if not np.isfinite(res2.chi2) or not res2.chi2 < res.chi2:
        return None
    fixed_np = {k: v for k, v in res2.params.items() if k not in res2.packing.names}
    C = found["cov"]
    q = compute_quantities(res2.params, res2.packing, res2.flat, C, prob.lay,
                           prob.rig.mass_kg, fixed_np, prob.rig.drawbar_pull_N)
    out = _larger(res2.quantities, q)
    shift = {k: float(e.value) - float(res.quantities[k].value)
             for k, e in res2.quantities.items()
             if k in res.quantities and e.value is not None
             and res.quantities[k].value is not None}
    kind = found["kind"]
    what, why = kind.label(found["terms"], geo)
    label = f"least squares with {what} taken out"
    info = {"terms": found["described"], "chi2_per_dof_before": float(res.chi2_per_dof),
            "chi2_per_dof_after": float(res2.chi2_per_dof), "shift": shift,
            "note": (f"{why}. Fitted beside the model it holds the whole misfit; it is "
                     "taken out of the data and the model refitted, each error the larger "
                     "of the refit's and the one with the nuisance's own uncertainty "
                     "carried")}
    return _widened(res2, out, method=label, clusters=None, cov=C,
                    covs={label: (C, None)}, speed_sensitivity=None, label=label,
                    nuisance=(kind.name.replace(" ", "_"), info),
                    headline=f"{kind.name} taken out",
                    uncertainty_method=label + " (unexplained misfit: a measurement nuisance)"
                    ), label


def partial_shift(res, method: str, disc):
    """An unexplained verdict's result `res` (robust_result's, with its `method`) whose
    errors also carry, in quadrature, how far a partial family term moved each quantity
    (`disc`: the families' Discovery; its `final` is the model extended by the terms that
    earned their place without bringing the residuals to the noise) when nothing holds the
    whole misfit (no nuisance taken out, no free speed profile). Which model holds
    the misfit is not known, and the headline must not depend on that choice by more than
    its error says: on a cogging the sandwich widened the slip's error by 1.4 while the
    partial term moved it by 2 of them (bench_discovery). Returns (result, method)."""
    alt = getattr(disc, "final", None)
    if alt is None or not getattr(disc, "terms", None) or (res.robust or {}).get("headline") \
            or not alt.chi2 < res.chi2:  # a term that did not lower chi^2 is no reading
        return res, method  # a nuisance or a free speed profile that holds the whole misfit
        # is the headline: the partial term is then a worse reading of it
    out, shift = {}, {}
    for k, est in res.quantities.items():
        a = alt.quantities.get(k)
        if a is None or a.value is None or est.value is None or est.std is None:
            out[k] = est
            continue
        d = float(a.value) - float(est.value)
        shift[k] = d
        out[k] = dataclasses.replace(est, std=float(np.hypot(est.std, d)), ci95=None)
    method = method + " + the partial family term's shift"
    info = dict(res.robust or {})
    info.update(robust_std={k: e.std for k, e in out.items()}, label=method,
                partial_term_shift=shift)
    info["uncertainty_method"] = (info.get("uncertainty_method", method)
                                  + "; each error also carries the shift a partial family "
                                    "term makes")
    return dataclasses.replace(res, quantities=out, robust=info), method
