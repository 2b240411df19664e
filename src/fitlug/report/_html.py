"""DIR/report.html: one self-contained page (figures embedded as base64 PNG, no links out).

Built from DIR/fit.json and DIR/state.npz only, so `fit-lug report DIR` rebuilds it
without refitting. Sections: summary, estimates, trajectories (with the stall enlarged),
body displacement and velocity, residuals, posterior (corner plot, slippage), convergence,
discrepancy (filled by :mod:`fitlug.report._discrepancy` when that module exists).
"""

from __future__ import annotations

import base64
import html
import io
import os

import numpy as np

from . import _plots
from ._state import load_state

REFERENCE_L_MM = 127.0
REFERENCE_N = 8
DPI = 96

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:2em auto;
max-width:1100px;color:#222;line-height:1.4;padding:0 1em}
h1{font-size:1.6em;margin-bottom:.2em}h2{border-bottom:1px solid #ddd;padding-bottom:.2em;
margin-top:1.8em}table{border-collapse:collapse;margin:.6em 0;font-size:.92em}
td,th{border:1px solid #ddd;padding:.25em .6em;text-align:right}th{background:#f4f4f4}
td:first-child,th:first-child{text-align:left}img{max-width:100%;height:auto;display:block;
margin:.4em 0}.headline{font-size:1.25em;background:#f0f6ff;border-left:4px solid #08519c;
padding:.6em 1em}.warn{background:#fff4e5;border-left:4px solid #e6550d;padding:.5em 1em}
.ok{color:#2b8a3e}.bad{color:#c92a2a}.small{font-size:.85em;color:#666}
.row{display:flex;gap:1em;flex-wrap:wrap}.row>div{flex:1;min-width:300px}
"""


def figure_html(fig, alt: str) -> str:
    """A matplotlib figure as an embedded <img> (base64 PNG); closes the figure."""
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    # one draw only: layouts are set when the figure is made (bbox_inches="tight" draws twice)
    fig.savefig(buf, format="png", dpi=DPI)
    plt.close(fig)
    data = base64.b64encode(buf.getvalue()).decode("ascii")
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{data}">'


def _fig(w, h, rows=1, cols=1):
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(rows, cols, figsize=(w, h), squeeze=False, layout="constrained")
    return fig, axes


def _fmt(x, digits=5):
    if x is None:
        return "&ndash;"
    if isinstance(x, (list, tuple)):
        return "[" + ", ".join(_fmt(v, digits) for v in x) + "]"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    try:
        return f"{float(x):.{digits}g}"
    except (TypeError, ValueError):
        return html.escape(str(x))


def _table(head, rows) -> str:
    h = "".join(f"<th>{html.escape(c)}</th>" for c in head)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><tr>{h}</tr>{body}</table>"


def is_reference_rig(meta: dict) -> bool:
    """The reference robot of the paper: n = 8 lugs on L = 127 mm."""
    return (meta.get("n_contact") == REFERENCE_N
            and abs(float(meta.get("L_mm", 0)) - REFERENCE_L_MM) < 1e-6)


# ----- sections ---------------------------------------------------------------------------

_QUANTITIES = (("slip", "steady slippage s0", ""), ("delta_l_mm", "lug deflection dl'", "mm"),
               ("stiffness_N_per_mm", "lug shear stiffness k", "N/mm"),
               ("rolling_resistance", "rolling resistance C_rr", ""),
               ("k_over_m_N_per_mm_kg", "k / m", "N/(mm kg)"))
_LSQ_NAME = {"k_over_m_N_per_mm_kg": "k_over_m"}


def _summary(fj, st) -> str:
    s = fj.get("slip") or {}
    mc = fj.get("mcmc")
    parts = [f'<div class="headline">Slippage s0 = <b>{_fmt(s.get("value"), 6)}</b> '
             f'&plusmn; {_fmt(s.get("std"), 2)} (95 %: {_fmt(s.get("ci95"), 6)})']
    if is_reference_rig(st["meta"]) and fj.get("reference_paper_slip"):
        parts.append(f' &mdash; reference paper: {_fmt(fj["reference_paper_slip"])}')
    parts.append("</div>")
    verdict = (fj.get("discrepancy") or {}).get("verdict")
    effects = ", ".join((fj.get("least_squares") or {}).get("effects", [])) or "none"
    lines = [f"Input: <code>{html.escape(str(fj.get('input')))}</code>; "
             f"fitlug {html.escape(str(fj.get('fitlug_version', '')))}.",
             f"Uncertainty: {html.escape(str(fj.get('uncertainty_method', '')))}.",
             f"chi2/dof under the final model: {_fmt(fj.get('chi2_per_dof'), 4)}; effects: "
             f"{html.escape(effects)}."]
    if verdict:
        lines.append(f"Discrepancy verdict: <b>{html.escape(verdict)}</b>.")
    if mc is None:
        why = fj.get("mcmc_skipped") or "least squares only"
        lines.append(f"Posterior not sampled ({html.escape(str(why))}): the uncertainties "
                     "are the least-squares (Jacobian) ones.")
    elif not mc.get("converged"):
        parts.append(f'<p class="warn">MCMC not converged: '
                     f'{html.escape(str(mc.get("message", "")))}</p>')
    return "".join(parts) + "<p>" + "<br>".join(lines) + "</p>"


def _estimates(fj, st) -> str:
    lsq = st["meta"].get("least_squares", {})
    src = "posterior" if fj.get("mcmc") else "least squares"
    rows = []
    for key, label, unit in _QUANTITIES:
        e = fj.get(key)
        ls = lsq.get(_LSQ_NAME.get(key, key)) or {}
        if e is None:
            rows.append([label, unit, "not identifiable" if key.startswith("stiff") else
                         "&ndash;", "", "", "", ""])
            continue
        rows.append([label, unit, _fmt(e.get("value"), 6), _fmt(e.get("std"), 3),
                     _fmt(e.get("ci95"), 6), src,
                     f'{_fmt(ls.get("value"), 6)} &plusmn; {_fmt(ls.get("std"), 3)}'])
    geo, gsd = fj.get("geometry") or {}, fj.get("geometry_std") or {}
    names = {"R_mm": "wheel pitch radius R", "D_mm": "wheel distance D",
             "e_mm": "marker offset e", "pitch_mm": "lug pitch p"}
    for k, label in names.items():
        v, sd = geo.get(k), gsd.get(k)
        ci = None if v is None or sd is None else [v - 1.96 * sd, v + 1.96 * sd]
        rows.append([label, "mm", _fmt(v, 7), _fmt(sd, 3), _fmt(ci, 7), "least squares", ""])
    noise = fj.get("noise_mm") or {}
    for role in ("lug", "body"):
        rows.append([f"noise, {role} markers", "mm", _fmt(noise.get(role), 4), "", "",
                     html.escape(str(fj.get("noise_source", ""))), ""])
    return _table(["quantity", "unit", "value", "std", "95 % interval", "from",
                   "least squares"], rows) + _glitches(fj)


def _glitches(fj) -> str:
    """The samples kept out of the estimates as gross errors (fit.json `glitches`)."""
    gl = fj.get("glitches")
    if gl is None:
        return ""
    rule = html.escape(str(fj.get("glitch_rule") or ""))
    if not gl:
        return f'<p class="small">Glitches: none found ({rule}).</p>'
    rows = [[html.escape(str(g.get("marker"))), _fmt(g.get("time_s"), 5),
             _fmt(g.get("dx_mm"), 3), _fmt(g.get("dy_mm"), 3), _fmt(g.get("size_sigma"), 3)]
            for g in gl]
    return (f"<h3>Glitches kept out of the estimates ({len(gl)})</h3>"
            + _table(["marker", "time (s)", "dx (mm)", "dy (mm)", "size (sigma)"], rows)
            + f'<p class="small">Rule: {rule}.</p>')


def _trajectories(st) -> str:
    fig, ax = _fig(*_plots.trajectory_figsize(st))
    _plots.plot_trajectories(st, ax=ax[0, 0])
    a = figure_html(fig, "lug-marker trajectories in the ground frame, data and model")
    fig, ax = _fig(6, 4.5)
    _plots.plot_stall(st, ax=ax[0, 0])
    b = figure_html(fig, "horizontal stall enlarged")
    return a + b


def _kinematics(st) -> str:
    fig, ax = _fig(12, 3.6, 1, 2)
    _plots.plot_displacement(st, ax=ax[0, 0])
    _plots.plot_velocity(st, ax=ax[0, 1])
    return figure_html(fig, "body displacement and velocity over time")


def _residuals(st, fj) -> str:
    fig, ax = _fig(12, 8, 4, 1)
    for k, axis in enumerate(("x", "y")):
        _plots.plot_residuals_time(st, axis, ax=ax[k, 0])
        _plots.plot_residuals_path(st, axis, ax=ax[2 + k, 0])
    ax[0, 0].set_title("Residuals (data - model) over time and along the belt path")
    out = figure_html(fig, "residuals over time and along the path")
    if "base_lug_res_x" in st:
        base = ", ".join(st["meta"].get("base_effects") or []) or "base model"
        fig, ax = _fig(12, 4.2, 2, 1)
        for k, axis in enumerate(("x", "y")):
            _plots.plot_residuals_time(st, axis, ax=ax[k, 0], prefix="base_")
        ax[0, 0].set_title(f"Before the explanation's effects ({base}): residuals over time")
        out += figure_html(fig, "residuals before the effects were added")
    fig, ax = _fig(6, 3)
    _plots.plot_segment_rms(st, ax=ax[0, 0], noise_mm=fj.get("noise_mm"))
    out += figure_html(fig, "RMS residual per segment")
    rms = _plots.segment_rms(st)
    rows = [[g, _fmt(rms[(g, "x")][0], 3), _fmt(rms[(g, "y")][0], 3), str(rms[(g, "x")][1])]
            for g in list(_plots.SEGMENTS) + ["body"]]
    return out + _table(["segment", "RMS x (um)", "RMS y (um)", "samples"], rows)


_CORNER = (("slip", "s0"), ("stiffness_N_per_mm", "k (N/mm)"), ("k_over_m", "k/m"),
           ("rolling_resistance", "C_rr"), ("slide_mu", "1/s_K"))


def _posterior(st, fj) -> str:
    meta = st["meta"]
    if "post_samples" not in st:
        return "<p>No posterior samples (least-squares-only run).</p>"
    names = meta["post_names"]
    S = st["post_samples"]
    cols, labels = [], []
    for key, label in _CORNER:
        if key == "k_over_m" and "stiffness_N_per_mm" in names:
            continue  # k itself is shown; k/m is the same up to the mass
        if key in names:
            cols.append(names.index(key))
            labels.append(label)
    out = ""
    if len(cols) >= 2:
        fig = _plots.plot_corner(S[:, cols], labels)
        out += figure_html(fig, "corner plot of the physical parameters")
    fig, ax = _fig(7, 3.6)
    ref = fj.get("reference_paper_slip") if is_reference_rig(meta) else None
    ls = meta.get("least_squares", {}).get("slip") or {}
    _plots.plot_slip_posterior(S[:, names.index("slip")], ax=ax[0, 0], reference=ref,
                               least_squares=(ls.get("value"), ls.get("std")))
    out += figure_html(fig, "slippage posterior")
    return out


def _convergence(st, fj) -> str:
    mc = fj.get("mcmc")
    if not mc:
        return "<p>Least squares only: no chain was run.</p>"
    ok = mc.get("converged")
    status = ('<span class="ok">converged</span>' if ok
              else '<span class="bad">not converged</span>')
    rows = [["status", status], ["message", html.escape(str(mc.get("message", "")))],
            ["method", html.escape(str(mc.get("method", "")))],
            ["marginalised", html.escape(str(mc.get("marginalised", "")))],
            ["walkers", _fmt(mc.get("walkers"))], ["steps (burn-in)",
                                                    f'{_fmt(mc.get("steps"))} '
                                                    f'({_fmt(mc.get("burn_in"))})'],
            ["acceptance fraction", _fmt(mc.get("acceptance"), 3)],
            ["wall time (s)", _fmt(mc.get("seconds"), 3)], ["seed", _fmt(mc.get("seed"))]]
    tau = mc.get("autocorr_time_per_parameter") or {}
    ess = mc.get("ess_per_parameter") or {}
    for k in tau:
        rows.append([f"autocorrelation time / ESS of {html.escape(k)}",
                     f"{_fmt(tau[k], 3)} steps / {_fmt(ess.get(k), 4)}"])
    chk = mc.get("linearity_check") or {}
    if chk:
        rows.append(["linearisation check",
                     f'max |delta chi2| = {_fmt(chk.get("max_delta_chi2"), 2)} at '
                     f'{_fmt(chk.get("points"))} points {_fmt(chk.get("sigma"))} sigma out '
                     f'(tolerance {_fmt(chk.get("tolerance"))})'])
    pri = mc.get("priors") or {}
    rows.append(["priors", html.escape("; ".join(f"{k}: {v}" for k, v in pri.items()))])
    out = _table(["diagnostic", "value"], rows)
    if "post_chain" in st:
        fig, ax = _fig(8, 2.6)
        name = (st["meta"].get("post_parameters") or ["s0"])[0]
        _plots.plot_trace(st["post_chain"], ax=ax[0, 0], name=name)
        out += figure_html(fig, "walker traces")
    return out


def _discrepancy_section(fit_json: dict, state: dict) -> str:
    """HOOK: the discrepancy section, a whole <section> with its own heading, or "".

    The explain side owns it: `fitlug.report._discrepancy.discrepancy_section(fit_json,
    state) -> str` renders it when that module exists (it returns "" when fit.json has no
    'discrepancy' block). Without the module, a plain table of the block is shown.
    """
    try:
        from ._discrepancy import discrepancy_section
    except ImportError:
        discrepancy_section = None
    if discrepancy_section is not None:
        return discrepancy_section(fit_json, state)
    disc = fit_json.get("discrepancy")
    if not disc:
        return ""
    rows = [[html.escape(str(e.get("id"))), _fmt(e.get("delta_bic"), 4),
             _fmt(e.get("chi2_per_dof_before"), 4), _fmt(e.get("chi2_per_dof_after"), 4),
             html.escape(", ".join(f"{k}={_fmt(v, 4)}" for k, v in
                                   (e.get("params") or {}).items()))]
            for e in disc.get("effects", [])]
    out = f"<p>Verdict: <b>{html.escape(str(disc.get('verdict')))}</b></p>"
    if rows:
        out += _table(["effect", "delta BIC", "chi2/dof before", "after", "parameters"], rows)
    return f'<section id="discrepancy"><h2>Discrepancy</h2>{out}</section>'


def write_report(out_dir) -> str:
    """Render DIR/report.html from DIR/fit.json and DIR/state.npz; returns its path.

    Raises InputError when either file is missing or unreadable.
    """
    from .._errors import InputError
    from ..io import read_json, write_text_atomic

    out_dir = os.fspath(out_dir)
    fj_path = os.path.join(out_dir, "fit.json")
    if not os.path.isfile(fj_path):
        raise InputError(fj_path, "no fit.json in the fit folder")
    fj = read_json(fj_path)
    st = load_state(out_dir)
    title = f"fitlug report: {os.path.basename(str(fj.get('input') or out_dir))}"
    disc = _discrepancy_section(fj, st)
    sections = [
        ("summary", "Summary", _summary(fj, st)),
        ("estimates", "Estimates", _estimates(fj, st)),
        ("trajectories", "Lug-marker trajectories", _trajectories(st)),
        ("kinematics", "Body displacement and velocity", _kinematics(st)),
        ("residuals", "Residuals", _residuals(st, fj)),
        ("posterior", "Posterior", _posterior(st, fj)),
        ("convergence", "Convergence diagnostics", _convergence(st, fj)),
    ]
    body = [f'<section id="{sid}"><h2>{html.escape(h)}</h2>{content}</section>'
            for sid, h, content in sections]
    body.insert(2, disc)  # after the estimates: what the model left out, and what it cost
    body = "".join(body)
    page = (f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
            f"<title>{html.escape(title)}</title><style>{_CSS}</style></head><body>"
            f"<h1>{html.escape(title)}</h1>{body}"
            f'<p class="small">Written by fitlug from fit.json and state.npz in this folder; '
            f"`fit-lug report DIR` rebuilds it.</p></body></html>")
    path = os.path.join(out_dir, "report.html")
    write_text_atomic(path, page)
    return path
