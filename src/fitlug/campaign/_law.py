"""The campaign model on the recordings' points: the law chosen (linear or
Janosi-Hanamoto, by BIC on the kept set), the flags of the recordings that disagree (and
why), the posterior estimates and the slip curves.
"""

from __future__ import annotations

import numpy as np

from .._errors import FitError
from . import _model
from ._result import CampaignResult, RecordingOutcome, _num


def fit_points(outcomes, *, seed: int = 0, alpha: float = _model.FLAG_ALPHA,
               budget_s: float = 600.0) -> CampaignResult:
    """The campaign model on recordings whose points are known (outcomes with `point`
    dicts, or plain point dicts): law choice, flags, posterior, curves."""
    outs = []
    for o in outcomes:
        if isinstance(o, dict):
            o = RecordingOutcome(name=o["name"], input=None, out=o["name"], status="fitted",
                                 point=o, ground=o.get("ground") or "default",
                                 mass_kg=o["mass_kg"], drawbar_pull_N=o.get("drawbar_pull_N"))
        outs.append(o)
    ok = [o for o in outs if o.point is not None]
    if len(ok) < 2:
        errs = "; ".join(o.error or o.name for o in outs if o.point is None)[:300]
        raise FitError(f"a campaign needs at least two fitted recordings, got {len(ok)}"
                       + (f" ({errs})" if errs else ""))
    for o in ok:
        o.point = dict(o.point, ground=o.ground or o.point.get("ground") or "default")
    points = [_model.Point.from_dict(o.point) for o in ok]
    law, fit, keep, pvals, fits, dbic = choose_law(points, alpha)
    chain = _model.sample_law(fit, seed=seed, time_budget_s=budget_s)
    samples = chain.flat() if hasattr(chain, "flat") else chain.samples.reshape(-1, fit.n_params)
    names = list(fit.names)
    est = {}
    for i, nm in enumerate(names):
        est[nm] = _estimate(samples[:, i])
    if law == "janosi_hanamoto":
        for i, nm in enumerate(names):
            if nm.startswith("inv_F_max["):
                g = nm[10:-1]
                u = samples[:, i]
                with np.errstate(divide="ignore"):
                    F = np.where(u > 0, 1.0 / np.maximum(u, 1e-300), np.inf)
                est[f"F_max[{g}]"] = _estimate(F)
    d = fit.design
    for o, p_ok, p in zip(ok, keep, pvals):
        o.p_value = float(p)
        o.consistent = bool(p_ok)
        o.traction_own = _model.Point.from_dict(o.point).own_traction
        g = o.ground
        cname = f"C_rr[{g}]"
        if cname in names:
            c = samples[:, names.index(cname)]
            F = o.mass_kg * c * _model.G + (o.drawbar_pull_N or 0.0)
            o.traction = (float(np.median(F)), float(np.std(F, ddof=1)))
        else:
            o.traction = o.traction_own
        if not p_ok:
            o.reason = _flag_reason(o, fit, samples, names, d, alpha, len(ok))
    curves = _curves(law, samples, names, ok, keep, d.nL)
    mc = {"walkers": int(chain.samples.shape[1]), "steps": int(chain.steps),
          "discard": int(chain.discard), "autocorr_time": _num(np.max(chain.tau)),
          "ess": _num(np.min(chain.ess)), "converged": bool(chain.converged),
          "reason": chain.reason or None, "seed": seed}
    n, L = points[0].n, points[0].L
    return CampaignResult(law=law, delta_bic=dbic, fits=fits, names=names, samples=samples,
                          mcmc=mc, recordings=outs, estimates=est, curves=curves, alpha=alpha,
                          nL=d.nL, settings={"n": n, "L": L})


def choose_law(points, alpha: float = _model.FLAG_ALPHA):
    """Flags under each law; the kept set is that of the law that keeps more recordings
    (a curved law flags many recordings under the linear one; a stray recording is flagged
    under both); then the law by BIC on that set, and its own flags."""
    fl, keep_l, p_l = _model.fit_with_flags(points, "linear", alpha)
    fj, keep_j, p_j = _model.fit_with_flags(points, "janosi_hanamoto", alpha)
    keep = keep_j if keep_j.sum() > keep_l.sum() else keep_l
    kept = [p for p, k in zip(points, keep) if k]
    fl_same = _model.fit_law(kept, "linear")
    fj_same = _model.fit_law(kept, "janosi_hanamoto")
    dbic = fj_same.bic - fl_same.bic
    if dbic < _model.DELTA_BIC_NAMED:
        return "janosi_hanamoto", fj, keep_j, p_j, {"linear": fl_same, "janosi_hanamoto": fj}, \
            dbic
    return "linear", fl, keep_l, p_l, {"linear": fl, "janosi_hanamoto": fj_same}, dbic


def _estimate(x) -> dict:
    x = np.asarray(x, float)
    x = x[np.isfinite(x)] if np.any(np.isfinite(x)) else x
    lo, med, hi = np.percentile(x, [2.5, 50, 97.5])
    return {"value": _num(med), "std": _num(np.std(x, ddof=1)), "ci95": [_num(lo), _num(hi)]}


def _flag_reason(o, fit, samples, names, d, alpha, N) -> str:
    p = o.point
    k_med = float(np.median(samples[:, names.index("k")]))
    k_own = 2.0 * o.mass_kg / (1000.0 * p["slope"] * d.nL)
    own = ""
    c = p.get("chi2_per_dof")
    if p.get("verdict") == "unexplained":
        own = (f"; its own fit is unexplained (chi2/dof {c:.3g} under "
               f"{', '.join(p.get('effects') or []) or 'the base model'}): the misfit left in "
               "that recording may bias its point -- read its report before taking it for "
               "another track")
    elif c is not None and c > 3:
        own = (f"; its own fit is poor (chi2/dof {c:.3g} under "
               f"{', '.join(p.get('effects') or []) or 'the base model'}): a misfit the "
               "explanation left in that recording biases its point")
    return (f"pull {o.drawbar_pull_N:g} N, mass {o.mass_kg:g} kg, ground {o.ground}: its point "
            f"(slip {p['slip']:.4g}, ds/da {p['slope']:.3g} per mm/s^2; read with the linear "
            f"law alone k = {k_own:.3g} N/mm, the campaign's {k_med:.3g}) disagrees with the "
            f"shared law: p = {o.p_value:.2g} < {alpha:g}/{N} -- another track, a wrong rig "
            f"(mass, pull, n, L) or another ground{own}")


def _curves(law, samples, names, ok, keep, nL) -> dict:
    F_hi = max((o.traction[0] for o in ok if o.traction), default=1.0) * 1.15
    grounds = sorted({o.ground for o, k in zip(ok, keep) if k})
    keys = ["all"] if law == "linear" else grounds
    out = {}
    rng = np.random.default_rng(0)
    sub = samples if len(samples) <= 4000 else samples[rng.choice(len(samples), 4000, False)]
    for g in keys:
        top = F_hi
        if law == "janosi_hanamoto":
            Fm = 1.0 / np.median(sub[:, names.index(f"inv_F_max[{g}]")])
            top = min(F_hi, 0.97 * Fm) if np.isfinite(Fm) else F_hi
        F = np.linspace(0.0, top, 60)
        S = _model.curve(law, sub, names, g, F, nL)
        lo, med, hi = np.percentile(S, [2.5, 50, 97.5], axis=0)
        out[g] = {"traction_N": F.tolist(), "slip": med.tolist(), "slip_lo95": lo.tolist(),
                  "slip_hi95": hi.tolist()}
    return out
