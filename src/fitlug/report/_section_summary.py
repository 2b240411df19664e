"""The report's first screen: the headline box (what was measured, the slip and the derived
quantities with one 1 σ error each, the rig as given) and the verdict on left-out physics
in words; with the quantity helpers the estimates section shares."""

from __future__ import annotations

import math

from .._reference import is_reference_rig as reference_rig
from . import _format as F
from ._markup import _e


def is_reference_rig(fj: dict, meta: dict | None = None) -> bool:
    """The reference study's robot (`fitlug._reference.is_reference_rig`: n = 8, L = 127 mm,
    lug pitch 18.36 mm as given or fitted), from a fit.json's rig and geometry; `meta` (the
    state's) gives n and L where the fit.json has no rig. A rig nobody gave (`assumed`,
    the reference's values standing in for it) is not the reference study's."""
    rig, meta = fj.get("rig") or {}, meta or {}
    if rig.get("assumed"):  # no rig given: nothing says the robot is the reference's
        return False
    return reference_rig(rig.get("lugs_in_contact", meta.get("n_contact")),
                         rig.get("load_bearing_length_mm", meta.get("L_mm")),
                         rig.get("lug_pitch_mm"), (fj.get("geometry") or {}).get("pitch_mm"))


_QUANTITIES = (("slip", "steady slippage s₀", ""), ("delta_l_mm", "lug deflection Δl′", "mm"),
               ("stiffness_N_per_mm", "lug shear stiffness k", "N/mm"),
               ("rolling_resistance", "rolling resistance C<sub>rr</sub>", ""),
               ("k_over_m_N_per_mm_kg", "k / m", "N/(mm·kg)"))
_LSQ_NAME = {"k_over_m_N_per_mm_kg": "k_over_m"}


def _not_identifiable(fj, key, said: dict | None = None, label: str = "") -> str:
    """'not identifiable: <the reason>' for quantity `key`. With `said` (reason -> the
    label of the quantity it was first given for, filled here), a reason already given in
    the same box or table is named, not repeated: a run where no slip is read gives the
    same two-line reason for all five quantities."""
    why = (fj.get("not_identifiable") or {}).get(key)
    if why and said is not None and said.setdefault(why, label) != label:
        return f"not identifiable: as {said[why]}"
    if why:
        return f"not identifiable: {_e(why)}"
    if key.startswith("stiff"):
        return "not identifiable: no mass in rig.toml (only k/m)"
    return "not identifiable"


def _pm(est, unit="") -> str:
    if not est or est.get("value") is None:
        return "–"
    return F.pm(est.get("value"), est.get("std"), unit=unit)


def _sliding(fj) -> bool:
    return "lug_sliding" in ((fj.get("least_squares") or {}).get("effects") or [])


def _widened(fj) -> str:
    """Why the headline error is wider than the least-squares one, or "" (the method is
    named by the headline's note beside it)."""
    d = fj.get("discrepancy") or {}
    if d.get("verdict") != "unexplained":
        return ""
    from ._section_discrepancy import modelled

    if modelled(d):
        return ""  # the mismatch was modelled (outside the catalog): not a widened error
    return ("the residuals hold a mismatch no catalog effect explains, so the error bar "
            "includes it")


def _located_sentence(d: dict) -> str:
    from ._section_discrepancy import located_sentence

    return located_sentence(d)


def _verdict_box(fj) -> str:
    """The verdict's box, and (beside any verdict but 'none', which says it) the marker's
    place on the lug where the explanation fitted it."""
    d = fj.get("discrepancy") or {}
    mol = "".join(f" {_e((e.get('reading') or '').capitalize())}."
                  for e in d.get("marker_on_lug") or [])
    extra = (f'<div class="verdict v-none"><b>Marker on the lug.</b>{mol}</div>'
             if mol and d.get("verdict") != "none" else "")
    return _verdict_main(fj) + extra


