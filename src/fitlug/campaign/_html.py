"""DIR/campaign.html: the campaign on one self-contained page (figures inline, base64 PNG)."""

from __future__ import annotations

import html
import os

import numpy as np

from ..io._atomic import write_text_atomic
from ..report import _format as F
from ..report._figure import _fig, figure_html
from ..report._markup import _CSS, _table


def _fmt(x, digits=5):
    """A table cell: numbers to `digits` significant digits (never e+ notation), lists
    bracketed, None as a dash."""
    if x is None:
        return "&ndash;"
    if isinstance(x, (list, tuple)):
        return "[" + ", ".join(_fmt(v, digits) for v in x) + "]"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    try:
        return F.sig(float(x), digits)
    except (TypeError, ValueError):
        return html.escape(str(x))
from . import _model

_COLORS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#9467bd", "#8c564b", "#e377c2", "#17becf")


def _law_label(law):
    return "linear (elastic lugs)" if law == "linear" else "Janosi-Hanamoto (sliding lugs)"


def _curve_figure(result, doc) -> str:
    fig, axes = _fig(9.5, 5.2)
    ax = axes[0, 0]
    grounds = sorted({r.ground for r in result.recordings if r.point})
    col = {g: _COLORS[i % len(_COLORS)] for i, g in enumerate(grounds)}
    for g, c in result.curves.items():
        F = np.asarray(c["traction_N"])
        color = "#333" if g == "all" else col.get(g, "#333")
        lab = _law_label(result.law) + ("" if g == "all" else f", {g}")
        ax.fill_between(F, c["slip_lo95"], c["slip_hi95"], color=color, alpha=0.18,
                        lw=0, label="95 % band" if g in ("all", grounds[0]) else None)
        ax.plot(F, c["slip"], color=color, lw=1.8, label=lab)
    # the other law at its least-squares optimum, for comparison
    other = "janosi_hanamoto" if result.law == "linear" else "linear"
    fo = result.fits.get(other)
    if fo is not None:
        for g, c in result.curves.items():
            F = np.asarray(c["traction_N"])
            gg = g if g != "all" else grounds[0]
            try:
                s = _model.curve(other, fo.theta[None], fo.names, gg, F, result.nL)[0]
            except ValueError:
                continue
            ax.plot(F, s, ls="--", lw=1.0, color="#777",
                    label=f"{_law_label(other)} (least squares)" if g in ("all", grounds[0])
                    else None)
    for r in result.recordings:
        if not r.point or r.traction is None:
            continue
        sd = float(np.sqrt(max(np.asarray(r.point["cov"])[0][0], 0.0)))
        x, xs = r.traction if r.consistent else r.traction_own
        if r.consistent:
            ax.errorbar(x, r.point["slip"], xerr=xs, yerr=sd, fmt="o", ms=5,
                        color=col[r.ground], capsize=2)
        else:
            ax.errorbar(x, r.point["slip"], xerr=xs, yerr=sd, fmt="x", ms=8, color="#c92a2a",
                        capsize=2)
            ax.annotate(r.name, (x, r.point["slip"]), fontsize=8, color="#c92a2a",
                        xytext=(4, 4), textcoords="offset points")
    for g in grounds:
        ax.plot([], [], "o", color=col[g], label=f"recordings on {g}")
    if result.flagged:
        ax.plot([], [], "x", color="#c92a2a", label="flagged (not averaged in)")
    ax.set_xlabel("steady traction F0 = m C_rr g + F_d (N)")
    ax.set_ylabel("steady slip s0")
    ax.set_xlim(left=0)
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    return figure_html(fig, "slip against traction")


def _residual_figure(result) -> str:
    fig, axes = _fig(9.5, 3.0, 1, 2)
    d = result.fits[result.law].design
    pts = [r for r in result.recordings if r.point]
    pl = [_model.Point.from_dict(r.point) for r in pts]
    dd = _model._Design(pl, result.law)
    th = _model._remap(result.fits[result.law], dd)
    pred, F = dd.predict(th)
    for j, (lab, ax) in enumerate(zip(("slip", "ds/da"), axes[0])):
        y = dd.y[:, j]
        sd = np.sqrt([p.cov[j, j] for p in pl])
        z = (y - pred[0, :, j]) / sd
        c = ["#c92a2a" if not r.consistent else "#1f77b4" for r in pts]
        ax.scatter(F[0], z, c=c, s=18)
        ax.axhline(0, color="#333", lw=0.8)
        ax.set_xlabel("traction (N)")
        ax.set_ylabel(f"{lab}: (data - law) / sigma")
        ax.grid(alpha=0.3)
    del d
    return figure_html(fig, "normalised residuals of each recording against the law")


