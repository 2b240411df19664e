"""The report's "Modelled beyond the catalog" part: each family term that fitlug.explain
kept (fit.json `discrepancy.discovered`, MODEL.md §5), in words, in a table and in a
figure: the fitted shape against its natural coordinate with its 95 % band (left) and the
term's residuals before and after it, averaged in bins of the coordinate (right).

Everything comes from fit.json; nothing here imports fitlug.explain.
"""

from __future__ import annotations

import html
import math

from . import _format as F


def _e(x) -> str:
    return html.escape(str(x))


def _num(x, digits=4) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    return F.sig(x, digits) if isinstance(x, (int, float)) else _e(x)


def verdict_sentence(d: dict) -> str:
    """One plain sentence (no HTML) of what the kept family terms are, or ""."""
    terms = d.get("discovered") or []
    if not terms:
        return ""
    what = "; ".join(t.get("reading", "").rstrip(".") for t in terms)
    if d.get("verdict") == "modelled":
        return (f"No catalog effect explains the mismatch, but a term of the "
                f"{' and '.join(t['family'] for t in terms)} famil"
                f"{'y' if len(terms) == 1 else 'ies'} models it: {what}.")
    return (f"A {' and '.join(t['family'] for t in terms)} term takes part of the mismatch "
            f"(partial: the residuals stay above the noise): {what}.")


def plot_term(t: dict):
    """Figure of one term: shape with band | binned residuals before and after."""
    from ._figure import new_figure

    fig, ax = new_figure(9.0, 3.2, 1, 2)
    a, b = ax[0, 0], ax[0, 1]
    sh = t.get("shape") or {}
    x = sh.get("coordinate") or []
    if x:
        a.fill_between(x, sh["lo"], sh["hi"], color="#9ecae1", alpha=0.6, lw=0,
                       label="95 % band")
        a.plot(x, sh["value"], color="#08519c", lw=1.6, label="fitted")
        a.axhline(0.0, color="#888", lw=0.6)
        a.set_xlabel(f"{sh.get('coordinate_name', t.get('coordinate'))} "
                     f"({sh.get('coordinate_unit', '')})")
        a.set_ylabel(sh.get("unit", ""))
        a.set_title(f"{t['family']}: the shape found")
        a.legend(loc="best")
    rb = t.get("residuals") or {}
    if rb.get("coordinate"):
        xc = rb["coordinate"]
        for key, col, lab in (("before", "#d95f02", "before"), ("after", "#1b9e77", "after")):
            ys = [float("nan") if v is None else 1000.0 * v for v in rb[key]]
            b.plot(xc, ys, "o-", ms=3, color=col, lw=1, label=lab)
        b.axhline(0.0, color="#888", lw=0.6)
        b.set_xlabel(rb.get("coordinate_name", ""))
        b.set_ylabel("mean residual (µm)")
        b.set_title("its residuals, before and after")
        b.legend(loc="best")
    return fig


def discovered_html(d: dict) -> str:
    """HTML (an <h3> part) of fit.json's discrepancy `discovered` terms, or ""."""
    terms = d.get("discovered") or []
    if not terms:
        return ""
    from ._figure import figure_html

    out = ["<h3>Modelled beyond the catalog</h3>",
           f"<p>{_e(verdict_sentence(d))}</p>",
           "<div class=scroll><table><tr><th>family</th><th>coordinate</th><th>where</th>"
           "<th>form</th><th>parameters</th><th>Δχ²</th><th>ΔBIC</th>"
           "<th>χ²/dof before → after</th></tr>"]
    for t in terms:
        where = ", ".join(x for x in (t.get("segment"), t.get("axis")) if x)
        if t.get("frequency_hz"):
            where += f", {F.sig(t['frequency_hz'], 4)} Hz"
        ps = "<br>".join(f"{_e(k)} = {_num(v)}" for k, v in (t.get("params") or {}).items()
                         if not isinstance(v, list))
        out.append(f"<tr><td>{_e(t['family'])}{' (partial)' if t.get('partial') else ''}</td>"
                   f"<td>{_e(t.get('coordinate'))}</td><td>{_e(where)}</td>"
                   f"<td>{_e(t.get('form', ''))}</td><td>{ps}</td>"
                   f"<td>{_num(t.get('delta_chi2'), 3)}</td><td>{_num(t.get('delta_bic'), 3)}</td>"
                   f"<td>{_num(t.get('chi2_per_dof_before'))} → "
                   f"{_num(t.get('chi2_per_dof_after'))}</td></tr>")
    out.append("</table></div>")
    for t in terms:
        try:
            out.append(figure_html(
                plot_term(t), f"{t['family']} term: shape and residuals",
                f"Left: the {_e(t['family'])} term's shape against its coordinate, with its "
                "95 % band (the coefficients' uncertainty, marginal over every other "
                "parameter). Right: the mean residual of the samples it acts on, in bins "
                "of its coordinate, before the term (the catalog's final model) and after. "
                f"Reading: {_e(t.get('reading', ''))}"))
        except Exception as exc:  # noqa: BLE001 - a plot must never sink the report
            out.append(f"<p>(plot unavailable: {_e(exc)})</p>")
    return "\n".join(out)
