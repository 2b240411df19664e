"""DIR/report.html: one self-contained page (figures embedded as base64 PNG, no links out).

Built from DIR/fit.json and DIR/state.npz (and DIR/posterior.nc for the chain diagnostics,
when present), so `fit-lug report DIR` rebuilds it without refitting. The first screen is
the headline box: what was measured, on which rig, the slip and the derived quantities with
one 1 σ error each (the fit.json one, used everywhere on the page), and the verdict on
left-out physics in words. Then a table of contents and the sections: estimates, the slip
drawn (s(t), slip against traction force, the stall), what the model left out
(:mod:`fitlug.report._section_discrepancy`), trajectories, kinematics, residuals (per marker too),
least-squares statistics, posterior, convergence. Numbers go through
:mod:`fitlug.report._format`: digits set by the uncertainty.
"""

from __future__ import annotations

import html
import os

from . import _format as F
from ._figure import _encoded_aside
from ._markup import _CSS, _e
from ._section_convergence import _convergence
from ._section_estimates import _estimates
from ._section_kinematics import _kinematics
from ._section_least_squares import _least_squares
from ._section_posterior import _posterior
from ._section_residuals import _residuals
from ._section_slip import _slip_section
from ._section_summary import _headline
from ._section_trajectories import _trajectories
from ._state import load_state


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


def _discrepancy_section(fit_json: dict, state: dict, plots: str | None = None) -> str:
    """The "What the model left out" section (a whole <section>), or ""."""
    from ._section_discrepancy import discrepancy_section

    return discrepancy_section(fit_json, state, plots)


#: the parts of the page drawn from the fit and its explanation alone, never from the
#: posterior (fit.json's estimates, uncertainty method, mcmc block; state.npz's post_*):
#: :mod:`fitlug.report._aside` draws them while the posterior is sampled
EARLY = ("trajectories", "kinematics", "residuals", "least-squares", "discrepancy-plots")


def _early_makers(fj, st) -> dict:
    from ._discrepancy_plots import discrepancy_plots

    return {"trajectories": lambda: _trajectories(st), "kinematics": lambda: _kinematics(st),
            "residuals": lambda: _residuals(st, fj),
            "least-squares": lambda: _least_squares(fj, st),
            "discrepancy-plots": lambda: discrepancy_plots(fj, st)}


def convergence_part(fj: dict, st: dict, out_dir) -> dict:
    """{"convergence": the section's HTML} drawn from DIR's final fit.json dict, state and
    posterior.nc, for :func:`write_report`'s `early`."""
    out_dir = os.fspath(out_dir)
    with _encoded_aside() as aside:
        return {"convergence": aside.fill(_convergence(st, fj, out_dir))}


def early_parts(fj: dict, st: dict) -> dict:
    """The :data:`EARLY` parts of the page (HTML with their figures), drawn from a fit.json
    dict and state arrays made before the posterior (fitlug.report.fit_json and
    fitlug.report._state.state_arrays without it): the same HTML as the final files give.
    """
    with _encoded_aside() as aside:
        parts = {k: make() for k, make in _early_makers(fj, st).items()}
        return {k: aside.fill(v) for k, v in parts.items()}


def write_report(out_dir, early: dict | None = None) -> str:
    """Render DIR/report.html from DIR/fit.json and DIR/state.npz; returns its path.

    early: parts drawn already (:func:`early_parts`; fitlug.report._aside: also
    "convergence", the section drawn from posterior.nc), used in their place; a mapping,
    whose lookups may wait for another process: it is read after the other parts of the
    posterior are drawn.
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
        page = _page(fj, st, out_dir, name, title, {} if early is None else early)
        page = aside.fill(page)
    path = os.path.join(out_dir, "report.html")
    write_text_atomic(path, page)
    return path


def _page(fj, st, out_dir, name, title, early: dict) -> str:
    """The whole page (figures as placeholders when encoded aside); `early`: parts drawn
    already (:func:`early_parts`)."""
    makers = {**_early_makers(fj, st), "convergence": lambda: _convergence(st, fj, out_dir)}

    def part(key):
        return early[key] if key in early else makers[key]()

    # the parts drawn here first, then those `early` holds: where they are still being
    # drawn by other processes (fitlug.report._aside), the work overlaps
    late = {"estimates": _estimates(fj, st), "slip": _slip_section(fj, st),
            "posterior": _posterior(st, fj), "convergence": part("convergence")}
    sections = [
        ("estimates", "Estimates", late["estimates"]),
        ("slip", "The slip drawn", late["slip"]),
        ("discrepancy", "What the model left out", None),
        ("trajectories", "Lug-marker trajectories", part("trajectories")),
        ("kinematics", "Body displacement and velocity", part("kinematics")),
        ("residuals", "Residuals", part("residuals")),
        ("least-squares", "Least-squares statistics", part("least-squares")),
        ("posterior", "Posterior", late["posterior"]),
        ("convergence", "Convergence diagnostics", late["convergence"]),
    ]
    body, toc = [], []
    for sid, h, content in sections:
        if content is None:
            disc = _discrepancy_section(fj, st, early.get("discrepancy-plots"))
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
