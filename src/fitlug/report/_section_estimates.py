"""The report's "Estimates" section: every quantity with its error and interval, the
geometry and noise levels, the named effects' parameters and the glitches kept out."""

from __future__ import annotations

from . import _format as F
from ._markup import _e, _table
from ._section_summary import _LSQ_NAME, _QUANTITIES, _not_identifiable, _pm, _sliding


def _estimates(fj, st) -> str:
    lsq = st["meta"].get("least_squares", {})
    src = "posterior" if fj.get("mcmc") else "least squares"
    # a slip read off the straight runs (the model does not describe the path; fit.json
    # holds them only then, as the discrepancy section reads it): that is where it and Δl′
    # come from, whatever samples them after
    runs = (fj.get("discrepancy") or {}).get("straight_runs") or {}
    rows = []
    said: dict = {}  # reasons given in this table (_not_identifiable)
    for key, label, unit in _QUANTITIES:
        e = fj.get(key)
        ls = lsq.get(_LSQ_NAME.get(key, key)) or {}
        if e is None or e.get("value") is None:
            rows.append([label, unit, _not_identifiable(fj, key, said, f"the {label}"), "", "",
                         _pm(ls) if ls.get("value") is not None and key in fj else ""])
            continue
        ci = e.get("ci95") or [None, None]
        how = f"straight runs ({runs.get('method', '')})" \
            if runs and key in ("slip", "delta_l_mm") else src
        rows.append([label, unit, _pm(e), F.interval(ci[0], ci[1], e.get("std"), 95),
                     _e(how), _pm(ls)])
    geo, gsd = fj.get("geometry") or {}, fj.get("geometry_std") or {}
    names = {"R_mm": "wheel pitch radius R", "D_mm": "wheel distance D",
             "e_mm": "marker offset e", "pitch_mm": "lug pitch p"}
    for k, label in names.items():
        v, sd = geo.get(k), gsd.get(k)
        ci = (None, None) if v is None or sd is None else (v - 1.96 * sd, v + 1.96 * sd)
        rows.append([label, "mm", F.pm(v, sd), F.interval(ci[0], ci[1], sd, 95),
                     "least squares", ""])
    noise = fj.get("noise_mm") or {}
    for role in ("lug", "body"):
        v = noise.get(role)
        rows.append([f"noise, {role} markers", "µm",
                     F.sig(None if v is None else 1000 * v, 3), "",
                     _e(fj.get("noise_source", "")), ""])
    out = _table(["quantity", "unit", "value ± 1 σ", "interval", "from",
                  "least squares ± 1 σ"], rows)
    if _sliding(fj):
        out += ("<p class=small>Under lug_sliding, Δl′ is the elastic lug deflection at the "
                "steady load, s<sub>el</sub>·L/(n−1) with the elastic slip s<sub>el</sub>; s₀ "
                "is the law's total steady slip, larger by the sliding part (see the "
                "headline), so Δl′ ≠ s₀·L/(n−1) here.</p>")
    d = fj.get("discrepancy") or {}
    for eff in d.get("effects") or []:
        out += _effect_table(eff)
    return out + _glitches(fj)


def _effect_table(eff) -> str:
    std = eff.get("params_std") or {}
    ni = eff.get("not_identifiable") or {}
    rows = []
    for k, v in (eff.get("params") or {}).items():
        if v is None:
            rows.append([_e(k), f"not identifiable: {_e(ni.get(k, 'the data do not pin it'))}"])
        else:
            rows.append([_e(k), F.pm(v, std.get(k))])
    return (f"<p>Effect <b>{_e(eff.get('id'))}</b> (least squares, delta-method errors): "
            f"{_e(eff.get('meaning', ''))}</p>" + _table(["parameter", "value ± 1 σ"], rows))


#: glitch rows shown before the rest is folded away (<details>)
GLITCH_ROWS = 20


def _glitches(fj) -> str:
    """The samples kept out of the estimates as gross errors (fit.json `glitches`)."""
    gl = fj.get("glitches")
    if gl is None:
        return ""
    rule = _e(str(fj.get("glitch_rule") or ""))
    if not gl:
        return f'<p class="small">Glitches: none found ({rule}).</p>'
    rows = [[_e(str(g.get("marker"))), F.sig(g.get("time_s"), 5),
             F.sig(g.get("dx_mm"), 3), F.sig(g.get("dy_mm"), 3), F.sig(g.get("size_sigma"), 3)]
            for g in gl]
    head = ["marker", "time (s)", "dx (mm)", "dy (mm)", "size (σ)"]
    # a misfit the model does not describe flags 100-140 samples of its structure on a
    # contact-dynamics engine's recording: the first GLITCH_ROWS shown, the rest folded
    more = (f"<details><summary>the other {len(rows) - GLITCH_ROWS} (fit.json "
            f"<code>glitches</code>)</summary>{_table(head, rows[GLITCH_ROWS:])}</details>"
            if len(rows) > GLITCH_ROWS else "")
    return (f"<h3>Glitches kept out of the estimates ({len(gl)})</h3>"
            + _table(head, rows[:GLITCH_ROWS]) + more
            + f'<p class="small">Rule: {rule}.</p>')
