"""The report's "What the model left out" section (HTML, plots as base64 PNG).

Everything it shows comes from fit.json's `discrepancy` block (written by
fitlug.explain.Explanation.to_json) and, for the residuals before and after the named
effects, from the report's saved state (`base_*` arrays). It opens with one plain sentence,
then: the slip before and after (the final row carries the headline's error), the named
effects, whiteness tests before and after, where the mismatch sits (shares of the
structured misfit apart from spectral lines), residuals before/after over time and along
the belt coordinate, the binned residual maps, the misfit breakdown on a log scale, the
spectrum with its peaks named, and every candidate with the reason it was or was not fitted.
"""

from __future__ import annotations

import html
import math

from . import _format as F
from ._discrepancy_plots import discrepancy_plots
from ._straight_text import not_claimed_clause, straight_sentence

MAX_FITS_PER_ROUND = 4  # fitlug.explain._explain.MAX_FITS_PER_ROUND (read at run time)


def _e(x) -> str:
    return html.escape(str(x))


def _num(x, digits=4) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    if isinstance(x, (int, float)):
        return F.sig(x, digits)
    return _e(x)


def modelled(d: dict) -> bool:
    """Whether an unexplained mismatch was modelled outside the catalog (a measurement
    nuisance taken out, a free speed profile as headline) rather than widening the error."""
    return bool(d.get("image_motion") or d.get("marker_shift")
                or (d.get("speed_sensitivity") or {}).get("headline"))


def handling_sentence(d: dict) -> str:
    """What was done about an unexplained mismatch, one plain clause (no HTML): a
    measurement nuisance or a free speed profile that holds it, else the widened error."""
    im, ms = d.get("image_motion"), d.get("marker_shift")
    if im:
        f = ", ".join(f"{t['frequency_hz']:.3g}" for t in im.get("terms") or [])
        return (f"it is a common motion of the whole image at {f} Hz (the camera moved): "
                "taken out and the model refitted, the headline is that fit")
    if ms:
        parts = "; ".join(
            f"marker {t['marker']} by ({t['shift_um'][0]:.0f}, {t['shift_um'][1]:.0f}) um "
            f"from {t['from_time_s']:.3g} s" for t in ms.get("terms") or [])
        return (f"it is one marker shifted and staying there ({parts}: knocked on its lug?): "
                "taken out and the model refitted, the headline is that fit")
    st = d.get("straight_runs")
    if st:
        return straight_sentence(st) + not_claimed_clause(d)
    if d.get("far_from_data"):
        return "no slip is read: " + d["far_from_data"]
    sens = d.get("speed_sensitivity") or {}
    if sens.get("headline"):
        return ("a free speed profile follows it (a motion of the drive the adaptive profile "
                "must not follow): that fit holds the whole mismatch and is the headline")
    return "the slip's error bar includes this mismatch"


def located_sentence(d: dict) -> str:
    """One plain sentence: where the mismatch is and what it looks like."""
    shares = [p for p in d.get("located") or [] if not p.get("test")]
    lines = [p for p in d.get("located") or [] if p.get("test") == "spectral line"]
    if not shares and not lines:
        det = d.get("detection_after") or d.get("detection_before") or {}
        if det.get("line_hz") and (det.get("line_p") or 1) < 0.05:
            return (f"The residuals carry a common spectral line at "
                    f"{F.sig(det['line_hz'], 3)} Hz ({_e(det.get('line_group', ''))}).")
        return "The residuals are not white, but no single place carries the mismatch."
    parts, hint = [], None
    if shares:
        p = max(shares, key=lambda q: q.get("share_of_misfit") or 0)
        tr = p.get("t_range_s") or [None, None]
        seg = str(p.get("segment", "")).replace("_", " ")
        phase = p.get("phase")
        when = ("over the whole recording" if phase in (None, "all")
                else f"while {_e(phase)}")
        parts.append(f"Most of the structured misfit ({F.percent(p.get('share_of_misfit'))}) "
                     f"is in the {_e(p.get('axis'))} residuals of markers on the "
                     f"{_e(seg)} {when} ({F.sig(tr[0], 3)}–{F.sig(tr[1], 3)} s)")
        if p.get("frequency_hz"):
            hint = _frequency_hint(p["frequency_hz"], d, p.get("axis"), p.get("segment"))
            parts[-1] += f", varying at about {F.sig(p['frequency_hz'], 2)} Hz" + hint
    if lines:
        q = lines[0]
        if q.get("frequency_hz"):
            again = _frequency_hint(q["frequency_hz"], d, q.get("axis"), q.get("segment"))
            # the same reading as the part's above is said once (it is ~150 letters)
            again = " (the same)" if again and again == hint else again
            parts.append(f"a spectral line stands out at {F.sig(q['frequency_hz'], 3)} Hz "
                         f"in {_e(q.get('axis', ''))} ({_e(q.get('segment', ''))})" + again)
        else:
            parts.append("a spectral line stands out")
    return "; ".join(parts) + "."