def _verdict_main(fj) -> str:
    d = fj.get("discrepancy")
    if not d:
        why = fj.get("discrepancy_skipped")
        return (f'<div class="verdict v-explained">Left-out physics not examined'
                f'{f" ({_e(why)})" if why else ""}.</div>')
    v = d.get("verdict")
    s = fj.get("slip") or {}
    mol = "".join(f" {_e((e.get('reading') or '').capitalize())} (χ²/dof "
                  f"{F.sig(e.get('chi2_per_dof_before'), 4)} → "
                  f"{F.sig(e.get('chi2_per_dof_after'), 4)} with h and τ fitted)."
                  for e in d.get("marker_on_lug") or [])
    if v == "none" and mol:
        return ('<div class="verdict v-none"><b>No left-out physics.</b> The base model '
                'fits to the measurement noise with the lug markers placed on their lugs '
                f'(MODEL.md §2\'s h and τ).{mol}</div>')
    if v == "none":
        det = d.get("detection_before") or {}
        return ('<div class="verdict v-none"><b>No left-out physics.</b> The base model fits '
                f'to the measurement noise (χ²/dof {F.sig(det.get("chi2_per_dof"), 4)}, '
                f'expected 1 ± {F.sig(det.get("chi2_spread"), 2)}; residuals white): the slip '
                'above needs no correction.</div>')
    if v == "explained":
        effs = d.get("effects") or []
        names = ", ".join(f"<b>{_e(e['id'])}</b>" for e in effs)
        meaning = " ".join(_e(e.get("meaning", "")) for e in effs if e.get("meaning"))
        b = d.get("slip_before") or {}
        off = ""
        if b.get("value") is not None and s.get("value"):
            rel = (b["value"] - s["value"]) / s["value"]
            sig = F.sigma_apart(b["value"], s.get("std"), s["value"])
            side = "below" if rel < 0 else "above"
            nsig = F.sigma_apart(b["value"], s.get("std"), s["value"]).split(" σ")[0]
            off = (f" Without {'it' if len(effs) == 1 else 'them'} the base model's slip was "
                   f"{F.pm(b['value'], b.get('std'))}: {F.sig(abs(100 * rel), 2)} % {side} "
                   f"the corrected value, {nsig} σ off.")
        return (f'<div class="verdict v-explained"><b>Explained</b> by {names} '
                f'(χ²/dof {F.sig(d.get("chi2_per_dof_before"), 4)} → '
                f'{F.sig(d.get("chi2_per_dof_after"), 4)}).{off} {meaning}</div>')
    from ._section_discrepancy import handling_sentence
    from ._section_discovered import verdict_sentence

    if v == "modelled":
        return (f'<div class="verdict v-explained"><b>Modelled beyond the catalog.</b> '
                f'{_e(verdict_sentence(d))} χ²/dof {F.sig(d.get("chi2_per_dof_before"), 4)} → '
                f'{F.sig(d.get("chi2_per_dof_after"), 4)}; the slip above is the extended '
                "model's, its error carrying the term's uncertainty.</div>")
    sentence = _located_sentence(d)
    if d.get("far_from_data"):  # no slip read (explain._straight.far_from_data)
        tail = "."
    elif _widened(fj):  # the error bar carries the mismatch
        # the method once on the page's top (the headline's note names it): here only
        # where the verdict's own differs from it
        how = d.get("slip_after_uncertainty")
        how = f" ({_e(how)})" if how and how not in (fj.get("uncertainty_method") or "") else ""
        tail = f"{how}; treat the slip as a measurement with an unmodelled systematic."
    else:  # modelled outside the catalog: the headline is that model's fit
        tail = "."
    return ('<div class="verdict v-unexplained"><b>⚠ Unexplained mismatch.</b> The residuals '
            'are not consistent with the noise and no catalog effect earns its place. '
            f'{sentence} {_e(_cap(handling_sentence(d)))}{tail}</div>')


def _cap(text: str) -> str:
    return text[:1].upper() + text[1:]


def _given(x) -> str:
    """A rig input as it was given (no digits added): 127, 18.36, 10."""
    try:
        return f"{float(x):g}"
    except (TypeError, ValueError):
        return "–"


def _rig_line(fj, st) -> str:
    rig = fj.get("rig") or {}
    meta = st.get("meta", {})
    parts = [f"n = {_e(rig.get('lugs_in_contact', meta.get('n_contact')))} lugs in contact",
             f"L = {_given(rig.get('load_bearing_length_mm', meta.get('L_mm')))} mm",
             f"lug pitch {_given(rig.get('lug_pitch_mm'))} mm"]
    m = rig.get("mass_kg")
    parts.append(f"mass {_given(m)} kg" if m is not None else "mass not given")
    dp = rig.get("drawbar_pull_N")
    if dp is not None:
        parts.append(f"drawbar pull {_given(dp)} N" + (" (a push)" if dp < 0 else ""))
    ground = rig.get("ground")
    g = rig.get("ground_name") or (ground.get("name") if isinstance(ground, dict) else ground)
    if g:
        parts.append(f"ground: {_e(g)}")
    if rig.get("assumed"):
        return ("Rig: none given (no rig.toml), the reference robot's values assumed: "
                + ", ".join(parts) + ".")
    return "Rig (as given): " + ", ".join(parts) + "."


