"""The report's "Residuals" section and its plots: residuals over time and along the belt
coordinate by path segment, RMS per segment, per-marker small multiples and coverage, and
what was found in the file (frame transform, identity swaps, tracks kept out)."""

from __future__ import annotations

import numpy as np

from . import _format as F
from ._figure import (BODY_COLOR, FIG_W, SEG_COLORS, SEGMENTS, _ax, _fig, figure_html,
                      new_figure)
from ._markup import _e, _table


def _residuals(st, fj) -> str:
    fig, ax = _fig(FIG_W, 8.5, 4, 1)
    for k, axis in enumerate(("x", "y")):
        plot_residuals_time(st, axis, ax=ax[k, 0])
        plot_residuals_path(st, axis, ax=ax[2 + k, 0], P=st["meta"].get(
            "belt_length_mm"))
    out = figure_html(fig, "residuals over time and along the belt coordinate",
                      "Residuals (data − model, µm) over time (top two) and along the belt "
                      "coordinate u (bottom two: where on the belt loop the marker was, "
                      "0 to the belt length P), coloured by path segment. Look for structure: "
                      "white noise is a flat band. Vertical stripes over time are the robot "
                      "at rest (many samples at one place).")
    fig, ax = _fig(6.5, 3.2)
    plot_segment_rms(st, ax=ax[0, 0], noise_mm=fj.get("noise_mm"))
    out += figure_html(fig, "RMS residual per path segment and axis",
                       "RMS residual per path segment and axis against the measured noise "
                       "levels (lines): bars far above their line point at left-out physics.")
    rms = segment_rms(st)
    rows = [[g, F.sig(rms[(g, "x")][0], 3), F.sig(rms[(g, "y")][0], 3), str(rms[(g, "x")][1])]
            for g in list(SEGMENTS) + ["body"]]
    out += _table(["segment", "RMS x (µm)", "RMS y (µm)", "samples"], rows)
    out += _markers(st, fj)
    return out


def _markers(st, fj) -> str:
    fig = plot_marker_residuals(st, glitches=fj.get("glitches"))
    out = figure_html(fig, "residuals per marker over time (small multiples)",
                      "Residual size |r|/σ per marker over time (one panel each, same "
                      "scale); gaps are frames where the marker was not seen, red crosses "
                      "glitches kept out of the fit. Look for one marker unlike the others.")
    cov = marker_coverage(st)
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


def _residual_groups(st: dict, axis: str, prefix: str = ""):
    """[(label, color, t, u, res_um)] per lug segment plus the body markers."""
    r = st[f"{prefix}lug_res_{axis}"] * 1000.0
    out = []
    for k, name in enumerate(SEGMENTS):
        sel = (st["lug_seg"] == k) & np.isfinite(r)
        out.append((name, SEG_COLORS[k], st["lug_t"][sel], st["lug_u"][sel], r[sel]))
    rb = st[f"{prefix}body_res_{axis}"] * 1000.0
    sel = np.isfinite(rb)
    out.append(("body", BODY_COLOR, st["body_t"][sel], None, rb[sel]))
    return out


def plot_residuals_time(st: dict, axis: str = "x", ax=None, prefix: str = ""):
    """Residuals (data - model, µm) over time, coloured by path segment; the legend sits
    above the axes, never over the data."""
    ax = _ax(ax, (10, 3))
    for name, col, t, _, r in _residual_groups(st, axis, prefix):
        ax.plot(t, r, ".", ms=1.2, color=col, label=name)
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xlabel("t (s)")
    ax.set_ylabel(f"{axis} residual (µm)")
    ax.legend(frameon=False, ncol=5, markerscale=6, loc="lower right",
              bbox_to_anchor=(1.0, 1.0), borderaxespad=0.1)
    return ax


def plot_residuals_path(st: dict, axis: str = "x", ax=None, prefix: str = "",
                        P: float | None = None):
    """Lug residuals (µm) along the belt coordinate u (0 .. belt length P), by segment."""
    ax = _ax(ax, (10, 3))
    for name, col, _, u, r in _residual_groups(st, axis, prefix)[:4]:
        ax.plot(u, r, ".", ms=1.2, color=col, label=name)
    ax.axhline(0, color="k", lw=0.5)
    Ptxt = f", P = {P:.1f} mm" if P else ""
    ax.set_xlabel(f"belt coordinate u: position on the belt loop (mm{Ptxt})")
    ax.set_ylabel(f"{axis} residual (µm)")
    ax.legend(frameon=False, ncol=4, markerscale=6, loc="lower right",
              bbox_to_anchor=(1.0, 1.0), borderaxespad=0.1)
    return ax


def segment_rms(st: dict, prefix: str = "") -> dict:
    """RMS residual (um) per group and axis: {(group, axis): (rms, count)}."""
    out = {}
    for axis in ("x", "y"):
        for name, _, _, _, r in _residual_groups(st, axis, prefix):
            out[(name, axis)] = (float(np.sqrt(np.mean(r ** 2))) if len(r) else float("nan"),
                                 int(len(r)))
    return out