#: how close (relative) a misfit's frequency must be to a multiple of the lug-passing or
#: the wheels' turning frequency to be said to be locked to it
LOCKED_TOL = 0.04


def _frequency_hint(f: float, d: dict, axis, segment) -> str:
    """What a misfit's frequency is, in a track's terms, where the cruise's belt speed is
    known (the straight runs' reading, explain._straight): a multiple of the lug-passing
    frequency v/p (a link chain's polygon, lug-locked motion), of the wheels' turning
    frequency v/(2 pi R), or, in the body's x, neither (the body surging fore and aft on
    its own). "" where nothing is known or nothing fits."""
    st = d.get("straight_runs") or {}
    v, p, R = st.get("v_belt_mm_s"), st.get("pitch_mm"), st.get("R_mm")
    if not (v and p and R and f and f > 0):
        return ""
    for base, what in ((v / p, "the lug-passing frequency (motion locked to the lugs, as "
                                "a chain of links makes in rolling its polygon round the "
                                "wheels: chordal action)"),
                       (v / (2.0 * math.pi * R), "the wheels' turning frequency")):
        k = round(f / base)
        if 1 <= k <= 3 and abs(f - k * base) <= LOCKED_TOL * k * base:
            times = {1: "", 2: "twice ", 3: "three times "}[k]
            return f" ({times}{what}, {F.sig(base, 3)} Hz at cruise)"
    if axis == "x" and "body" in str(segment):
        return (" (locked neither to the lugs nor to the wheels: the body surging fore and "
                "aft on its own, as a body does on its lugs' springs)")
    if axis == "x" and "bottom" in str(segment) and f < 0.5 * v / p:
        return (" (locked neither to the lugs nor to the wheels, where the lugs hold on the "
                "ground: the body surging fore and aft over its planted lugs, as a body does "
                "on its lugs' springs)")
    return ""


def _slip(d) -> str:
    if not d or d.get("value") is None:
        return "–"
    ci = d.get("ci95") or [None, None]
    return (f"{F.pm(d['value'], d.get('std'))} "
            f"<span class=small>({F.interval(ci[0], ci[1], d.get('std'), 95)})</span>")


def _whiteness(d) -> str:
    b, a = d.get("detection_before") or {}, d.get("detection_after") or {}
    if not b:
        return ""

    def cells(x):
        if not x:
            return ["–"] * 5
        return [f"{F.sig(x.get('chi2_per_dof'), 4)} (z = {F.sig(x.get('chi2_z'), 2)})",
                f"Q = {F.sig(x.get('ljung_box_q'), 3)} on {x.get('ljung_box_dof', '–')} dof, "
                f"p = {F.sig(x.get('ljung_box_p'), 2)}",
                f"p = {F.sig(x.get('periodogram_p'), 2)} (worst {_e(x.get('periodogram_series', ''))})",
                f"{F.sig(x.get('line_hz'), 3)} Hz in {_e(x.get('line_group', ''))}, "
                f"p = {F.sig(x.get('line_p'), 2)}",
                '<span class="ok">white</span>' if x.get("consistent")
                else '<span class="bad">not white</span>']

    head = ["", "χ²/dof", "Ljung–Box", "cumulative periodogram", "strongest common line",
            "verdict"]
    rows = [["base model"] + cells(b), ["final model"] + cells(a)]
    h = "".join(f"<th>{c}</th>" for c in head)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>" for r in rows)
    alpha = b.get("alpha", 0.05)
    return (f"<h3>Whiteness tests, before and after</h3><div class=scroll><table><tr>{h}</tr>"
            f"{body}</table></div><p class=small>Each test at α/4 "
            f"(α = {F.sig(alpha, 2)} in all): p below {F.sig(alpha / 4, 2)} fails. "
            f"χ²/dof of white noise is 1 ± {F.sig(b.get('chi2_spread'), 2)}.</p>")