def write_campaign_html(result, doc: dict, out: str) -> str:
    e = doc["stiffness_N_per_mm"]
    parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>fitlug campaign"
             f"</title><style>{_CSS}</style></head><body>",
             "<h1>Campaign: the track's traction-slip law</h1>",
             f"<p class='small'>fitlug {html.escape(doc['fitlug_version'])}; "
             f"{len(result.recordings)} recordings, n = {_fmt(doc['n_contact'])}, "
             f"L = {_fmt(doc['load_bearing_length_mm'])} mm</p>",
             f"<div class='headline'>Law: <b>{_law_label(result.law)}</b> "
             f"(&Delta;BIC sliding &minus; linear = {_fmt(result.delta_bic, 4)}; named when "
             f"&lt; &minus;10). Lug stiffness k = <b>{_fmt(e['value'], 5)} &plusmn; "
             f"{_fmt(e['std'], 2)}</b> N/mm (95 %: {_fmt(e['ci95'], 5)})</div>"]
    if result.flagged:
        parts.append(f"<p class='warn'>{len(result.flagged)} recording(s) flagged and left out "
                     "of the law: " + ", ".join(html.escape(r.name) for r in result.flagged)
                     + " (see below).</p>")
    if result.failed:
        parts.append(f"<p class='warn'>{len(result.failed)} recording(s) failed: "
                     + ", ".join(html.escape(r.name) for r in result.failed) + "</p>")
    parts += ["<h2>Slip against traction</h2>",
              "<p>Each recording's steady slip s0 (its own fit) at its steady traction "
              "F0 = m C_rr g + F_d (C_rr of its ground from the campaign; flagged ones at "
              "their own reading m s0 / (1000 ds/da)), with 1-sigma error bars; the law's "
              "posterior median and 95 % band; dashed: the other law at its least-squares "
              "optimum.</p>", _curve_figure(result, doc), _residual_figure(result)]
    rows = []
    for name, c in doc["law"]["compared"].items():
        rows.append([_law_label(name) + (" <b>(named)</b>" if name == result.law else ""),
                     _fmt(c["chi2"], 5), str(c["n_params"]), str(c["n_data"]),
                     _fmt(c["bic"], 6),
                     ", ".join(f"{html.escape(k)} = {_fmt(v, 4)} &plusmn; "
                               f"{_fmt(c['params_std'].get(k), 2)}"
                               for k, v in c["params"].items())])
    parts += ["<h2>Linear and sliding laws compared</h2>",
              _table(["law", "chi2", "params", "data", "BIC", "least-squares parameters"], rows)]
    rows = []
    for g, c in doc["rolling_resistance"].items():
        fm = (doc.get("F_max_N") or {}).get(g)
        rows.append([html.escape(g), _fmt(c["value"], 5), _fmt(c["std"], 2),
                     _fmt(c["ci95"], 5),
                     "&ndash;" if fm is None else f"{_fmt(fm['value'], 4)} "
                     f"(95 %: {_fmt(fm['ci95'], 4)})",
                     str(sum(r.ground == g and bool(r.consistent) for r in result.recordings))])
    parts += ["<h2>Rolling resistance per ground</h2>",
              _table(["ground", "C_rr", "std", "95 %", "F_max (N)", "recordings"], rows)]
    rows = []
    for r, e in zip(result.recordings, doc["recordings"]):
        link = (f"<a href='{html.escape(e['report'])}'>{html.escape(r.name)}</a>"
                if e.get("report") else html.escape(r.name))
        s = e.get("slip") or {}
        t = e.get("traction_N") or {}
        st = ("<span class='bad'>failed</span>" if r.status == "failed" else
              "<span class='ok'>yes</span>" if r.consistent else
              "<span class='bad'>flagged</span>")
        rows.append([link, html.escape(str(r.ground)), _fmt(r.mass_kg, 4),
                     _fmt(r.drawbar_pull_N, 4),
                     f"{_fmt(t.get('value'), 4)} &plusmn; {_fmt(t.get('std'), 2)}",
                     f"{_fmt(s.get('value'), 5)} &plusmn; {_fmt(s.get('std'), 2)}",
                     _fmt(r.p_value, 3), st, _verdict(e), html.escape(r.status),
                     _fmt(r.seconds, 3)])
    parts += ["<h2>Recordings</h2>",
              _table(["recording", "ground", "mass (kg)", "pull (N)", "traction (N)", "slip",
                      "p (consistency)", "consistent", "own fit", "fit", "seconds"], rows),
              f"<p class='small'>Consistency: {html.escape(doc['consistency']['test'])}; "
              f"flagged when p &lt; {_fmt(result.alpha)}/N = "
              f"{_fmt(doc['consistency']['threshold'], 3)}.</p>"]
    if result.flagged:
        parts.append("<h2>Flagged recordings</h2><ul>" + "".join(
            f"<li><b>{html.escape(r.name)}</b>: {html.escape(r.reason or '')}</li>"
            for r in result.flagged) + "</ul>")
    if result.failed:
        parts.append("<h2>Failed recordings</h2><ul>" + "".join(
            f"<li><b>{html.escape(r.name)}</b>: <code>{html.escape(r.error or '')}</code></li>"
            for r in result.failed) + "</ul>")
    m = doc["mcmc"]
    parts += ["<h2>Posterior</h2>",
              f"<p>emcee, {m['walkers']} walkers &times; {m['steps']} steps (burn-in "
              f"{m['discard']}), autocorrelation time {_fmt(m['autocorr_time'], 3)}, ESS "
              f"{_fmt(m['ess'], 4)}, " + ("converged" if m["converged"] else
                                         "<span class='bad'>not converged</span>")
              + f", seed {m['seed']}.</p>", "</body></html>"]
    path = os.path.join(out, "campaign.html")
    write_text_atomic(path, "\n".join(parts))
    return path


def _verdict(e: dict) -> str:
    """The recording's own explanation: its verdict and the effects named (issue 32: an
    `unexplained` recording is shown as such, its point read with care)."""
    v = e.get("verdict")
    if v is None:
        return "-"
    named = ", ".join(e.get("effects") or [])
    text = html.escape(v + (f": {named}" if named else ""))
    return f"<span class='bad'>{text}</span>" if v == "unexplained" else text

