"""What :func:`fitlug.explain.explain` returns: the :class:`Explanation` (verdict, base and
final fits, the effects added as :class:`Step`s, the families' terms, and its fit.json
`discrepancy` block) — the record, apart from the search that fills it (:mod:`._explain`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..model import CATALOG
from . import _display
from ._criterion import (BIC_THRESHOLD, LEFT_MISFIT_Z, MIN_SHARE_REMOVED, MODELLED_CHI2,
                         STRONG_MISFIT_Z)
from ._detect import ALPHA, Detection
from ._locate import Location, residual_map, spectrum_summary


@dataclass
class Step:
    """One effect added to the model."""

    effect: str
    params: dict
    delta_bic: float
    chi2_per_dof_before: float
    chi2_per_dof_after: float
    misfit_removed_share: float


@dataclass
class Explanation:
    """What explain() concluded; `final` is the FitResult under base + named effects."""

    verdict: str  # 'none' | 'explained' | 'modelled' | 'unexplained'
    base: object
    final: object
    effects: list
    located: list
    steps: list = field(default_factory=list)
    detection_before: Detection | None = None
    detection_after: Detection | None = None
    location_before: Location | None = None
    location_after: Location | None = None
    rounds: list = field(default_factory=list)
    slip_uncertainty: str = "least squares"
    timing_s: dict = field(default_factory=dict)
    geometry: object = None  # fitlug.explain.Geometry of the residual vectors
    systematics: dict | None = None  # the tracker-systematics check (see ._systematics)
    discovery: object = None  # the families' search (fitlug.explain.families.Discovery)
    #: steps that fitted a part of the base model (MODEL.md §2's marker height h and
    #: relaxation tau, `lug_shear`): named and shown, not left-out physics (BASE_EFFECTS)
    base_steps: list = field(default_factory=list)

    @property
    def discovered(self) -> list:
        """The kept family terms as fit.json's `discrepancy.discovered` dicts (MODEL.md §5)."""
        return [t.to_json() for t in self.discovery.terms] if self.discovery else []

    def __repr__(self) -> str:
        return _display.short_repr(self)

    def _repr_html_(self) -> str:
        return _display.html(self)

    def summary(self) -> str:
        """The terminal's text for the final fit with this explanation (fitlug.summary)."""
        return _display.summary(self)

    def _final_params(self, step: Step) -> dict:
        """The effect's parameters under the final model, with standard errors (and as
        they were when the effect was added, before later effects and the polish)."""
        try:
            params = self.final.effect_params(step.effect)
            std = self.final.effect_params_std(step.effect)
        except (KeyError, AttributeError):  # the final model lost it: keep the step's
            params, std = step.params, None
        return {"params": params, "params_std": std, "params_when_added": step.params}

    def _correlated(self) -> dict:
        """The base fit's residuals' correlation per role (issue 42: a tracker's pixel
        locking and drift, :mod:`._correlated`), and the candidates it turned down."""
        from ._correlated import describe

        per_role = describe(self.geometry, self.base.residuals)
        turned = [t["id"] for rd in self.rounds for t in rd.get("tried", []) if _deflated(t)]
        if self.discovery is not None:
            turned += [t["family"] for t in self.discovery.tried if _deflated(t)]
        out = {"per_role": per_role, "turned_down": sorted(set(turned))}
        if turned and not self.effects and not self.discovered:
            out["note"] = ("tracker systematic: the misfit is correlated in time per marker "
                           "as a tracker's pixel locking and drift make it ("
                           + ", ".join(f"{k} {v['correlated_um']:.2g} um beside "
                                       f"{v['white_um']:.2g} um white"
                                       for k, v in per_role.items())
                           + "); " + ", ".join(sorted(set(turned)))
                           + " removed no more than that correlated error does, so none is "
                             "claimed")
        return out

    def to_json(self) -> dict:
        """The `discrepancy` block of fit.json (DATA.md)."""
        def slip(res):
            return res.slip.as_dict()

        out = {
            "verdict": self.verdict,
            "located": self.located,
            "effects": [{"id": s.effect, **self._final_params(s), "delta_bic": s.delta_bic,
                         "chi2_per_dof_before": s.chi2_per_dof_before,
                         "chi2_per_dof_after": s.chi2_per_dof_after,
                         "misfit_removed_share": s.misfit_removed_share,
                         "meaning": CATALOG[s.effect].meaning} for s in self.steps],
            "marker_on_lug": [{"id": s.effect, **self._final_params(s), "delta_bic": s.delta_bic,
                               "chi2_per_dof_before": s.chi2_per_dof_before,
                               "chi2_per_dof_after": s.chi2_per_dof_after,
                               "meaning": CATALOG[s.effect].meaning,
                               "reading": base_reading(self.final)}
                              for s in self.base_steps],
            "slip_before": slip(self.base),
            "slip_after": slip(self.final),
            "slip_after_uncertainty": self.slip_uncertainty,
            "chi2_per_dof_before": float(self.base.chi2_per_dof),
            "chi2_per_dof_after": float(self.final.chi2_per_dof),
            "detection_before": self.detection_before.as_dict() if self.detection_before else None,
            "detection_after": self.detection_after.as_dict() if self.detection_after else None,
            "misfit_before": self.location_before.as_dict() if self.location_before else None,
            "misfit_after": self.location_after.as_dict() if self.location_after else None,
            "candidates": self.rounds,
            "criterion": {"delta_bic_threshold": BIC_THRESHOLD, "alpha": ALPHA,
                          "min_share_of_strong_excess_chi2_removed": MIN_SHARE_REMOVED,
                          "strong_excess_chi2_in_spreads": STRONG_MISFIT_Z,
                          "after_an_effect_excess_chi2_in_spreads": LEFT_MISFIT_Z,
                          "bic": "chi2 + k ln N, noise per role fixed at the base fit's"},
            "timing_s": self.timing_s,
        }
        speed = (getattr(self.final, "robust", None) or {}).get("speed_sensitivity")
        if speed is not None:
            how = ("that fit holds the whole misfit and is the headline (slip_before: the "
                   "base model's)" if speed.get("headline") else
                   "shift added in quadrature to its robust error")
            out["speed_sensitivity"] = {
                **speed, "note": ("the model refitted with a free speed spline "
                                  f"(breakpoints {speed['spacing_s']:g} s apart): "
                                  "shift_raw is each quantity's change between the fits, "
                                  "shift its excess over the change's own scatter "
                                  f"(sqrt(max(0, d^2 - (V_free - V_base)))); {how}")}
        withheld = (getattr(self.final, "robust", None) or {}).get("withheld")
        if withheld is not None:  # partial readings of a misfit the model does not describe
            out["not_claimed"] = withheld
        straight = (getattr(self.final, "robust", None) or {}).get("straight_runs")
        if straight is not None:  # the slip read off the straight runs (explain._straight)
            how = ("the belt's travel from the lug markers' passages of the same places in "
                   "the body's frame, whole pitches and belt lengths apart"
                   if straight.get("method") == "belt clock" else
                   "v_belt from the lug markers' speed relative to the body on the top run")
            out["straight_runs"] = {
                **straight, "note": ("the model does not describe the path (chi2/dof "
                                     f"{self.final.chi2_per_dof:.0f}): the headline slip is "
                                     f"1 - v_body / v_belt at cruise, {how}")}
        far = (getattr(self.final, "robust", None) or {}).get("far_from_data")
        if far is not None:  # no slip read (explain._straight.far_from_data)
            out["far_from_data"] = far
        nuis = (getattr(self.final, "robust", None) or {}).get("nuisance")
        if nuis is not None:  # a measurement nuisance taken out (explain._nuisance)
            out[nuis[0]] = nuis[1]
        if self.discovery is not None:
            out["discovered"] = self.discovered
            out["families_tried"] = {"tried": self.discovery.tried,
                                     "not_tried_because": self.discovery.why_not,
                                     "modelled_chi2_per_dof": MODELLED_CHI2,
                                     "time_s": self.discovery.seconds,
                                     "glitches_after_terms": self.discovery.glitches}
        if self.systematics is not None:
            sysb = {k: v for k, v in self.systematics.items()
                    if k != "why_not" and not k.startswith("_")}
            if self.systematics.get("why_not") is None:
                out["systematics"] = sysb
            else:
                out["systematics_check"] = {**sysb, "not_systematics_because":
                                            self.systematics["why_not"],
                                            "note": "checked: not a tracker floor"}
        if self.geometry is not None and self.detection_before is not None \
                and not self.detection_before.consistent:
            out["correlated_error"] = self._correlated()
        if self.geometry is not None:
            g = self.geometry
            out["maps"] = {"before": residual_map(g, self.base.residuals)}
            out["spectra"] = {"before": spectrum_summary(g, self.base.residuals)}
            if self.final.residuals is not self.base.residuals:
                out["maps"]["after"] = residual_map(g, self.final.residuals)
                out["spectra"]["after"] = spectrum_summary(g, self.final.residuals)
        return _plain(out)


