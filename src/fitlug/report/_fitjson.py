"""fit.json: what `fit-lug trajectories.csv` concludes, for machines (DATA.md)."""

from __future__ import annotations

import numpy as np

from .._version import __version__
from .._reference import REFERENCE_SLIP


def _num(x):
    if x is None:
        return None
    x = float(x)
    return x if np.isfinite(x) else None


# quantity name (FitResult.quantities, Posterior.estimates) -> fit.json key
JSON_KEY = {"slip": "slip", "delta_l_mm": "delta_l_mm", "stiffness_N_per_mm":
            "stiffness_N_per_mm", "rolling_resistance": "rolling_resistance",
            "k_over_m": "k_over_m_N_per_mm_kg"}
NO_MASS = ("no mass in rig.toml ([vehicle] mass_kg): the data measure k/m "
           "(k_over_m_N_per_mm_kg), not k")


def fit_json(res, *, input_path: str | None = None, mcmc=None, discrepancy=None,
             posterior=None, not_identifiable=None, uncertainty_method=None) -> dict:
    """The fit.json dictionary of a least-squares result (plus posterior / discrepancy blocks).

    `posterior`: name -> Estimate from the sampler; it replaces the least-squares estimates
    of slip, delta_l_mm, stiffness_N_per_mm and rolling_resistance when given.
    `not_identifiable`: quantity name -> reason (fitlug.posterior's decision): those keys
    are null and the reasons go to the top-level "not_identifiable" {fit.json key: reason}.
    `uncertainty_method`: how the headline errors were made (default: from the inputs).
    """
    q = dict(res.quantities)
    prob = res.problem
    rig = prob.rig
    if posterior:
        q.update(posterior)
    unident = {JSON_KEY.get(k, k): v for k, v in (not_identifiable or {}).items()}
    for k, e in q.items():  # the least squares' and the posterior's own None-with-reason
        if k in JSON_KEY and e is not None and e.value is None and getattr(e, "reason", None):
            unident.setdefault(JSON_KEY[k], e.reason)
    if rig.mass_kg is None:
        unident["stiffness_N_per_mm"] = NO_MASS
    if uncertainty_method is None:
        robust = getattr(res, "robust", None)
        uncertainty_method = (
            "posterior (emcee)" if posterior else
            robust.get("uncertainty_method") or f"least squares, {robust['method']} errors" if robust else
            "least squares (Jacobian)")

    def est(name):
        if JSON_KEY.get(name, name) in unident:
            return None
        e = q.get(name)
        return None if e is None else e.as_dict()

    out = {
        "input": input_path or prob.rec.path,
        "fitlug_version": __version__,
        "slip": est("slip"),
        "delta_l_mm": est("delta_l_mm"),
        "stiffness_N_per_mm": est("stiffness_N_per_mm") if rig.mass_kg is not None else None,
        "rolling_resistance": est("rolling_resistance"),
        "k_over_m_N_per_mm_kg": est("k_over_m"),
        "geometry": {k: _num(q[k].value) for k in ("R_mm", "D_mm", "e_mm", "pitch_mm")},
        "geometry_std": {k: _num(q[k].std) for k in ("R_mm", "D_mm", "e_mm", "pitch_mm")},
        "n_belt_lugs": int(prob.lay.n_belt),
        "noise_mm": {"body": _num(prob.noise["body"]), "lug": _num(prob.noise["lug"])},
        "noise_source": prob.noise_source,
        "chi2_per_dof": _num(res.chi2_per_dof),
        "least_squares": {"converged": bool(res.converged), "steps": int(res.steps),
                          "chi2": _num(res.chi2), "dof": int(res.dof),
                          "n_params": int(res.n_params), "n_data": int(res.n_data),
                          "effects": list(res.effects)},
        "uncertainty_method": uncertainty_method,
        "not_identifiable": unident,
        "rig": {"load_bearing_length_mm": rig.load_bearing_length_mm,
                "lugs_in_contact": rig.lugs_in_contact, "lug_pitch_mm": rig.lug_pitch_mm,
                "mass_kg": rig.mass_kg,
                "drawbar_pull_N": getattr(rig, "drawbar_pull_N", 0.0),
                "ground": getattr(rig, "ground", None),
                "assumed": bool(getattr(rig, "assumed", False))},
        "reference_paper_slip": REFERENCE_SLIP,
        # fitted markers with their coverage, and tracker fragments fitted as one marker
        "markers": list(prob.init_info.get("markers", [])),
        "joined": list(prob.init_info.get("joined", [])),
    }
    law = ((getattr(res, "robust", None) or {}).get("slip_term") or {}).get("law") or {}
    if out["slip"] is not None and law.get("v_headline_mm_s"):
        # a slip law in the speed (MODEL.md §5): the headline is the steady slip at this speed
        out["slip"]["at_speed_mm_s"] = _num(law["v_headline_mm_s"])
    if getattr(rig, "drawbar_pull_N", 0.0) and rig.mass_kg is None:
        out.setdefault("not_identifiable", {})["rolling_resistance"] = (
            "a drawbar pull without [vehicle] mass_kg in rig.toml: only C_rr + F_d/(m g) "
            "is measured")
    info = getattr(prob, "init_info", None) or {}
    if "glitches" in info:  # isolated gross errors kept out of the estimates (fitlug.fit)
        out["glitches"] = [{k: (_num(v) if isinstance(v, float) else v) for k, v in g.items()}
                           for g in info["glitches"]]
        out["glitch_rule"] = info.get("glitch_rule")
        out["glitch_threshold_sigma"] = _num(info.get("glitch_threshold_sigma"))
    # what the data said was not as it should be (fitlug.fit._prepare): the transform to
    # the contract's frame, identity swaps repaired, tracks kept out, sigma_mm handled
    if "orientation" in info:
        out["orientation"] = dict(info["orientation"])
        out["direction"] = info["orientation"]["direction"]
    for key in ("swaps", "excluded", "sigma_notes"):
        if key in info:
            out[key] = list(info[key])
    spec = getattr(res, "constraints", None)
    if spec is not None and spec.as_json():
        # fitted under fitlug.Parameters (docs/library/parameters.md): the held, bounded
        # and prior'd parameters by their one name
        out["parameter_constraints"] = spec.as_json()
    if mcmc is not None:
        out["mcmc"] = mcmc
    else:
        out["mcmc"] = None
        out.pop("mcmc")
    if discrepancy is not None:
        out["discrepancy"] = _effect_identifiability(discrepancy, res)
    return out


def _effect_identifiability(disc: dict, res=None) -> dict:
    """Effect parameters the data cannot fix: null in `params`, the reason in the entry's
    `not_identifiable` (BRIEF). Decided from the information: FitResult.effect_identifiability
    (no information left in the parameter's Jacobian column), a standard error missing or
    not finite, or a phase whose std exceeds a quarter turn (its 95 % interval covers the
    circle)."""
    for e in disc.get("effects") or []:
        params, std = e.get("params") or {}, e.get("params_std") or {}
        why = {}
        if res is not None and hasattr(res, "effect_identifiability"):
            try:
                why.update(res.effect_identifiability(e["id"]))
            except (KeyError, ValueError):  # the final model lost the effect
                pass
        for k, v in params.items():
            if v is None or k in why or k not in std:
                continue
            sd = std.get(k)
            if sd is None or not np.isfinite(sd):
                why[k] = ("the data carry no information on it at this geometry (singular "
                          "Fisher information)")
            elif "phi" in k and sd > np.pi / 2:
                why[k] = (f"its std {sd:.2g} rad exceeds a quarter turn: the data do not fix "
                          "the phase")
        if why:
            e["params"] = {k: (None if k in why else v) for k, v in params.items()}
            e["not_identifiable"] = why
    return disc
