"""The text `fit-lug` prints on the terminal, from a fit.json dictionary; and
:func:`summary`, the same text for library objects (``res.summary()``)."""

from __future__ import annotations

from ._format import interval, pm, sig, sigma_apart


def summary(res, *, explanation=None, posterior=None) -> str:
    """The terminal's text for a fit: slip, Δl', k, C_rr with 1 sigma errors and 95 %
    intervals, chi^2/dof and noise, repairs, left-out physics, posterior.

    Args:
        res: a FitResult, or an Explanation (its final fit and discrepancy are used).
        explanation: the Explanation of `res` (its verdict and effects are listed).
        posterior: a Posterior of the final fit (its estimates replace the least
            squares').

    Returns:
        str: the lines joined by newlines.

    Raises:
        TypeError: `res` is neither a FitResult nor an Explanation.
    """
    from ..explain import Explanation
    from ..fit import FitResult
    from ._fitjson import fit_json

    if isinstance(res, Explanation):
        res, explanation = res.final, res
    if not isinstance(res, FitResult):
        raise TypeError(f"summary needs a FitResult or an Explanation, got {type(res).__name__}")
    doc = fit_json(res, posterior=None if posterior is None else posterior.estimates,
                   not_identifiable=None if posterior is None else posterior.not_identifiable,
                   uncertainty_method=None if posterior is None else posterior.uncertainty_method,
                   mcmc=None if posterior is None else posterior.mcmc_json(),
                   discrepancy=None if explanation is None else explanation.to_json())
    return "\n".join(summary_lines(doc))


def _fmt(est, unit="", reason=None):
    if not est or est.get("value") is None:
        return "not identifiable" + (f": {reason}" if reason else "")
    ci = est.get("ci95") or [None, None]
    u = f" {unit}" if unit else ""
    return (f"{pm(est['value'], est.get('std'))}{u}   ({interval(ci[0], ci[1], est.get('std'))})")


def summary_lines(doc: dict) -> list[str]:
    """The lines `fit-lug` prints for fit.json dictionary `doc` (without the closing
    "wrote ..." line)."""

    why = dict(doc.get("not_identifiable") or {})
    why.setdefault("stiffness_N_per_mm", "needs [vehicle] mass_kg in rig.toml")
    lines = [
        f"fitlug: {doc['input']}   (± is 1 sigma: {doc.get('uncertainty_method', '')})",
        f"  slip s0            {_fmt(doc['slip'], reason=why.get('slip'))}",
        f"  lug deflection Δl' {_fmt(doc['delta_l_mm'], 'mm', why.get('delta_l_mm'))}",
        f"  lug stiffness k    "
        f"{_fmt(doc['stiffness_N_per_mm'], 'N/mm', why.get('stiffness_N_per_mm'))}",
        f"  rolling resistance {_fmt(doc['rolling_resistance'], reason=why.get('rolling_resistance'))}",
        f"  chi2/dof           {doc['chi2_per_dof']:.3f}   (noise: body "
        f"{1000 * doc['noise_mm']['body']:.2f} µm, lug {1000 * doc['noise_mm']['lug']:.2f} µm)",
    ]
    applied = (doc.get("orientation") or {}).get("applied") or []
    if applied:
        lines.append("  axes               " + "; ".join(applied))
    for sw in doc.get("swaps") or []:
        lines.append(f"  identity swap      {' and '.join(sw['markers'])} from "
                     f"{sw['t_s']:g} s: repaired")
    for ex in doc.get("excluded") or []:
        lines.append(f"  kept out           {ex['marker']} ({ex['role']}, {ex['n_samples']} "
                     f"samples): {ex['reason']}")
    d = doc.get("discrepancy")
    if d:
        eff = d.get("effects") or []
        lines.append(f"  left-out physics   {d['verdict']}"
                     + (": " + ", ".join(e["id"] for e in eff) if eff else ""))
        for e in eff:
            std = e.get("params_std") or {}
            ps = ", ".join(f"{k} = " + (pm(v, std.get(k)) if v is not None else "n/a")
                           for k, v in (e.get("params") or {}).items())
            lines.append(f"    {e['id']}: {ps}")
        b, s = d.get("slip_before") or {}, doc.get("slip") or {}
        if eff and b.get("value") is not None and s.get("value"):
            lines.append(f"    slip without {'it' if len(eff) == 1 else 'them'} {pm(b['value'], b.get('std'))}: "
                         f"{sig(100 * (b['value'] - s['value']) / s['value'], 2)} %, "
                         f"{sigma_apart(b['value'], s.get('std'), s['value'])} the final value")
        for e in d.get("marker_on_lug") or []:
            std = e.get("params_std") or {}
            ps = ", ".join(f"{k} = " + (pm(v, std.get(k)) if v is not None else "n/a")
                           for k, v in (e.get("params") or {}).items())
            lines.append(f"  marker on the lug  {ps} (chi2/dof {e['chi2_per_dof_before']:.3g} "
                         f"-> {e['chi2_per_dof_after']:.3g}): {e.get('reading', '')}")
        for t in d.get("discovered") or []:
            lines.append(f"    {t['family']} ({t['coordinate']})"
                         f"{' partial' if t.get('partial') else ''}: chi2/dof "
                         f"{t['chi2_per_dof_before']:.3g} -> {t['chi2_per_dof_after']:.3g}, "
                         f"delta BIC {t['delta_bic']:.3g}: {t['reading']}")
        if d.get("verdict") == "unexplained":
            from ._section_discrepancy import handling_sentence, located_sentence

            import html

            lines.append("    " + html.unescape(located_sentence(d)))
            lines.append("    " + handling_sentence(d))
    m = doc.get("mcmc")
    if m:
        lines.append(f"  posterior          {m.get('walkers')} walkers × {m.get('steps')} steps, "
                     f"ESS {_int(m.get('ess'))}, " + ("converged" if m.get("converged") else "NOT converged"))
    return lines


def _int(x):
    try:
        return f"{float(x):.0f}"
    except (TypeError, ValueError):
        return str(x)
