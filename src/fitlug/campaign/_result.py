"""What a campaign concluded: `RecordingOutcome` per recording, `CampaignResult` for the
track (with its campaign.json document, `to_json`), and `write_campaign`, which writes
campaign.json and campaign.html.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

from .._version import __version__


@dataclass
class RecordingOutcome:
    """What the campaign concluded about one recording."""

    name: str
    input: str | None
    out: str
    status: str  # fitted | unchanged | failed
    error: str | None = None
    point: dict | None = None
    ground: str | None = None
    mass_kg: float | None = None
    drawbar_pull_N: float | None = None
    traction: tuple | None = None  # (value, std) on the campaign's C_rr
    traction_own: tuple | None = None  # (value, std) from the recording alone
    p_value: float | None = None
    consistent: bool | None = None
    reason: str | None = None
    seconds: float = 0.0


@dataclass
class CampaignResult:
    """The campaign's answer (see DATA.md campaign.json and `to_json`)."""

    law: str
    delta_bic: float
    fits: dict  # law id -> _model.LawFit (least squares, on the kept recordings)
    names: list  # parameter names of the chosen law
    samples: np.ndarray  # posterior samples (M, dim) of the chosen law
    mcmc: dict
    recordings: list  # RecordingOutcome, in source order
    estimates: dict  # name -> {"value", "std", "ci95"}
    curves: dict  # ground (or "all") -> {"traction_N", "slip", "slip_lo95", "slip_hi95"}
    alpha: float
    out: str | None = None
    nL: float = 0.0
    settings: dict = field(default_factory=dict)

    @property
    def stiffness(self) -> dict:
        return self.estimates["k"]

    @property
    def rolling_resistance(self) -> dict:
        return {n[5:-1]: e for n, e in self.estimates.items() if n.startswith("C_rr[")}

    @property
    def F_max(self) -> dict | None:
        if self.law != "janosi_hanamoto":
            return None
        return {n[6:-1]: e for n, e in self.estimates.items() if n.startswith("F_max[")}

    @property
    def flagged(self) -> list:
        return [r for r in self.recordings if r.consistent is False]

    @property
    def failed(self) -> list:
        return [r for r in self.recordings if r.status == "failed"]

    def to_json(self, out_dir: str | None = None) -> dict:
        out_dir = out_dir or self.out or "."
        recs = []
        for r in self.recordings:
            fit_rel = (os.path.relpath(os.path.join(r.out, "fit.json"), out_dir)
                       if r.status != "failed" else None)
            rep = os.path.join(r.out, "report.html")
            e = {"name": r.name, "input": r.input, "fit": fit_rel,
                 "report": (os.path.relpath(rep, out_dir) if os.path.isfile(rep) else None),
                 "status": r.status, "ground": r.ground, "mass_kg": r.mass_kg,
                 "pull": r.drawbar_pull_N,
                 "traction_N": _vs(r.traction), "traction_own_N": _vs(r.traction_own),
                 "slip": None, "slope_per_mm_s2": None,
                 "consistent": r.consistent, "p_value": _num(r.p_value),
                 "flag_reason": r.reason, "error": r.error}
            if r.point:
                cov = np.asarray(r.point["cov"])
                e["slip"] = {"value": r.point["slip"], "std": _num(math.sqrt(max(cov[0, 0], 0)))}
                e["slope_per_mm_s2"] = {"value": r.point["slope"],
                                        "std": _num(math.sqrt(max(cov[1, 1], 0)))}
                e["effects"] = r.point.get("effects")
                e["verdict"] = r.point.get("verdict")
            recs.append(e)
        fl, fj = self.fits.get("linear"), self.fits.get("janosi_hanamoto")
        chosen = self.fits[self.law]
        law_params = {"k_N_per_mm": self.estimates["k"]["value"]}
        law_std = {"k_N_per_mm": self.estimates["k"]["std"]}
        if self.law == "janosi_hanamoto":
            for g, e in self.F_max.items():
                law_params[f"F_max_N[{g}]"] = e["value"]
                law_std[f"F_max_N[{g}]"] = e["std"]
        main = "all" if "all" in self.curves else max(
            self.curves, key=lambda g: sum(r.ground == g for r in self.recordings))
        return {
            "fitlug_version": __version__,
            "recordings": recs,
            "law": {"id": self.law, "delta_bic": _num(self.delta_bic),
                    "criterion": "janosi_hanamoto named when its BIC is lower than the "
                                 "linear law's by more than 10 (delta_bic < -10)",
                    "params": law_params, "params_std": law_std,
                    "compared": {name: {"chi2": _num(f.chi2), "n_params": f.n_params,
                                        "n_data": f.n_data, "bic": _num(f.bic),
                                        "params": dict(zip(f.names, map(_num, f.theta))),
                                        "params_std": dict(zip(f.names, map(_num, f.std())))}
                                 for name, f in (("linear", fl), ("janosi_hanamoto", fj))
                                 if f is not None}},
            "stiffness_N_per_mm": self.estimates["k"],
            "rolling_resistance": self.rolling_resistance,
            "F_max_N": self.F_max,
            "curve": self.curves[main],
            "curves": self.curves,
            "consistency": {"test": "chi-square (2 dof) of each recording's (slip, ds/da) "
                                    "against the shared law, the law's uncertainty added",
                            "alpha": self.alpha, "threshold": self.alpha / max(
                                len([r for r in self.recordings if r.point]), 1),
                            "flagged": [r.name for r in self.flagged]},
            "failed": [{"name": r.name, "error": r.error} for r in self.failed],
            "mcmc": self.mcmc,
            "uncertainty_method": "posterior (emcee) of the campaign model; each recording's "
                                  "point from its least-squares fit (delta method)",
            "n_contact": int(self.settings.get("n", 0)) or None,
            "load_bearing_length_mm": self.settings.get("L"),
            "settings": {k: v for k, v in self.settings.items() if k not in ("n", "L")},
        }


def _num(x):
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def _vs(t):
    return None if t is None else {"value": _num(t[0]), "std": _num(t[1])}


def write_campaign(result: CampaignResult, out: str) -> tuple[str, str]:
    """campaign.json and campaign.html into `out`, atomically."""
    from ..io import write_json

    os.makedirs(out, exist_ok=True)
    jpath = os.path.join(out, "campaign.json")
    doc = result.to_json(out)
    write_json(jpath, doc)
    from ._html import write_campaign_html

    hpath = write_campaign_html(result, doc, out)
    return jpath, hpath