def plot_segment_rms(st: dict, ax=None, noise_mm: dict | None = None):
    """RMS residual per segment and axis (bars), with the fitted noise levels."""
    ax = _ax(ax, (6, 3))
    rms = segment_rms(st)
    groups = list(SEGMENTS) + ["body"]
    xs = np.arange(len(groups))
    for k, axis in enumerate(("x", "y")):
        vals = [rms[(g, axis)][0] for g in groups]
        ax.bar(xs + (k - 0.5) * 0.38, vals, width=0.38, label=f"{axis} residual",
               color=("#4c72b0", "#dd8452")[k])
    if noise_mm:
        for role, ls in (("lug", "--"), ("body", ":")):
            if noise_mm.get(role):
                ax.axhline(1000 * noise_mm[role], color="k", ls=ls, lw=0.8,
                           label=f"{role} noise")
    ax.set_xticks(xs, groups)
    ax.set_ylabel("RMS residual (µm)")
    ax.legend(frameon=False, ncol=4, loc="lower right", bbox_to_anchor=(1.0, 1.0),
              borderaxespad=0.1)
    return ax


def marker_coverage(st: dict) -> dict:
    """{marker name: {"role", "coverage", "n", "t_range", "rms_sigma"}} from the state."""
    meta = st.get("meta", {})
    names = meta.get("markers") or []
    noise = meta.get("noise_mm") or {}
    frames = np.unique(np.r_[st["lug_t"], st["body_t"]])
    out = {}
    for role, key, ids in (("lug", "lug_i", meta.get("lug_ids") or []),
                           ("body", "body_j", meta.get("body_ids") or [])):
        pre = "lug" if role == "lug" else "body"
        for i in np.unique(st[key]):
            sel = (st[key] == i) & st[f"{pre}_valid"]
            name = names[ids[i]] if ids and i < len(ids) and ids[i] < len(names) else f"{role} {i}"
            rx, ry = st[f"{pre}_res_x"][sel], st[f"{pre}_res_y"][sel]
            sig = noise.get(role) or 1.0
            t = st[f"{pre}_t"][sel]
            out[str(name)] = {"role": role, "coverage": sel.sum() / max(len(frames), 1),
                              "n": int(sel.sum()),
                              "t_range": [float(t.min()), float(t.max())] if len(t) else [],
                              "rms_sigma": float(np.sqrt(np.nanmean(rx ** 2 + ry ** 2) / 2)) / sig
                              if len(t) else float("nan")}
    return out


def plot_marker_residuals(st: dict, glitches=None, cols: int = 4):
    """Small multiples: |r|/σ over time, one panel per marker, shared scales."""
    meta = st.get("meta", {})
    names = meta.get("markers") or []
    noise = meta.get("noise_mm") or {}
    panels = []
    for role, key, ids in (("lug", "lug_i", meta.get("lug_ids") or []),
                           ("body", "body_j", meta.get("body_ids") or [])):
        for i in np.unique(st[key]):
            sel = (st[key] == i) & st[f"{role}_valid"]
            name = names[ids[i]] if ids and i < len(ids) and ids[i] < len(names) else f"{role} {i}"
            r = np.hypot(st[f"{role}_res_x"][sel], st[f"{role}_res_y"][sel]) / (
                noise.get(role) or 1.0) / np.sqrt(2)
            panels.append((str(name), role, st[f"{role}_t"][sel], r))
    n = max(len(panels), 1)
    rows = int(np.ceil(n / cols))
    fig, axes = new_figure(9.0, 0.3 + 1.25 * rows, rows, cols, sharex=True, sharey=True)
    top = max([np.nanpercentile(p[3], 99.5) for p in panels if len(p[3])] + [4.0])
    tlo = float(np.min(st["fine_t"]))
    thi = float(np.max(st["fine_t"]))
    gl = {}
    for g in glitches or []:
        gl.setdefault(str(g.get("marker")), []).append(g)
    for k, ax in enumerate(axes.flat):
        if k >= len(panels):
            ax.set_visible(False)
            continue
        name, role, t, r = panels[k]
        ax.plot(t, r, ".", ms=0.8, color="#4c72b0" if role == "lug" else BODY_COLOR)
        for g in gl.get(name, []):
            ax.plot([g.get("time_s")], [top * 0.9], "x", color="#c92a2a", ms=5)
        ax.set_ylim(0, top)
        ax.set_xlim(tlo, thi)
        ax.text(0.02, 0.95, name, transform=ax.transAxes, ha="left", va="top", fontsize=8,
                bbox={"fc": "white", "ec": "none", "alpha": 0.7, "pad": 1}, clip_on=True)
        ax.tick_params(labelsize=7)
    for ax in axes[-1]:
        ax.set_xlabel("t (s)", fontsize=8)
    for ax in axes[:, 0]:
        ax.set_ylabel("|r|/σ", fontsize=8)
    return fig
