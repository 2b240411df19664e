"""Honest errors when the misfit is unexplained: the likelihood stretched to the robust
covariance.

When fitlug.explain leaves a misfit unexplained (res.robust set), the white-noise
likelihood is orders of magnitude too confident: it is stretched to the cluster-robust
covariance of the slip law (see `tempering`), so the posterior is never narrower than the
robust least-squares errors. What the data cannot fix is found from the samples
"""

from __future__ import annotations

import math

import numpy as np

from ..fit._reading import misses_the_data, reads_straight_runs
from ..fit._result import FitResult
from ._derived import _derived_gradients
from ._marginal import _Marginal, slip_law_parameters

TEMPERED = ("slip", "delta_l_mm", "rolling_resistance", "k_over_m")


def tempering(res: FitResult, marg: "_Marginal | None" = None) -> dict:
    """How the likelihood of `res` is widened: {"factor": 1.0} when it is not.

    Only when fitlug.explain left a misfit unexplained and widened the least-squares errors
    to robust ones (res.robust: by marker, in time; each quantity the largest of them and
    of least squares, see fitlug.explain._robust). Then the posterior is made consistent
    with them: of the candidate covariances of the slip law (each robust one, and their
    sum), each scaled up until every reported quantity (slip, dl', C_rr, k/m) is at least
    as wide as its robust least-squares error (delta method), and each rescaled per
    parameter first so that a quantity of one parameter alone (slip, k/m) gets exactly its
    target, the tightest is used (least sum over the quantities of log(variance /
    target)). The likelihood is stretched to that covariance (_Marginal.widened): its
    shape and the priors are kept. No small-sample t factor is
    put on top: the largest of three variance estimates already covers the few clusters
    (bench_coverage's out-of-catalog rows: with t_{G-1} factors on top, the posterior
    intervals held the truth in 150 of 150 recordings).
    Returns {"factor" (slip variance over the white-noise one), "cov", "method",
    "clusters", "extra_scale", "note"}.
    """
    info = getattr(res, "robust", None)
    if not info or info.get("cov") is None:
        return {"factor": 1.0}
    sens = info.get("speed_sensitivity") or {}
    shifted = bool(sens.get("shift")) and not sens.get("headline")  # headline: the free fit
    if info.get("method") == "least squares" and not shifted:
        return {"factor": 1.0}
    if marg is None:
        marg = _Marginal(res, slip_law_parameters(res), batch=16)
    sl = res.packing.slices()
    idx = [sl[k].start for k in marg.names]
    grads = _derived_gradients(res, marg.names, marg.theta_hat)
    g = grads["slip"]
    cands = info.get("covs") or {info["method"]: (info["cov"], info.get("clusters"))}
    blocks = {name: (0.5 * (C + C.T)[np.ix_(idx, idx)], G)
              for name, (C, G) in cands.items() if C is not None}
    if len(blocks) > 1:  # their sum: at least as wide as each in every direction
        blocks["sum of the robust covariances"] = (sum(b[0] for b in blocks.values()), None)
    # each reported quantity's target variance: its robust least-squares one
    target = {}
    for q in TEMPERED:
        want = info["robust_std"].get(q)
        if q in grads and want and math.isfinite(want):
            target[q] = want ** 2
    for name, (S, G) in list(blocks.items()):  # each rescaled per parameter, so that a
        # quantity of one parameter alone (slip: s0; k/m: beta) gets exactly its target
        d = np.ones(len(idx))
        for q, want2 in target.items():
            nz = np.flatnonzero(np.abs(grads[q]) > 1e-12 * np.max(np.abs(grads[q])))
            have = float(grads[q] @ S @ grads[q])
            if len(nz) == 1 and have > 0:
                d[nz[0]] = max(d[nz[0]], math.sqrt(want2 / have))
        if np.any(d > 1.0):
            blocks[name + ", rescaled per parameter"] = (S * np.outer(d, d), G)
    best = None  # the tightest candidate: least total excess over the targets
    for name, (S, G) in blocks.items():
        extra = 1.0  # so that no reported quantity is narrower than its target
        for q, want2 in target.items():
            have = float(grads[q] @ S @ grads[q])
            if have > 0:
                extra = max(extra, want2 / have)
        excess = sum(math.log(max(float(grads[q] @ S @ grads[q]) * extra, 1e-300) / want2)
                     for q, want2 in target.items())
        if best is None or excess < best[0]:
            best = (excess, name, S * extra, G, extra)
    _, method, S, G, extra = best
    naive = float(g @ marg.cov @ g)
    factor = float(g @ S @ g) / naive if naive > 0 else float("inf")
    note = (f"{G} clusters" if G else "the robust covariances added" if "sum" in method
            else "its own covariance")
    if extra > 1.0 + 1e-9:
        note += f", errors x {math.sqrt(extra):.3f} so that no quantity is narrower than its own"
    if shifted:
        note += ("; the robust errors carry the speed-profile sensitivity (the shift of "
                 "each quantity when the speed spline is freed)")
    return {"factor": factor, "cov": S, "method": method, "clusters": G,
            "extra_scale": float(extra), "note": note}


def tempered_marginal(res: FitResult, names, batch: int) -> tuple:
    """(the marginal of `names`, its tempering): the likelihood the posterior samples,
    stretched to the robust covariance when the misfit is unexplained (see `tempering`;
    the returned dict without its "cov"). Under a straight-runs headline a singular
    marginal is ridged (`_Marginal`'s singular_ok), not an error."""
    marg = _Marginal(res, names, batch=batch,
                     singular_ok=reads_straight_runs(res) or misses_the_data(res))
    temper = tempering(res, marg)
    if temper.get("cov") is not None:
        marg.widened(temper.pop("cov"))
    return marg, temper