def _candidate_reason(c, rd, threshold, limit) -> str:
    if c["id"] == rd.get("accepted"):
        return "added (best ΔBIC of the round)"
    if c.get("rejected_because"):
        return c["rejected_because"]
    lin = c.get("delta_bic_linear")
    if c.get("delta_bic") is None:
        if lin is not None and lin >= threshold:
            return (f"not fitted: its one-step ΔBIC {F.sig(lin, 3)} is not below "
                    f"{F.sig(threshold, 2)}")
        return (f"not fitted: only the {limit} most promising candidates are fitted per "
                "round, and another was added")
    return "fitted, beaten by the added effect"


def _candidates(d) -> str:
    rounds = d.get("candidates") or []
    if not rounds:
        return ""
    crit = d.get("criterion") or {}
    thr = crit.get("delta_bic_threshold", -10.0)
    try:
        from ..explain._explain import MAX_FITS_PER_ROUND as limit
    except ImportError:  # pragma: no cover - the report does not need the explain stage
        limit = MAX_FITS_PER_ROUND
    out = ["<h3>Candidates tried</h3><div class=scroll><table><tr><th>round</th><th>effect</th>"
           "<th>ΔBIC (one step)</th><th>ΔBIC (fitted)</th><th>excess χ² removed</th>"
           "<th>outcome</th></tr>"]
    for rd in rounds:
        for c in rd.get("tried", []):
            share = c.get("misfit_removed_share")
            out.append(f"<tr><td>{rd['round']}</td><td>{_e(c['id'])}</td>"
                       f"<td>{F.sig(c.get('delta_bic_linear'), 3)}</td>"
                       f"<td>{F.sig(c.get('delta_bic'), 3)}</td>"
                       f"<td>{'' if share is None else F.percent(share)}</td>"
                       f"<td>{_e(_candidate_reason(c, rd, thr, limit))}</td></tr>")
    out.append("</table></div>")
    out.append(f"<p class=small>An effect is added when ΔBIC = Δχ² + Δk ln N &lt; "
               f"{F.sig(thr, 2)} and, when the misfit is strong, it removes at least "
               f"{F.percent(crit.get('min_share_of_strong_excess_chi2_removed', 0.3))} of the "
               "excess χ². The one-step ΔBIC is a single Gauss–Newton step from the current "
               "fit, used to rank the candidates.</p>")
    return "".join(out)


