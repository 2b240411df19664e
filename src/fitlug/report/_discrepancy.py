"""The report's "What the model left out" section (HTML, plots as base64 PNG).

Everything it shows comes from fit.json's `discrepancy` block (written by
fitlug.explain.Explanation.to_json): the verdict, the located mismatch, each named
effect, the improvement and the slip before and after, plus the binned residual maps
and spectra of the base and the final model. `state` (the report's saved state) is
accepted for symmetry with the other sections and not needed.
"""

from __future__ import annotations

import base64
import html
import io
import math

_CSS = ("<style>.fl-disc table{border-collapse:collapse;margin:.5em 0}"
        ".fl-disc td,.fl-disc th{border:1px solid #ccc;padding:2px 8px;text-align:left;"
        "font-size:90%}.fl-disc img{max-width:100%}</style>")


def _e(x) -> str:
    return html.escape(str(x))


def _num(x, digits=4) -> str:
    if x is None:
        return "–"
    if isinstance(x, (int, float)):
        if not math.isfinite(x):
            return "–"
        return f"{x:.{digits}g}"
    return _e(x)


def _slip(d) -> str:
    if not d:
        return "–"
    ci = d.get("ci95") or [None, None]
    return f"{_num(d['value'], 6)} ± {_num(d['std'], 2)} (95 %: {_num(ci[0], 6)} … {_num(ci[1], 6)})"


def _png(fig) -> str:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    plt.close(fig)
    return ('<img alt="plot" src="data:image/png;base64,'
            + base64.b64encode(buf.getvalue()).decode("ascii") + '">')