def _headline(fj, st) -> str:
    s = fj.get("slip") or {}
    rows = []
    said: dict = {}  # reasons given in this box (_not_identifiable)
    cmp_value, cmp_std, cmp_what = s.get("value"), s.get("std"), "this fit is"
    if _sliding(fj):
        dl = fj.get("delta_l_mm") or {}
        rig = fj.get("rig") or {}
        n, L = rig.get("lugs_in_contact"), rig.get("load_bearing_length_mm")
        if dl.get("value") is not None and n and L:
            s_el = dl["value"] * (n - 1) / L
            s_el_sd = (dl.get("std") or 0) * (n - 1) / L
            rows.append(["total slip s₀ (elastic + sliding)",
                         f'<span class="big">{_pm(s)}</span>',
                         "the track's steady slip under the sliding law: what the robot loses"])
            cmp_value, cmp_std = s_el, s_el_sd
            cmp_what = "the paper measured the elastic slip; this fit's elastic slip is"
            rows.append(["elastic slip Δl′(n−1)/L", F.pm(s_el, s_el_sd),
                         "lug shear alone, the paper's mechanism"])
            rows.append(["sliding part", F.sig(s["value"] - s_el, 3) if s.get("value") else "–",
                         "lug tips slipping at the friction limit"])
        else:
            rows.append(["slippage s₀", f'<span class="big">{_pm(s)}</span>', ""])
    elif s.get("value") is None:
        rows.append(["slippage s₀", _not_identifiable(fj, "slip", said, "the slippage s₀"), ""])
    else:
        rows.append(["slippage s₀", f'<span class="big">{_pm(s)}</span>', ""])
    for key, label, unit in _QUANTITIES[1:4]:
        e = fj.get(key)
        if e is None or e.get("value") is None:
            rows.append([label, _not_identifiable(fj, key, said, f"the {label}"), ""])
        else:
            rows.append([label, _pm(e, unit), ""])
    if not fj.get("stiffness_N_per_mm") and fj.get("k_over_m_N_per_mm_kg"):
        rows.append(["k / m", _pm(fj["k_over_m_N_per_mm_kg"], "N/(mm·kg)"), ""])
    body = "".join(f"<tr><td>{a}</td><td>{b}</td><td class=small>{c}</td></tr>"
                   for a, b, c in rows)
    notes = ["± is one standard error (1 σ) from "
             f"{_e(fj.get('uncertainty_method') or 'the fit')}; the same error is used "
             "everywhere on this page."]
    w = _widened(fj)
    ls_std = ((st.get("meta", {}).get("least_squares") or {}).get("slip") or {}).get("std")
    # the posterior's std is itself an estimate (relative sd 1/sqrt(2 ESS)): a posterior
    # tempered to the robust error scatters around it, one that left the mismatch out is
    # narrower by far (x 1/35 on a knocked marker)
    ess = (fj.get("mcmc") or {}).get("ess")
    tol = max(0.01, 3.0 / math.sqrt(2.0 * ess)) if ess and ess > 0 else 0.01
    if w and s.get("std") and ls_std and s["std"] < (1.0 - tol) * ls_std:
        notes.append(f'<span class="bad">Caution: the residuals hold an unexplained mismatch, '
                     f"and this error ({_e(fj.get('uncertainty_method', ''))}) does not include "
                     f"it; the least-squares error that does is ± {F.sig(ls_std, 2)}.</span>")
    elif w:
        notes.append(f"The error was widened: {w}.")
    ref = fj.get("reference_paper_slip")
    if ref and is_reference_rig(fj, st.get("meta", {})) and cmp_std:
        notes.append(f"Reference paper: s = {F.num(ref, 4)} (quoted to 4 digits); {cmp_what} "
                     f"{F.sigma_apart(cmp_value, cmp_std, ref)} it"
                     + (", within the paper's rounding." if abs(cmp_value - ref) < 1e-5
                        else "."))
    mc = fj.get("mcmc")
    if not mc:
        why = fj.get("mcmc_skipped") or "least squares only"
        # fitlug's own mcmc_skipped says what the errors are ("--no-mcmc: uncertainties
        # are least squares (Jacobian)"): the page said it twice
        notes.append(f"Posterior not sampled ({_e(why)})." if "uncertainties are" in why else
                     f"Posterior not sampled ({_e(why)}): the errors are the least-squares "
                     "(Jacobian) ones.")
    elif not mc.get("converged"):
        notes.append(f'<span class="bad">The posterior chain did not converge: '
                     f'{_e(mc.get("message", ""))}</span>')
    return (f'<div class="headline"><table>{body}</table>'
            f'<p class="small">{" ".join(notes)}</p>{_verdict_box(fj)}'
            f'<p class="small">{_rig_line(fj, st)}</p></div>')
