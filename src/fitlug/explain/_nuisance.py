"""Measurement nuisances that hold a located misfit: found, fitted, taken out.

Some misfits that no catalog physics explains are the measurement's, and have a simple
form: the whole image moving with a shaking camera (:mod:`._image_motion`), one marker
shifted on its lug at some instant and staying there (:mod:`._marker_shift`). When the
verdict is 'unexplained', :func:`search` asks for each kind whether a few of its terms
hold the whole misfit:

1. the kind proposes its strongest term in the residuals (a line of the common-mode
   spectrum; a marker and an instant) and how many independent candidates it searched
   (a continuous term, a frequency, is then refined on the joint fit);
2. the terms so far, each a few columns of the design (every sample weighted as its
   residual), are fitted beside every parameter of the model (one linear least-squares
   step with the model's exact Jacobian, as the tracker-systematics nuisance is); the new
   term must lower chi^2 by more than the largest of the searched candidates would
   through the noise alone (family-wise false alarm FALSE_ALARM, chi^2 with the term's
   columns as degrees);
3. terms are added (at most the kind's max_terms) until the residuals pass detection
   (fitlug.explain.detect) or nothing is located in them: the nuisance must hold the whole
   misfit, else nothing changes (the robust errors of explain._robust then stand).

The verdict stays 'unexplained' (a nuisance is no catalog physics), but the fitted
displacement is taken out of the data and the model refitted (explain._robust.taken_out):
the headline is that refit, and each error the larger of its least-squares one and the
one with the nuisance's own uncertainty carried (the model's covariance with the nuisance
fitted beside it).
"""

from __future__ import annotations

import numpy as np
from scipy import special

from ..fit._rowchunks import RowChunks
from ._detect import detect
from ._normal import normal_of, pinv_factor
from ._locate import locate

FALSE_ALARM = 1e-3  # family-wise, over the candidates a kind searched


def joint_fit(J, r, N):
    """One linear least-squares step of [J, N] on the residuals r: (delta, r2, the model's
    covariance with the nuisance carried); J dense or in time chunks, N (S, q)."""
    n_p = J.n_par if isinstance(J, RowChunks) else J.shape[1]
    JJ, JN = normal_of(J, N)
    Jr = normal_of(J, r)[1]
    A = np.block([[JJ, JN], [JN.T, N.T @ N]])
    b = np.r_[Jr, N.T @ r]
    M = pinv_factor(A, 1e-14)
    delta = -(M @ (M.T @ b))
    Jd = J.matvec(delta[:n_p]) if isinstance(J, RowChunks) else np.asarray(J) @ delta[:n_p]
    r2 = r + Jd + N @ delta[n_p:]
    return delta, r2, (M @ M.T)[:n_p, :n_p]


def holds(geo, r, dof: int, *, alpha: float, sigma_estimated: bool) -> bool:
    """Whether residuals r (laid out as `geo`, `dof` degrees) pass detection, or nothing
    is located in them: no misfit left."""
    det = detect(geo, r, dof, sigma_estimated=sigma_estimated, alpha=alpha)
    return det.consistent or not locate(geo, r, det).parts


def search(kind, res, geo, J, r, *, alpha: float, sigma_estimated: bool) -> dict | None:
    """The terms of nuisance `kind` that hold the misfit of fit `res` (weighted residuals
    r, zero where invalid; J its Jacobian or time chunks), or None: {"kind", "terms"
    (the kind's description of each, with its chi^2 gain and threshold), "delta" (the
    model's step), "cov", "displacement_mm" (of every sample), "chi2_per_dof"}."""
    terms, gains, fit = [], [], None
    cur = r
    for _ in range(kind.max_terms):
        found = kind.find(geo, cur, terms)
        if found is None:
            return None
        term, n_cand = found
        trial = terms + [term]
        if hasattr(kind, "refine"):  # continuous terms (a frequency) on the joint fit
            trial = kind.refine(geo, J, r, trial)
        N = kind.columns(geo, trial)
        delta, r2, cov = joint_fit(J, r, N)
        gain = float(cur @ cur) - float(r2 @ r2)
        thr = float(special.chdtri(kind.per_term, FALSE_ALARM / max(n_cand, 1)))
        if not gain > thr:
            return None  # no significant term (left): the nuisance does not hold the misfit
        terms, cur, fit = trial, r2, (N, delta, r2, cov)
        gains.append({"dchi2": gain, "threshold": thr})
        if holds(geo, r2, res.dof - N.shape[1], alpha=alpha,
                 sigma_estimated=sigma_estimated):
            break
    else:
        return None
    N, delta, r2, cov = fit
    n_p = len(delta) - N.shape[1]
    w = np.where(geo.valid, geo.weight, 0.0)
    disp = np.where(w > 0, (N @ delta[n_p:]) / np.where(w > 0, w, 1.0), 0.0)
    described = [{**d, **g} for d, g in zip(kind.describe(terms, delta[n_p:], geo), gains)]
    return {"kind": kind, "terms": terms, "described": described, "delta": delta[:n_p],
            "cov": 0.5 * (cov + cov.T), "displacement_mm": disp,
            "chi2_per_dof": float(r2 @ r2) / max(res.dof - N.shape[1], 1)}