def _located(d) -> str:
    loc = d.get("located") or []
    shares = [p for p in loc if not p.get("test")]
    lines = [p for p in loc if p.get("test")]
    out = []
    if shares:
        out.append("<h3>Where the mismatch is</h3><p class=small>Shares of the structured "
                   "misfit (the sum of lag-1 residual products; zero on average for white "
                   "noise), one row per significant (axis, path segment) cell; they add to at "
                   "most 100 %.</p><div class=scroll><table><tr><th>axis</th><th>segment</th>"
                   "<th>phase</th><th>dominant frequency</th><th>time (s)</th><th>share</th>"
                   "<th>markers</th></tr>")
        for p in shares:
            tr = p.get("t_range_s") or [None, None]
            out.append(f"<tr><td>{_e(p.get('axis'))}</td>"
                       f"<td>{_e(str(p.get('segment')).replace('_', ' '))}</td>"
                       f"<td>{_e(p.get('phase'))}</td>"
                       f"<td>{F.sig(p.get('frequency_hz'), 2)} Hz</td>"
                       f"<td>{F.sig(tr[0], 3)}–{F.sig(tr[1], 3)}</td>"
                       f"<td>{F.percent(p.get('share_of_misfit'))}</td>"
                       f"<td>{_e(', '.join(p.get('markers', [])))}</td></tr>")
        out.append("</table></div>")
    if lines:
        out.append("<p>Separate tests (not shares):</p><ul>")
        for p in lines:
            out.append(f"<li>{_e(p.get('test'))}: {_e(p.get('axis', ''))} "
                       f"{_e(str(p.get('segment', '')).replace('_', ' '))}"
                       + (f" at {F.sig(p.get('frequency_hz'), 3)} Hz"
                          if p.get("frequency_hz") else "")
                       + f", p = {F.sig(p.get('p_value'), 2)}; it concentrates "
                       f"{F.percent(p.get('share_of_excess_chi2', p.get('share_of_misfit')))}"
                       " of that group's excess χ².</li>")
        out.append("</ul>")
    sysm = d.get("systematics")
    if sysm:
        eff = sysm.get("slip_effect")
        if isinstance(eff, dict):  # {delta, std, in_std}
            eff = f"{F.sig(eff.get('delta'), 2)}, {F.sig(eff.get('in_std'), 2)} σ"
        else:
            eff = F.sig(eff, 2)
        out.append(f"<p>Below the tracker-systematics floor: a structured misfit of "
                   f"{F.sig(sysm.get('amplitude_um'), 2)} µm "
                   f"({F.percent(sysm.get('share_of_misfit'))} of the misfit; effect on the "
                   f"slip {eff}). {_e(sysm.get('note', ''))}</p>")
    return "".join(out)


