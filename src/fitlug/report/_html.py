"""DIR/report.html: one self-contained page (figures embedded as base64 PNG, no links out).

Built from DIR/fit.json and DIR/state.npz (and DIR/posterior.nc for the chain diagnostics,
when present), so `fit-lug report DIR` rebuilds it without refitting. The first screen is
the headline box: what was measured, on which rig, the slip and the derived quantities with
one 1 σ error each (the fit.json one, used everywhere on the page), and the verdict on
left-out physics in words. Then a table of contents and the sections: estimates, the slip
drawn (s(t), slip against traction force, the stall), what the model left out
(:mod:`fitlug.report._discrepancy`), trajectories, kinematics, residuals (per marker too),
least-squares statistics, posterior, convergence. Numbers go through
:mod:`fitlug.report._format`: digits set by the uncertainty.
"""

from __future__ import annotations

import base64
import html
import io
import math
import os

import numpy as np

from . import _format as F
from . import _plots
from ._state import load_state

REFERENCE_L_MM = 127.0
REFERENCE_N = 8
DPI = 96
FIG_W = 9.0  # inches: 864 px at 96 dpi, readable when the page is 800 px wide

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:1.2em auto;
max-width:1100px;color:#222;line-height:1.45;padding:0 1em}
h1{font-size:1.6em;margin:.2em 0}h2{border-bottom:1px solid #ddd;padding-bottom:.2em;
margin-top:1.8em}.meta{color:#555;font-size:.9em;overflow-wrap:anywhere}
table{border-collapse:collapse;margin:.6em 0;font-size:.92em;max-width:100%}
.scroll{overflow-x:auto;max-width:100%}
td,th{border:1px solid #ddd;padding:.25em .6em;text-align:right;vertical-align:top}
th{background:#f4f4f4}td:first-child,th:first-child{text-align:left}
figure{margin:1em 0}figure img{max-width:100%;height:auto;display:block}
figcaption{font-size:.88em;color:#444;margin-top:.3em}
.headline{background:#f0f6ff;border-left:5px solid #08519c;padding:.7em 1.1em;margin:.8em 0}
.headline table{font-size:1em;border:none}.headline td{border:none;padding:.1em .8em .1em 0}
.headline .big{font-size:1.35em;font-weight:600;white-space:nowrap}
.verdict{padding:.6em 1em;margin:.6em 0;border-left:5px solid}
.v-none{background:#ebfbee;border-color:#2b8a3e}.v-explained{background:#fff9db;border-color:#f08c00}
.v-unexplained{background:#ffe3e3;border-color:#c92a2a}
.warn{background:#fff4e5;border-left:4px solid #e6550d;padding:.5em 1em}
.ok{color:#2b8a3e}.bad{color:#c92a2a}.small{font-size:.85em;color:#666}
nav.toc{font-size:.92em;columns:2 16em;background:#fafafa;padding:.5em 1em;border:1px solid #eee}
nav.toc a{text-decoration:none}code{overflow-wrap:anywhere}
"""


#: zlib level of the embedded PNGs: 3 encodes in 2/3 of the default's (6) time for 5 % more
#: bytes
PNG_COMPRESS_LEVEL = 3
_PENDING: list = []  # inside write_report: [executor, {token: future}] (PNGs encoded aside)


def figure_html(fig, alt: str, caption: str = "") -> str:
    """A matplotlib figure as an embedded <img> in a <figure> with its caption; closes it.

    The figure is laid out (:func:`fitlug.report._layout.tidy`), drawn once at DPI and
    encoded as an RGB PNG (the page is white). Inside :func:`write_report` the encoding
    (zlib, which releases the GIL) runs in a helper thread while the next figure is drawn,
    and a placeholder stands in the page until it is done."""
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from ._layout import tidy

    if fig.dpi != DPI:
        fig.set_dpi(DPI)
    canvas = fig.canvas if isinstance(fig.canvas, FigureCanvasAgg) else FigureCanvasAgg(fig)
    tidy(fig)
    canvas.draw()  # one draw only: the layout is set above
    rgb = np.asarray(canvas.buffer_rgba())[..., :3].copy()
    _close(fig)
    if _PENDING:
        pool, futures = _PENDING[-1]
        token = f"\x00fitlug-figure-{len(futures)}\x00"
        futures[token] = pool.submit(_figure_tag, rgb, alt, caption)
        return token
    return _figure_tag(rgb, alt, caption)


def _figure_tag(rgb, alt: str, caption: str) -> str:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(rgb, "RGB").save(buf, format="png", dpi=(DPI, DPI),
                                     compress_level=PNG_COMPRESS_LEVEL)
    data = base64.b64encode(buf.getvalue()).decode("ascii")
    cap = f"<figcaption>{caption}</figcaption>" if caption else ""
    return (f'<figure><img alt="{html.escape(alt)}" '
            f'src="data:image/png;base64,{data}">{cap}</figure>')


class _encoded_aside:
    """Within this block figure_html returns placeholders and encodes in a helper thread;
    :meth:`fill` puts the figures into the page."""

    def __enter__(self):
        from concurrent.futures import ThreadPoolExecutor

        self.pool = ThreadPoolExecutor(1, thread_name_prefix="fitlug-png")
        self.futures: dict = {}
        _PENDING.append((self.pool, self.futures))
        return self

    def fill(self, page: str) -> str:
        for token, fut in self.futures.items():
            page = page.replace(token, fut.result(), 1)
        return page

    def __exit__(self, *exc):
        _PENDING.remove((self.pool, self.futures))
        self.pool.shutdown(wait=True)
        return False


def _close(fig) -> None:
    """Forget a figure pyplot knows of (one made by :mod:`._layout` it never saw)."""
    import sys

    plt = sys.modules.get("matplotlib.pyplot")
    if plt is not None and fig.canvas.manager is not None:
        plt.close(fig)


def _fig(w, h, rows=1, cols=1, **kw):
    return _plots.new_figure(w, h, rows, cols, **kw)


def _e(x) -> str:
    return html.escape(str(x))


def _table(head, rows) -> str:
    h = "".join(f"<th>{c}</th>" for c in head)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>" for r in rows)
    return f'<div class="scroll"><table><tr>{h}</tr>{body}</table></div>'


def is_reference_rig(meta: dict) -> bool:
    """The reference robot of the paper: n = 8 lugs on L = 127 mm."""
    return (meta.get("n_contact") == REFERENCE_N
            and abs(float(meta.get("L_mm", 0) or 0) - REFERENCE_L_MM) < 1e-6)


def recording_label(fj: dict, out_dir: str) -> str:
    """The recording's name: the CSV's folder for trajectories.csv, else the file's stem."""
    path = str(fj.get("input") or "")
    if not path:
        return os.path.basename(os.path.abspath(out_dir))
    stem = os.path.splitext(os.path.basename(path))[0]
    if stem == "trajectories":
        parent = os.path.basename(os.path.dirname(path))
        return parent or stem
    return stem


# ----- quantities -------------------------------------------------------------------------

_QUANTITIES = (("slip", "steady slippage s₀", ""), ("delta_l_mm", "lug deflection Δl′", "mm"),
               ("stiffness_N_per_mm", "lug shear stiffness k", "N/mm"),
               ("rolling_resistance", "rolling resistance C<sub>rr</sub>", ""),
               ("k_over_m_N_per_mm_kg", "k / m", "N/(mm·kg)"))
_LSQ_NAME = {"k_over_m_N_per_mm_kg": "k_over_m"}


def _not_identifiable(fj, key) -> str:
    why = (fj.get("not_identifiable") or {}).get(key)
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
    """Why the headline error is wider than the least-squares one, or ""."""
    d = fj.get("discrepancy") or {}
    if d.get("verdict") != "unexplained":
        return ""
    from ._discrepancy import modelled

    if modelled(d):
        return ""  # the mismatch was modelled (outside the catalog): not a widened error
    how = d.get("slip_after_uncertainty") or fj.get("uncertainty_method") or ""
    return ("the residuals hold a mismatch no catalog effect explains, so the error bar "
            "includes it" + (f" ({_e(how)})" if how else ""))


def _located_sentence(d: dict) -> str:
    from ._discrepancy import located_sentence

    return located_sentence(d)


def _verdict_box(fj) -> str:
    d = fj.get("discrepancy")
    if not d:
        why = fj.get("discrepancy_skipped")
        return (f'<div class="verdict v-explained">Left-out physics not examined'
                f'{f" ({_e(why)})" if why else ""}.</div>')
    v = d.get("verdict")
    s = fj.get("slip") or {}
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
    from ._discrepancy import handling_sentence

    sentence = _located_sentence(d)
    if _widened(fj):  # the error bar carries the mismatch
        tail = (f' ({_e(d.get("slip_after_uncertainty") or fj.get("uncertainty_method") or "widened")}); '
                'treat the slip as a measurement with an unmodelled systematic.')
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
        parts.append(f"drawbar pull {_given(dp)} N")
    ground = rig.get("ground")
    g = rig.get("ground_name") or (ground.get("name") if isinstance(ground, dict) else ground)
    if g:
        parts.append(f"ground: {_e(g)}")
    return "Rig (as given): " + ", ".join(parts) + "."


def _headline(fj, st) -> str:
    s = fj.get("slip") or {}
    rows = []
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
    else:
        rows.append(["slippage s₀", f'<span class="big">{_pm(s)}</span>', ""])
    for key, label, unit in _QUANTITIES[1:4]:
        e = fj.get(key)
        if e is None or e.get("value") is None:
            rows.append([label, _not_identifiable(fj, key), ""])
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
    if ref and is_reference_rig(st.get("meta", {})) and cmp_std:
        notes.append(f"Reference paper: s = {F.num(ref, 4)} (quoted to 4 digits); {cmp_what} "
                     f"{F.sigma_apart(cmp_value, cmp_std, ref)} it"
                     + (", within the paper's rounding." if abs(cmp_value - ref) < 1e-5
                        else "."))
    mc = fj.get("mcmc")
    if not mc:
        why = fj.get("mcmc_skipped") or "least squares only"
        notes.append(f"Posterior not sampled ({_e(why)}): the errors are the least-squares "
                     "(Jacobian) ones.")
    elif not mc.get("converged"):
        notes.append(f'<span class="bad">The posterior chain did not converge: '
                     f'{_e(mc.get("message", ""))}</span>')
    return (f'<div class="headline"><table>{body}</table>'
            f'<p class="small">{" ".join(notes)}</p>{_verdict_box(fj)}'
            f'<p class="small">{_rig_line(fj, st)}</p></div>')


def _meta_line(fj) -> str:
    prov = fj.get("provenance") or {}
    cmd = prov.get("command") or fj.get("command")
    date = fj.get("date_utc") or prov.get("date_utc")
    parts = []
    if date:
        parts.append(f"fitted {_e(date)}")
    parts.append(f"fitlug {_e(prov.get('fitlug_version') or fj.get('fitlug_version', ''))}")
    parts.append(f"input <code>{_e(fj.get('input'))}</code>")
    if cmd:
        parts.append(f"command <code>{_e(cmd)}</code>")
    if prov.get("input_sha256"):
        parts.append(f"input sha256 <code>{_e(str(prov['input_sha256'])[:12])}…</code>")
    return '<p class="meta">' + " · ".join(parts) + "</p>"


def _estimates(fj, st) -> str:
    lsq = st["meta"].get("least_squares", {})
    src = "posterior" if fj.get("mcmc") else "least squares"
    rows = []
    for key, label, unit in _QUANTITIES:
        e = fj.get(key)
        ls = lsq.get(_LSQ_NAME.get(key, key)) or {}
        if e is None or e.get("value") is None:
            rows.append([label, unit, _not_identifiable(fj, key), "", "",
                         _pm(ls) if ls.get("value") is not None and key in fj else ""])
            continue
        ci = e.get("ci95") or [None, None]
        rows.append([label, unit, _pm(e), F.interval(ci[0], ci[1], e.get("std"), 95), src,
                     _pm(ls)])
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


# ----- the slip drawn ---------------------------------------------------------------------

def _slip_section(fj, st) -> str:
    out = []
    fig, ax = _fig(FIG_W, 3.4)
    _plots.plot_slip_time(st, fj, ax=ax[0, 0])
    _, _, lo, hi = _plots.slip_band(st)
    half = float(np.nanmedian(hi - lo)) / 2
    out.append(figure_html(
        fig, "steady slip s(t) over the recording with its 1 sigma band",
        "The model's slip s(t) = s₀ + β·a(t) over the recording (line) with its 1 σ band "
        "(shaded; from the posterior samples of s₀ and β, else the least-squares errors); "
        f"the dashed line is the steady slip s₀. The band is ± {F.sig(half, 2)} at cruise"
        + (", too narrow to see at this scale. " if half < 0.01 * np.ptp(st["fine_s"]) else ". ")
        + "Look for the slip rising while the robot "
        "accelerates and falling while it brakes; at rest the slip is undefined (grey)."
        + (" Under lug_sliding the law is nonlinear." if _sliding(fj) else "")))
    fig, ax = _fig(FIG_W, 4.2)
    _plots.plot_slip_force(st, fj, ax=ax[0, 0])
    m = (fj.get("rig") or {}).get("mass_kg")
    out.append(figure_html(
        fig, "slip against traction force, data binned by phase and the fitted law",
        "Slip against the traction load F = m(a + C_rr g)"
        + ("" if m else " per kilogram (no mass given)")
        + ": points are the slip measured from the lug markers on the ground (their "
        "rearward creep relative to the body, binned, ±1 σ of each bin), coloured by phase "
        "(accelerating, cruising, braking); the line is the fitted law. Look for the "
        "points following the line; a bend away from it at high load means the lugs slide."))
    fig, ax = _fig(FIG_W, 4.4)
    creep = _plots.plot_stall(st, ax=ax[0, 0], slip=(fj.get("slip") or {}).get("value"),
                              D_mm=(fj.get("geometry") or {}).get("D_mm"))
    cap = ("One lug marker's stall on the ground, enlarged: data (dots, coloured by time) "
           "and model (line). Without slip the marker would stand still on the ground while "
           "its lug is loaded (the dashed vertical no-slip path); with slip it creeps "
           "rearward by s·D over the contact.")
    if creep:
        cap += (f" Measured creep {F.sig(creep['measured_mm'], 3)} mm; "
                f"s₀·D = {F.sig(creep['expected_mm'], 3)} mm.")
    out.append(figure_html(fig, "horizontal stall of one lug marker with creep length and "
                                "no-slip path", cap))
    return "".join(out)


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
    return (f"<h3>Glitches kept out of the estimates ({len(gl)})</h3>"
            + _table(["marker", "time (s)", "dx (mm)", "dy (mm)", "size (σ)"], rows)
            + f'<p class="small">Rule: {rule}.</p>')


def _trajectories(st) -> str:
    w, h = _plots.trajectory_figsize(st, width=FIG_W)
    fig, ax = _fig(w, h)
    _plots.plot_trajectories(st, ax=ax[0, 0])
    return figure_html(fig, "lug-marker trajectories in the ground frame, data and model",
                       "Every lug marker's path in the ground frame (dots: data, lines: "
                       "model) and the body markers (grey). The box marks the stall enlarged "
                       "above. Look for model lines through every cusp.")


def _kinematics(st) -> str:
    fig, ax = _fig(FIG_W, 6.0, 2, 1)
    _plots.plot_displacement(st, ax=ax[0, 0])
    _plots.plot_velocity(st, ax=ax[1, 0])
    return figure_html(fig, "body displacement and velocity over time",
                       "Top: body displacement X(t) (the paper's Fig. 13). Bottom: body "
                       "speed v and belt speed v_t = v/(1 − s) (Fig. 14); the gap between "
                       "them is the slip.")


def _residuals(st, fj) -> str:
    fig, ax = _fig(FIG_W, 8.5, 4, 1)
    for k, axis in enumerate(("x", "y")):
        _plots.plot_residuals_time(st, axis, ax=ax[k, 0])
        _plots.plot_residuals_path(st, axis, ax=ax[2 + k, 0], P=st["meta"].get(
            "belt_length_mm"))
    out = figure_html(fig, "residuals over time and along the belt coordinate",
                      "Residuals (data − model, µm) over time (top two) and along the belt "
                      "coordinate u (bottom two: where on the belt loop the marker was, "
                      "0 to the belt length P), coloured by path segment. Look for structure: "
                      "white noise is a flat band. Vertical stripes over time are the robot "
                      "at rest (many samples at one place).")
    fig, ax = _fig(6.5, 3.2)
    _plots.plot_segment_rms(st, ax=ax[0, 0], noise_mm=fj.get("noise_mm"))
    out += figure_html(fig, "RMS residual per path segment and axis",
                       "RMS residual per path segment and axis against the measured noise "
                       "levels (lines): bars far above their line point at left-out physics.")
    rms = _plots.segment_rms(st)
    rows = [[g, F.sig(rms[(g, "x")][0], 3), F.sig(rms[(g, "y")][0], 3), str(rms[(g, "x")][1])]
            for g in list(_plots.SEGMENTS) + ["body"]]
    out += _table(["segment", "RMS x (µm)", "RMS y (µm)", "samples"], rows)
    out += _markers(st, fj)
    return out


def _markers(st, fj) -> str:
    fig = _plots.plot_marker_residuals(st, glitches=fj.get("glitches"))
    out = figure_html(fig, "residuals per marker over time (small multiples)",
                      "Residual size |r|/σ per marker over time (one panel each, same "
                      "scale); gaps are frames where the marker was not seen, red crosses "
                      "glitches kept out of the fit. Look for one marker unlike the others.")
    cov = _plots.marker_coverage(st)
    listed = {str(m.get("id")): m for m in fj.get("markers") or []}
    rows = []
    for name, c in cov.items():
        m = listed.get(name, {})
        ids = m.get("ids") or []
        rows.append([_e(name), _e(m.get("role", c["role"])),
                     F.percent(m.get("coverage", c["coverage"]), 3),
                     str(m.get("n_samples", c["n"])),
                     "–".join(F.sig(x, 3) for x in (m.get("t_range_s") or c["t_range"])),
                     _e(", ".join(str(i) for i in ids)) if len(ids) > 1 else "",
                     F.sig(c["rms_sigma"], 3)])
    out += _table(["marker", "role", "coverage", "samples", "seen (s)", "joined from",
                   "RMS/σ"], rows)
    joined = fj.get("joined") or []
    if joined:
        out += "<p>Tracker fragments fitted as one marker: " + "; ".join(
            f"{_e(j.get('marker'))} ← {_e(', '.join(str(i) for i in j.get('ids', [])))} "
            f"({_e(j.get('reason', ''))})" for j in joined) + ".</p>"
    out += _found(fj)
    gl = fj.get("glitches") or []
    if gl:
        rule = f" ({_e(fj['glitch_rule'])})" if fj.get("glitch_rule") else ""
        out += (f"<p>{len(gl)} glitch sample(s) kept out of the estimates{rule}: "
                + "; ".join(f"{_e(g.get('marker'))} at {F.sig(g.get('time_s'), 4)} s "
                            f"({F.sig(g.get('size_sigma'), 3)} σ)" for g in gl[:12])
                + (" …" if len(gl) > 12 else "") + ".</p>")
    return out


def _found(fj) -> str:
    """The frame transform, identity swaps, tracks kept out and sigma_mm notes (fit.json
    `orientation`, `swaps`, `excluded`, `sigma_notes`)."""
    out = ""
    applied = (fj.get("orientation") or {}).get("applied") or []
    if applied:
        out += ("<p>The file's axes were brought to x along travel, y up: "
                + "; ".join(_e(a) for a in applied) + ". Positions here are in that frame.</p>")
    sw = fj.get("swaps") or []
    if sw:
        out += ("<p>Identity swaps repaired: " + "; ".join(
            f"{_e(' and '.join(s.get('markers', [])))} from {F.sig(s.get('t_s'), 4)} s"
            for s in sw[:12]) + (" …" if len(sw) > 12 else "")
            + f" ({_e(sw[0].get('reason', ''))}).</p>")
    ex = fj.get("excluded") or []
    if ex:
        out += ("<p>Tracks kept out of the fit (not markers): " + "; ".join(
            f"{_e(x.get('marker'))} ({_e(x.get('role'))}, {x.get('n_samples')} samples: "
            f"{_e(x.get('reason', ''))})" for x in ex) + ".</p>")
    for note in fj.get("sigma_notes") or []:
        out += f"<p>{_e(note)}.</p>"
    return out


def _least_squares(fj, st) -> str:
    ls = fj.get("least_squares") or {}
    chi2, n, k = ls.get("chi2"), ls.get("n_data"), ls.get("n_params")
    bic = chi2 + k * np.log(n) if None not in (chi2, n, k) and n else None
    rows = [["data points N", F.num(n)], ["free parameters", F.num(k)],
            ["degrees of freedom", F.num(ls.get("dof"))], ["χ²", F.sig(chi2, 6)],
            ["χ²/dof", F.sig(fj.get("chi2_per_dof"), 4)
             + (f" (white noise: 1 ± {F.sig(np.sqrt(2 / ls['dof']), 2)})" if ls.get("dof")
                else "")],
            ["BIC = χ² + k ln N", F.sig(bic, 7)],
            ["solver steps", F.num(ls.get("steps"))],
            ["converged", "yes" if ls.get("converged") else '<span class="bad">no</span>'],
            ["effects in the model", _e(", ".join(ls.get("effects") or []) or "none")],
            ["noise (lug / body)", " / ".join(
                F.sig(1000 * v, 3) + " µm" if v else "–"
                for v in ((fj.get("noise_mm") or {}).get("lug"),
                          (fj.get("noise_mm") or {}).get("body")))
             + f" ({_e(fj.get('noise_source', ''))})"]]
    out = _table(["statistic", "value"], rows)
    if "lsq_corr" in st:
        names = st["meta"].get("corr_names") or []
        fig, ax = _fig(min(FIG_W, 2.2 + 0.55 * len(names)), min(FIG_W, 1.8 + 0.5 * len(names)))
        _plots.plot_correlation(st["lsq_corr"], names, ax=ax[0, 0])
        out += figure_html(fig, "correlation matrix of the physical and effect parameters",
                           "Correlation of the least-squares fit's scalar parameters "
                           "(physical and effect ones; per-marker offsets and the speed "
                           "spline left out). |r| near 1 means the data barely tell the two "
                           "apart.")
    return out


_CORNER = (("slip", "s₀"), ("stiffness_N_per_mm", "k (N/mm)"), ("k_over_m", "k/m"),
           ("rolling_resistance", "C_rr"))
_DERIVED = {"delta_l_mm", "k_over_m", "rolling_resistance", "slip", "stiffness_N_per_mm",
            "s0", "beta"}


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
        if {"k_over_m": "k_over_m_N_per_mm_kg"}.get(key, key) in (fj.get("not_identifiable")
                                                                  or {}):
            continue  # nothing to draw: the data do not fix it
        if key in names:
            cols.append(names.index(key))
            labels.append(label)
    for j, key in enumerate(names):  # effect parameters that were sampled
        if key not in _DERIVED:
            cols.append(j)
            labels.append(key)
    out = ""
    if len(cols) >= 2:
        fig = _plots.plot_corner(S[:, cols], labels)
        out += figure_html(fig, "corner plot of the physical and sampled effect parameters",
                           "Posterior of the physical parameters (and any sampled effect "
                           "parameter): titles give the median ± 1 σ, dashed lines the 2.5, "
                           "50 and 97.5 % quantiles (the 95 % interval). Effect parameters "
                           "that enter linearly are marginalised, not sampled: their "
                           "errors are in the estimates.")
    fig, ax = _fig(FIG_W, 3.6)
    ref = fj.get("reference_paper_slip") if is_reference_rig(meta) else None
    ls = meta.get("least_squares", {}).get("slip") or {}
    _plots.plot_slip_posterior(S[:, names.index("slip")], ax=ax[0, 0], reference=ref,
                               least_squares=(ls.get("value"), ls.get("std")))
    out += figure_html(fig, "slippage posterior histogram",
                       "Posterior of the steady slip s₀ (histogram) with its 95 % interval "
                       "(shaded) and the least-squares normal (dashed)"
                       + ("; the reference paper's value is the dash-dotted line." if ref
                          else "."))
    return out


def _arviz_diagnostics(out_dir):
    """(names, rows, chains) from DIR/posterior.nc: R-hat, bulk/tail ESS, MCSE per
    parameter, and the draws (walker, draw) of each sampled parameter; None without it."""
    path = os.path.join(out_dir, "posterior.nc")
    if not os.path.isfile(path):
        return None
    import logging
    import warnings

    log = logging.getLogger("arviz")
    level = log.level
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        log.setLevel(logging.ERROR)  # a short chain is reported in the table, not on stderr
        try:
            import arviz as az

            idata = az.from_netcdf(path)
            summ = az.summary(idata, kind="diagnostics", round_to="none")
            post = idata.posterior
            chains = {k: np.asarray(post[k].values) for k in post.data_vars}
        except Exception:  # noqa: BLE001 - an unreadable file only loses this table
            return None
        finally:
            log.setLevel(level)
    return summ, chains


def _convergence(st, fj, out_dir) -> str:
    mc = fj.get("mcmc")
    if not mc:
        return "<p>Least squares only: no chain was run.</p>"
    ok = mc.get("converged")
    status = ('<span class="ok">converged</span>' if ok
              else '<span class="bad">not converged</span>')
    rows = [["status", status], ["message", _e(mc.get("message", ""))],
            ["method", _e(mc.get("method", ""))],
            ["marginalised", _e(mc.get("marginalised", ""))],
            ["walkers", F.num(mc.get("walkers"))],
            ["steps (burn-in)", f'{F.num(mc.get("steps"))} ({F.num(mc.get("burn_in"))})'],
            ["acceptance fraction", F.sig(mc.get("acceptance"), 3)],
            ["wall time", F.sig(mc.get("seconds"), 2) + " s"], ["seed", F.num(mc.get("seed"))]]
    chk = mc.get("linearity_check") or {}
    if chk:
        rows.append(["linearisation check",
                     f'max |Δχ²| = {F.sig(chk.get("max_delta_chi2"), 2)} at '
                     f'{F.num(chk.get("points"))} points {F.num(chk.get("sigma"))} σ out '
                     f'(tolerance {F.num(chk.get("tolerance"))})'])
    pri = mc.get("priors") or {}
    rows.append(["priors", _e("; ".join(f"{k}: {v}" for k, v in pri.items()))])
    out = _table(["diagnostic", "value"], rows)
    diag = _arviz_diagnostics(out_dir)
    tau = mc.get("autocorr_time_per_parameter") or {}
    sampled = list(mc.get("parameters") or tau)
    if diag is not None:
        summ, chains = diag
        prow = []
        for name in summ.index:
            r = summ.loc[name]
            mean = float(np.mean(chains[name])) if name in chains else None
            prow.append([_e(name) + (" (sampled)" if name in sampled else ""),
                         F.sig(mean, 6), F.sig(r.get("mcse_mean"), 2),
                         F.sig(r.get("r_hat"), 4), F.sig(r.get("ess_bulk"), 3),
                         F.sig(r.get("ess_tail"), 3),
                         F.sig(tau.get(name), 3) if name in tau else ""])
        out += ("<p>Per parameter, computed by ArviZ from the saved samples "
                "(<code>posterior.nc</code>; the walkers are treated as chains, which "
                "slightly overstates R-hat's power for an ensemble sampler):</p>"
                + _table(["parameter", "mean", "MCSE of mean", "R-hat", "ESS bulk",
                          "ESS tail", "τ (steps)"], prow))
        traces = {k: chains[k] for k in sampled if k in chains} or {
            k: v for k, v in list(chains.items())[:4]}
        fig = _plots.plot_traces(traces)
        out += figure_html(fig, "walker traces of every sampled parameter",
                           "Walker traces (after burn-in) of every sampled parameter: each "
                           "line is one walker. Look for a stationary band without trends "
                           "or stuck walkers.")
    elif "post_chain" in st:
        fig, ax = _fig(FIG_W, 2.6)
        name = (st["meta"].get("post_parameters") or ["s0"])[0]
        _plots.plot_trace(st["post_chain"], ax=ax[0, 0], name=name)
        out += figure_html(fig, "walker traces of the slip",
                           f"Walker traces of {_e(name)} after burn-in (posterior.nc not "
                           "found: the other parameters' traces need it).")
    return out


def _discrepancy_section(fit_json: dict, state: dict) -> str:
    """The "What the model left out" section (a whole <section>), or ""."""
    from ._discrepancy import discrepancy_section

    return discrepancy_section(fit_json, state)


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
    a, b = fj.get("run_id"), st["meta"].get("run_id")
    if a != b:  # a folder mixing two runs' files (fitlug.cli._outdir)
        raise InputError(out_dir, f"fit.json (run {a or 'without an id'}) and state.npz "
                                  f"(run {b or 'without an id'}) come from different runs: "
                                  "rerun fit-lug to rebuild the folder")
    name = recording_label(fj, out_dir)
    s = fj.get("slip") or {}
    verdict = (fj.get("discrepancy") or {}).get("verdict")
    title = f"{name}: slip {F.pm(s.get('value'), s.get('std'))}" + (
        f" ({verdict})" if verdict and verdict != "none" else "") + " · fitlug"
    with _encoded_aside() as aside:
        page = _page(fj, st, out_dir, name, title)
        page = aside.fill(page)
    path = os.path.join(out_dir, "report.html")
    write_text_atomic(path, page)
    return path


def _page(fj, st, out_dir, name, title) -> str:
    """The whole page (figures as placeholders when encoded aside)."""
    sections = [
        ("estimates", "Estimates", _estimates(fj, st)),
        ("slip", "The slip drawn", _slip_section(fj, st)),
        ("discrepancy", "What the model left out", None),
        ("trajectories", "Lug-marker trajectories", _trajectories(st)),
        ("kinematics", "Body displacement and velocity", _kinematics(st)),
        ("residuals", "Residuals", _residuals(st, fj)),
        ("least-squares", "Least-squares statistics", _least_squares(fj, st)),
        ("posterior", "Posterior", _posterior(st, fj)),
        ("convergence", "Convergence diagnostics", _convergence(st, fj, out_dir)),
    ]
    body, toc = [], []
    for sid, h, content in sections:
        if content is None:
            disc = _discrepancy_section(fj, st)
            if disc:
                body.append(disc)
                toc.append((sid, h))
            continue
        body.append(f'<section id="{sid}"><h2>{html.escape(h)}</h2>{content}</section>')
        toc.append((sid, h))
    nav = ('<nav class="toc" aria-label="contents"><b>Contents</b><ol>'
           + "".join(f'<li><a href="#{sid}">{html.escape(h)}</a></li>' for sid, h in toc)
           + "</ol></nav>")
    summary = f'<section id="summary">{_headline(fj, st)}</section>'
    page = (f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
            f'<meta name="viewport" content="width=device-width, initial-scale=1">'
            f"<title>{html.escape(title)}</title><style>{_CSS}</style></head><body>"
            f"<h1>Track slip of {html.escape(name)}</h1>{_meta_line(fj)}{summary}{nav}"
            f"{''.join(body)}"
            f'<p class="small">Written by fitlug'
            + (f" (run {_e(fj['run_id'])})" if fj.get("run_id") else "")
            + ' from fit.json and state.npz in this folder; '
            f"<code>fit-lug report DIR</code> rebuilds it.</p></body></html>")
    return page