def _deflated(d: dict) -> bool:
    return "residuals' correlation" in (d.get("rejected_because") or "")


def _plain(x):
    """JSON-safe copy: numpy scalars to Python, non-finite numbers to None (strict JSON)."""
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, np.ndarray):
        return _plain(x.tolist())
    return x


#: catalog ids that fit a part of MODEL.md §2's base model: where the explanation adds
#: one, it is the base model's own parameter found (the marker height h and the lug's
#: relaxation tau, fitted only where the data show them; h = 1 otherwise), so it neither
#: makes a verdict nor counts as left-out physics, and is reported under `marker_on_lug`
BASE_EFFECTS = ("lug_shear",)


def as_base(ex: "Explanation") -> "Explanation":
    """`ex` with its BASE_EFFECTS moved from the left-out physics to the base model: an
    'explained' verdict that needed nothing else is 'none'."""
    import dataclasses

    base = [s for s in ex.steps if s.effect in BASE_EFFECTS]
    if not base and not set(ex.effects) & set(BASE_EFFECTS):
        return ex
    effects = [e for e in ex.effects if e not in BASE_EFFECTS]
    verdict = "none" if ex.verdict == "explained" and not effects else ex.verdict
    return dataclasses.replace(ex, verdict=verdict, effects=effects, base_steps=base,
                               steps=[s for s in ex.steps if s.effect not in BASE_EFFECTS])