def discrepancy_section(fit_json: dict, state=None, plots: str | None = None) -> str:
    """HTML of "What the model left out" from a fit.json dict (empty string if absent).

    plots: :func:`discrepancy_plots` of the same fit.json's discrepancy block and state,
    drawn already (fitlug.report._aside draws them while the posterior is sampled)."""
    fj = fit_json or {}
    d = fj.get("discrepancy")
    head = '<section id="discrepancy"><h2>What the model left out</h2>'
    if not d:
        skipped = fj.get("discrepancy_skipped")
        if skipped:
            return f"{head}<p>Not examined ({_e(skipped)}).</p></section>"
        return ""
    out = [head]
    v = d.get("verdict")
    det = d.get("detection_before") or {}
    effects = d.get("effects") or []
    if v == "none":
        out.append("<p><b>Nothing.</b> The base model's residuals are consistent with the "
                   f"measurement noise (χ²/dof {_num(det.get('chi2_per_dof'))}, expected 1 ± "
                   f"{_num(det.get('chi2_spread'), 2)}); nothing was added.</p>")
    elif v == "explained":
        names = ", ".join(e["id"] for e in effects)
        out.append(f"<p><b>The base model missed {_e(names)}.</b> {located_sentence(d)} "
                   f"Adding {'it' if len(effects) == 1 else 'them'} brings χ²/dof from "
                   f"{_num(d.get('chi2_per_dof_before'))} to {_num(d.get('chi2_per_dof_after'))}."
                   "</p>")
    elif v == "modelled":
        from ._section_discovered import verdict_sentence

        out.append(f'<div class="verdict v-explained"><b>Modelled beyond the catalog.</b> '
                   f"{located_sentence(d)} {_e(verdict_sentence(d))} χ²/dof goes from "
                   f"{_num(d.get('chi2_per_dof_before'))} to "
                   f"{_num(d.get('chi2_per_dof_after'))}; the headline is the extended "
                   "model's fit, its errors carrying the term's uncertainty.</div>")
    else:
        nuis = d.get("image_motion") or d.get("marker_shift")
        how = ("what the mismatch is was found and modelled outside the catalog (below), and "
               "the headline is that model's fit" if modelled(d) else
               "so the slip's error bar includes the mismatch")
        out.append(f'<div class="verdict v-unexplained"><b>Unexplained.</b> '
                   f"{located_sentence(d)} No catalog effect earns its place; {how} "
                   f"({_e(d.get('slip_after_uncertainty', '') or fj.get('uncertainty_method', ''))}).</div>")
        if nuis:
            out.append(f"<p>A measurement nuisance holds the whole mismatch: "
                       f"{_e(nuis.get('note', ''))}. χ²/dof goes from "
                       f"{_num(nuis.get('chi2_per_dof_before'))} to "
                       f"{_num(nuis.get('chi2_per_dof_after'))}.</p>")
    sens = d.get("speed_sensitivity")
    if v == "unexplained" and sens and sens.get("headline"):
        out.append(f"<p>Refitted with a free speed profile (breakpoints "
                   f"{_num(sens.get('spacing_s'), 2)} s apart), χ²/dof goes from "
                   f"{_num(sens.get('chi2_per_dof_base'))} to {_num(sens.get('chi2_per_dof'))}: "
                   "the drive's motion has content the adaptive profile must not follow (it "
                   "would swallow lug- and wheel-locked effects), and the free fit holds the "
                   "whole mismatch, so it is the headline; the base model's slip is in the "
                   "table below.</p>")
    elif v == "unexplained" and d.get("straight_runs"):
        out.append(f"<p>Straight runs: {handling_sentence(d)}.</p>")
    elif v == "unexplained" and sens and (sens.get("shift") or {}).get("slip") is not None:
        out.append(f"<p>Speed-profile sensitivity: refitted with a free speed profile "
                   f"(breakpoints {_num(sens.get('spacing_s'), 2)} s apart), χ²/dof goes "
                   f"from {_num(sens.get('chi2_per_dof_base'))} to "
                   f"{_num(sens.get('chi2_per_dof'))} and the slip moves by "
                   f"{_num(sens['shift']['slip'], 2)}. A misfit that does not average out "
                   "biases the slip in a way no residual scatter shows, so this shift is "
                   "added in quadrature to the error bar.</p>")
    final = fj.get("slip") or d.get("slip_after")
    out.append("<div class=scroll><table><tr><th></th><th>slip ± 1 σ</th><th>χ²/dof</th></tr>"
               f"<tr><td>base model</td><td>{_slip(d.get('slip_before'))}</td>"
               f"<td>{_num(d.get('chi2_per_dof_before'))}</td></tr>"
               f"<tr><td>final model (the headline)</td><td>{_slip(final)}</td>"
               f"<td>{_num(d.get('chi2_per_dof_after'))}</td></tr></table></div>")
    if effects:
        out.append("<h3>Named effects</h3><div class=scroll><table><tr><th>effect</th>"
                   "<th>parameters ± 1 σ</th><th>ΔBIC</th><th>χ²/dof before → after</th>"
                   "<th>what it is</th></tr>")
        for e in effects:
            std = e.get("params_std") or {}
            ni = e.get("not_identifiable") or {}
            params = "<br>".join(
                f"{_e(k)} = " + (F.pm(x, std.get(k)) if x is not None
                                 else f"not identifiable ({_e(ni.get(k, ''))})")
                for k, x in (e.get("params") or {}).items())
            out.append(f"<tr><td>{_e(e['id'])}</td><td>{params}</td>"
                       f"<td>{F.sig(e.get('delta_bic'), 3)}</td>"
                       f"<td>{_num(e.get('chi2_per_dof_before'))} → "
                       f"{_num(e.get('chi2_per_dof_after'))}</td>"
                       f"<td>{_e(e.get('meaning', ''))}</td></tr>")
        out.append("</table></div>")
    if d.get("discovered"):
        from ._section_discovered import discovered_html

        out.append(discovered_html(d))
    out.append(_whiteness(d))
    out.append(_located(d))
    plots = discrepancy_plots(fj, state) if plots is None else plots
    if plots:
        out.append(plots)
    out.append(_candidates(d))
    out.append("</section>")
    return "\n".join(out)