def plot_maps(maps: dict):
    """Residual maps (series x time, mean residual in sigma) before and after, side by side.

    Each map has its own colour scale: after a good explanation the remaining residuals
    are hundreds of times smaller than before and would be invisible on a shared one.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    keys = [k for k in ("before", "after") if maps.get(k)]
    fig, axes = plt.subplots(1, len(keys), figsize=(6.5 * len(keys), 4.5), squeeze=False)
    for ax_, k in zip(axes[0], keys):
        m = maps[k]
        a = np.array([[np.nan if v is None else v for v in row]
                      for row in m["mean_residual_sigma"]], float)
        vmax = float(np.nanpercentile(np.abs(a), 99)) if np.isfinite(a).any() else 1.0
        vmax = max(vmax, 1.0)  # noise alone gives ~0.3 sigma per 0.1 s bin
        t = m["t_edges_s"]
        im = ax_.imshow(a, aspect="auto", cmap="RdBu_r", vmin=-vmax, vmax=vmax,
                        extent=[t[0], t[-1], len(m["series"]) - 0.5, -0.5],
                        interpolation="nearest")
        ax_.set_yticks(range(len(m["series"])))
        ax_.set_yticklabels(m["series"], fontsize=7)
        ax_.set_xlabel("time (s)")
        ax_.set_title(f"residuals {k} (mean per 0.1 s, sigma)", fontsize=10)
        fig.colorbar(im, ax=ax_, shrink=0.8)
    fig.tight_layout()
    return fig


def plot_spectra(spectra: dict):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 3.2))
    for k, style in (("before", "-"), ("after", "-")):
        s = spectra.get(k)
        if s and s.get("f_hz"):
            ax.semilogy(s["f_hz"], s["power"], style, lw=1, label=k)
    s = spectra.get("before") or spectra.get("after") or {}
    for key, lab, c in (("lug_passing_hz", "lug passing", "C3"),
                        ("wheel_revolution_hz", "wheel revolution", "C2")):
        f = s.get(key)
        if f:
            ax.axvline(f, color=c, ls="--", lw=0.8, label=f"{lab} {f:.2f} Hz")
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("residual power (sigma^2)")
    ax.set_xlim(0, min(50.0, max(s.get("f_hz") or [50.0])))
    ax.legend(fontsize=8)
    return fig


def plot_breakdown(before: dict, after: dict | None):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    dims = ["segment", "phase", "axis", "role"]
    fig, axes = plt.subplots(1, len(dims), figsize=(12, 2.8))
    for ax, dim in zip(axes, dims):
        b = (before or {}).get(dim, {})
        a = (after or {}).get(dim, {}) if after else {}
        names = list(b)
        x = range(len(names))
        ax.bar([i - 0.2 for i in x], [b[n]["misfit_chi2"] for n in names], 0.4, label="before")
        if a:
            ax.bar([i + 0.2 for i in x], [a.get(n, {}).get("misfit_chi2", 0.0) for n in names],
                   0.4, label="after")
        ax.set_xticks(list(x))
        ax.set_xticklabels(names, rotation=30, fontsize=7)
        ax.set_title(f"misfit by {dim}", fontsize=9)
        ax.axhline(0, color="k", lw=0.5)
    axes[0].set_ylabel("structured misfit (chi^2)")
    axes[0].legend(fontsize=7)
    return fig


def discrepancy_section(fit_json: dict, state=None) -> str:
    """HTML of "What the model left out" from a fit.json dict (empty string if absent)."""
    d = (fit_json or {}).get("discrepancy")
    if not d:
        skipped = (fit_json or {}).get("discrepancy_skipped")
        if skipped:
            return (f'<section id="discrepancy" class="fl-disc"><h2>What the model left out</h2>'
                    f"<p>Not examined ({_e(skipped)}).</p></section>")
        return ""
    out = ['<section id="discrepancy" class="fl-disc">', _CSS, "<h2>What the model left out</h2>"]
    v = d.get("verdict")
    det = d.get("detection_before") or {}
    if v == "none":
        out.append("<p><b>Nothing significant.</b> The base model's residuals are consistent "
                   f"with the measurement noise (chi²/dof {_num(det.get('chi2_per_dof'))}, "
                   f"expected 1 ± {_num(det.get('chi2_spread'), 2)}; Ljung–Box p = "
                   f"{_num(det.get('ljung_box_p'), 2)}; cumulative periodogram p = "
                   f"{_num(det.get('periodogram_p'), 2)}).</p>")
    elif v == "explained":
        names = ", ".join(e["id"] for e in d.get("effects", []))
        out.append(f"<p><b>Explained</b> by {_e(names)}: chi²/dof "
                   f"{_num(d.get('chi2_per_dof_before'))} → {_num(d.get('chi2_per_dof_after'))}."
                   "</p>")
    else:
        out.append("<p><b>Unexplained.</b> The residuals are not consistent with the noise and "
                   "no (further) catalog effect earns its place. The slip's error bar is "
                   f"widened accordingly ({_e(d.get('slip_after_uncertainty', ''))}).</p>")
    out.append("<table><tr><th></th><th>slip</th><th>chi²/dof</th></tr>"
               f"<tr><td>base model</td><td>{_slip(d.get('slip_before'))}</td>"
               f"<td>{_num(d.get('chi2_per_dof_before'))}</td></tr>"
               f"<tr><td>final model</td><td>{_slip(d.get('slip_after'))}</td>"
               f"<td>{_num(d.get('chi2_per_dof_after'))}</td></tr></table>")
    if d.get("effects"):
        out.append("<h3>Named effects</h3><table><tr><th>effect</th><th>parameters</th>"
                   "<th>ΔBIC</th><th>chi²/dof before → after</th><th>meaning</th></tr>")
        for e in d["effects"]:
            std = e.get("params_std") or {}
            params = ", ".join(f"{_e(k)} = {_num(x)}" + (f" ± {_num(std[k], 2)}" if std.get(k)
                                                        else "")
                               for k, x in (e.get("params") or {}).items())
            out.append(f"<tr><td>{_e(e['id'])}</td><td>{params}</td>"
                       f"<td>{_num(e.get('delta_bic'), 5)}</td>"
                       f"<td>{_num(e.get('chi2_per_dof_before'))} → "
                       f"{_num(e.get('chi2_per_dof_after'))}</td>"
                       f"<td>{_e(e.get('meaning', ''))}</td></tr>")
        out.append("</table>")
    if d.get("located"):
        out.append("<h3>Located mismatch</h3><table><tr><th>markers</th><th>axis</th>"
                   "<th>segment</th><th>phase</th><th>frequency (Hz)</th><th>time (s)</th>"
                   "<th>share</th></tr>")
        for p in d["located"]:
            tr = p.get("t_range_s") or [None, None]
            out.append(f"<tr><td>{_e(', '.join(p.get('markers', [])))}</td>"
                       f"<td>{_e(p.get('axis'))}</td><td>{_e(p.get('segment'))}</td>"
                       f"<td>{_e(p.get('phase'))}</td><td>{_num(p.get('frequency_hz'), 3)}</td>"
                       f"<td>{_num(tr[0], 3)} – {_num(tr[1], 3)}</td>"
                       f"<td>{_share(p)}</td></tr>")
        out.append("</table>")
    plots = []
    try:
        if d.get("maps"):
            plots.append(_png(plot_maps(d["maps"])))
        mb, ma = d.get("misfit_before") or {}, d.get("misfit_after") or {}
        if mb.get("breakdown"):
            plots.append(_png(plot_breakdown(mb["breakdown"], ma.get("breakdown"))))
        if d.get("spectra"):
            plots.append(_png(plot_spectra(d["spectra"])))
    except Exception as exc:  # a plot must never sink the report
        plots.append(f"<p>(plots unavailable: {_e(exc)})</p>")
    if plots:
        out.append("<h3>Residuals before and after</h3>" + "".join(plots))
    rounds = d.get("candidates") or []
    if rounds:
        out.append("<h3>Candidates tried</h3><table><tr><th>round</th><th>effect</th>"
                   "<th>ΔBIC (one step)</th><th>ΔBIC (fitted)</th><th>misfit removed</th>"
                   "<th>verdict</th></tr>")
        for rd in rounds:
            for c in rd.get("tried", []):
                if c.get("delta_bic") is None and c["id"] != rd.get("accepted"):
                    verdict = "not fitted (no score)"
                elif c["id"] == rd.get("accepted"):
                    verdict = "added"
                else:
                    verdict = c.get("rejected_because") or "not the best"
                share = c.get("misfit_removed_share")
                out.append(f"<tr><td>{rd['round']}</td><td>{_e(c['id'])}</td>"
                           f"<td>{_num(c.get('delta_bic_linear'), 5)}</td>"
                           f"<td>{_num(c.get('delta_bic'), 5)}</td>"
                           f"<td>{'' if share is None else f'{100 * share:.0f} %'}</td>"
                           f"<td>{_e(verdict)}</td></tr>")
        out.append("</table>")
    out.append("</section>")
    return "\n".join(out)


def _share(part: dict) -> str:
    """A located row's share; a row found by a test (a spectral line) is not a share."""
    if part.get("share_of_misfit") is None:
        x = part.get("share_of_excess_chi2")
        return f"({part.get('test', 'test')})" if x is None else \
            f"({part.get('test', 'test')}: {100 * x:.0f} % of excess chi2)"
    return f"{100 * part['share_of_misfit']:.0f} %"
