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


def fit_json(res, *, input_path: str | None = None, mcmc=None, discrepancy=None,
             posterior=None) -> dict:
    """The fit.json dictionary of a least-squares result (plus posterior / discrepancy blocks).

    `posterior`: name -> Estimate from the sampler; it replaces the least-squares estimates
    of slip, delta_l_mm, stiffness_N_per_mm and rolling_resistance when given.
    """
    q = dict(res.quantities)
    prob = res.problem
    rig = prob.rig
    if posterior:
        q.update(posterior)

    def est(name):
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
        "n_belt_lugs": prob.lay.n_belt,
        "noise_mm": {"body": _num(prob.noise["body"]), "lug": _num(prob.noise["lug"])},
        "noise_source": prob.noise_source,
        "chi2_per_dof": _num(res.chi2_per_dof),
        "least_squares": {"converged": bool(res.converged), "steps": int(res.steps),
                          "chi2": _num(res.chi2), "dof": int(res.dof),
                          "n_params": int(res.n_params), "n_data": int(res.n_data),
                          "effects": list(res.effects)},
        "uncertainty_method": "posterior (emcee)" if posterior else "least squares (Jacobian)",
        "rig": {"load_bearing_length_mm": rig.load_bearing_length_mm,
                "lugs_in_contact": rig.lugs_in_contact, "lug_pitch_mm": rig.lug_pitch_mm,
                "mass_kg": rig.mass_kg},
        "reference_paper_slip": REFERENCE_SLIP,
    }
    info = getattr(prob, "init_info", None) or {}
    if "glitches" in info:  # isolated gross errors kept out of the estimates (fitlug.fit)
        out["glitches"] = [{k: (_num(v) if isinstance(v, float) else v) for k, v in g.items()}
                           for g in info["glitches"]]
        out["glitch_rule"] = info.get("glitch_rule")
        out["glitch_threshold_sigma"] = _num(info.get("glitch_threshold_sigma"))
    if mcmc is not None:
        out["mcmc"] = mcmc
    else:
        out["mcmc"] = None
        out.pop("mcmc")
    if discrepancy is not None:
        out["discrepancy"] = discrepancy
    return out
