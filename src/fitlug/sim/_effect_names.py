"""An effect's parameters by the names fit.json reports them (``epsilon``, ``phi_rad`` of
wheel_runout; ``d_mm`` of belt_sag) turned into the model's own (``runout_a``,
``runout_b``; ``sag_d``), so that a Scenario takes a fit's discrepancy block as it is.

Renames are found by probing the effect's ``report`` (a reported value equal to one
parameter's value is that parameter under another name); the speed modulations'
polar (epsilon, phi) and lug_sliding's s_K are inverted explicitly."""

from __future__ import annotations

import math


def reported_names(eid: str) -> dict:
    """{fit.json name: model parameter} of the renamed parameters of effect `eid`."""
    from ..model.effects import CATALOG

    eff = CATALOG[eid]
    probe = {k: 0.1234567 + 0.0101 * i for i, k in enumerate(eff.defaults)}
    try:
        rep = eff.report(dict(probe))
    except Exception:  # noqa: BLE001 - a plugin's report that needs more: no renames
        return {}
    return {r: k for r, v in rep.items() for k, pv in probe.items()
            if v is not None and r != k and abs(float(v) - pv) < 1e-12}


def internal_params(eid: str, vals: dict) -> dict:
    """`vals` with fit.json names replaced by the model's parameters (others kept)."""
    from ..model.effects import CATALOG

    if eid not in CATALOG or not isinstance(vals, dict):
        return vals
    eff = CATALOG[eid]
    out = {k: v for k, v in vals.items() if k in eff.defaults}
    rest = {k: v for k, v in vals.items() if k not in eff.defaults}
    prefix = getattr(eff, "prefix", None)
    if prefix and "epsilon" in rest:  # phi_rad 0 when left out, as `fit-lug simulate`
        eps, phi = float(rest.pop("epsilon")), float(rest.pop("phi_rad", 0.0))
        out[prefix + "_a"], out[prefix + "_b"] = eps * math.cos(phi), eps * math.sin(phi)
    if eid == "lug_sliding" and "s_K" in rest:
        out["slide_mu"] = 1.0 / float(rest.pop("s_K"))
    names = reported_names(eid)
    for k, v in rest.items():
        out[names.get(k, k)] = v
    return out


def accepted_names(eid: str) -> list[str]:
    """The fit.json names :func:`internal_params` turns into effect `eid`'s parameters."""
    from ..model.effects import CATALOG

    extra = ["epsilon", "phi_rad"] if getattr(CATALOG[eid], "prefix", None) else []
    extra += ["s_K"] if eid == "lug_sliding" else []
    return list(reported_names(eid)) + extra