def base_reading(res) -> str:
    """Where the lug markers sit and what the lugs do, in words (from `res`'s h, tau)."""
    try:
        p = res.effect_params("lug_shear")
    except (KeyError, ValueError, AttributeError):
        return ""
    h, tau = float(p["h"]), float(p["tau_s"])
    hs = f"{h:.2f}" if abs(h) >= 0.005 else "0.00"
    back = (f"the shear springs back in {1000 * tau:.0f} ms after the lug lifts off at the "
            "rear of the contact patch")
    if h < 0.15:
        return (f"the lug markers sit on the lug tips (h = {hs}; 0 tip, 1 pitch line): in "
                "contact they stand still on the ground while each lug shears under the "
                f"traction, and {back}")
    where = ("near the lug tips" if h < 0.4 else "half-way up the lugs" if h < 0.7
             else "near the belt's pitch line")
    # a tip that slides drifts too: a marker at height h' on a lug whose tip slides at r of
    # the creep drifts at r + h' (1 - r) >= h' (an engine's crawler at friction 0.16 and
    # 0.12, markers on the tips: h 0.49 and 0.71), so h is the markers' height only where
    # the tips hold
    return (f"in contact the lug markers drift over the ground at {hs} of the pitch line's "
            f"creep (h = {hs}; 0 tip, 1 pitch line): they sit {where} while the lug tips "
            "hold, or lower (down to the tips) while the tips slide over the ground: the "
            f"drift alone does not tell the two apart; each lug shears under the traction, "
            f"and {back}")
