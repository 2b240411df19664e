"""The plots of the report's "What the model left out" section
(:mod:`fitlug.report._section_discrepancy`): residuals before and after the named effects,
the binned residual maps, the misfit breakdown and the spectrum with its peaks named, and
:func:`discrepancy_plots`, the section's figures as HTML (one of the page's early parts,
:data:`fitlug.report._page.EARLY`)."""

from __future__ import annotations

import html

import numpy as np

from . import _format as F
from ._figure import figure_html, log_axis

SHARED_SCALE_MAX_RATIO = 30.0  # before/after maps share a colour scale below this ratio


def _new(w, h, rows=1, cols=1, **kw):
    from ._figure import new_figure

    return new_figure(w, h, rows, cols, **kw)


def _map_array(m):
    return np.array([[np.nan if v is None else v for v in row]
                     for row in m["mean_residual_sigma"]], float)


def plot_maps(maps: dict):
    """Residual maps (series x time, mean residual in σ per bin) before and after.

    One colour scale for both unless the after map is SHARED_SCALE_MAX_RATIO times
    weaker; returns (fig, shared).
    """
    from ._figure import CBAR

    keys = [k for k in ("before", "after") if maps.get(k)]
    arrs = {k: _map_array(maps[k]) for k in keys}
    vmax = {k: max(float(np.nanpercentile(np.abs(a), 99)) if np.isfinite(a).any() else 1.0,
                   1.0) for k, a in arrs.items()}
    shared = len(keys) < 2 or vmax[keys[0]] / vmax[keys[-1]] < SHARED_SCALE_MAX_RATIO
    if shared:
        top = max(vmax.values())
        vmax = {k: top for k in keys}
    nser = max(len(maps[k]["series"]) for k in keys)
    fig, axes = _new(9.0, min(2.0 + 0.14 * nser, 9.0), 1, len(keys))
    for ax_, k in zip(axes[0], keys):
        m = maps[k]
        t = m["t_edges_s"]
        im = ax_.imshow(arrs[k], aspect="auto", cmap="RdBu_r", vmin=-vmax[k], vmax=vmax[k],
                        extent=[t[0], t[-1], len(m["series"]) - 0.5, -0.5],
                        interpolation="nearest")
        step = max(1, len(m["series"]) // 30)
        ax_.set_yticks(range(0, len(m["series"]), step))
        ax_.set_yticklabels(m["series"][::step], fontsize=7)
        ax_.set_xlabel("t (s)")
        ax_.set_title(f"{k}: mean residual per bin (σ)"
                      + ("" if shared else f", own scale ±{F.sig(vmax[k], 2)}"), fontsize=9)
        if not shared or k == keys[-1]:
            fig.colorbar(im, ax=ax_, shrink=0.8, label="σ", **CBAR)
    return fig, shared


def spectral_peaks(f, p, lug_hz=None, wheel_hz=None, n=4, factor=8.0):
    """The n strongest local maxima above `factor` × the median power, each named by its
    relation to the lug-passing and wheel-revolution frequencies: [(f, p, name)]."""
    f, p = np.asarray(f, float), np.asarray(p, float)
    if len(p) < 3:
        return []
    med = np.median(p)
    idx = [i for i in range(1, len(p) - 1)
           if p[i] >= p[i - 1] and p[i] >= p[i + 1] and p[i] > factor * med]
    idx = sorted(idx, key=lambda i: -p[i])[:n]
    out = []
    for i in sorted(idx, key=lambda i: f[i]):
        name = ""
        df = (f[1] - f[0]) * 1.01
        for base, what in ((lug_hz, "lug passing"), (wheel_hz, "wheel revolution")):
            if base:
                h = round(f[i] / base)
                if 1 <= h <= 2 and abs(f[i] - h * base) <= df:
                    name = what if h == 1 else f"{h}× {what}"
                    break
        if not name:
            name = ("below 1 Hz: the motion profile" if f[i] < 1.0
                    else "not a rig frequency: a disturbance outside the catalog?")
        out.append((float(f[i]), float(p[i]), name))
    return out


def _close_groups(pts, gap):
    """(f, p) points sorted by f, in runs whose neighbours lie closer than `gap` in f."""
    groups = []
    for pt in pts:
        if groups and pt[0] - groups[-1][-1][0] < gap:
            groups[-1].append(pt)
        else:
            groups.append([pt])
    return groups


def plot_spectra(spectra: dict):
    fig, axes = _new(9.0, 3.6)
    ax = axes[0, 0]
    s0 = spectra.get("before") or spectra.get("after") or {}
    for k, col in (("before", "#d95f02"), ("after", "#1b9e77")):
        s = spectra.get(k)
        if s and s.get("f_hz"):
            ax.plot(s["f_hz"], s["power"], "-", lw=1, color=col, label=k)
    log_axis(ax)
    for key, lab, c in (("lug_passing_hz", "lug passing", "C3"),
                        ("wheel_revolution_hz", "wheel revolution", "C2")):
        f = s0.get(key)
        if f:
            ax.axvline(f, color=c, ls="--", lw=0.8, label=f"{lab} {f:.2f} Hz")
    peaks = []
    for k in ("before", "after"):
        s = spectra.get(k)
        if s and s.get("f_hz"):
            for fpk, ppk, name in spectral_peaks(s["f_hz"], s["power"], s0.get("lug_passing_hz"),
                                                 s0.get("wheel_revolution_hz")):
                peaks.append((k, fpk, ppk, name))
    f_hi = min(50.0, max(s0.get("f_hz") or [50.0]))
    # one label per group of peaks closer than 4 % of the axis (before and after often
    # share a line; five lines under 2.5 Hz were drawn over each other)
    for grp in _close_groups(sorted({(round(fp, 6), pp) for _, fp, pp, _ in peaks}),
                             0.04 * f_hi):
        fs = sorted({fp for fp, _ in grp})
        fp, pp = max(grp, key=lambda g: g[1])
        ax.annotate(", ".join(f"{x:.2f}" for x in fs) + " Hz", (fp, pp),
                    textcoords="offset points", xytext=(3, 4), fontsize=8)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("residual power (σ²)")
    ax.set_xlim(0, f_hi)
    ax.legend(frameon=False, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return fig, peaks


def plot_breakdown(before: dict, after: dict | None):
    """Structured misfit (χ²) per dimension before and after, on a log axis so that a
    misfit hundreds of times smaller stays visible; values ≤ 1 are drawn at 1."""
    dims = [d for d in ("segment", "phase", "axis", "role") if (before or {}).get(d)]
    fig, axes = _new(9.0, 3.4, 1, max(len(dims), 1), sharey=True)
    for ax, dim in zip(axes[0], dims):
        b = (before or {}).get(dim, {})
        a = (after or {}).get(dim, {}) if after else {}
        names = list(b)
        x = np.arange(len(names))
        clip = lambda v: max(float(v or 0.0), 1.0)  # noqa: E731
        ax.bar(x - 0.2, [clip(b[n]["misfit_chi2"]) for n in names], 0.4, label="before",
               color="#d95f02")
        if a:
            ax.bar(x + 0.2, [clip(a.get(n, {}).get("misfit_chi2")) for n in names], 0.4,
                   label="after", color="#1b9e77")
        log_axis(ax)
        ax.set_xticks(x, [str(n).replace("_", " ") for n in names], rotation=35, ha="right",
                      fontsize=8)
        ax.set_title(f"by {dim}", fontsize=9)
    axes[0, 0].set_ylabel("structured misfit (χ², log)")
    axes[0, 0].legend(frameon=False, fontsize=8)
    return fig


def plot_before_after(st: dict):
    """Lug and body residuals before (base model) and after (named effects): over time
    and along the belt coordinate, both axes, on shared y scales per row."""
    from ._section_residuals import plot_residuals_path, plot_residuals_time

    fig, axes = _new(9.0, 9.5, 4, 2)
    P = st.get("meta", {}).get("belt_length_mm")
    for j, (prefix, name) in enumerate((("base_", "before"), ("", "after"))):
        for k, axis in enumerate(("x", "y")):
            plot_residuals_time(st, axis, ax=axes[k, j], prefix=prefix)
            plot_residuals_path(st, axis, ax=axes[2 + k, j], prefix=prefix, P=P)
            for row in (k, 2 + k):
                axes[row, j].set_title(f"{name}: {axis} residual", fontsize=9, loc="left")
                axes[row, j].xaxis.label.set_fontsize(8)
                if (row, j) == (0, 0):
                    handles, labels = axes[row, j].get_legend_handles_labels()
                axes[row, j].get_legend().remove()
    fig.legend(handles, labels, loc="upper center", ncol=5, frameon=False,
               markerscale=6)
    for row in range(4):  # one scale per row: before and after compare directly
        lo = min(axes[row, 0].get_ylim()[0], axes[row, 1].get_ylim()[0])
        hi = max(axes[row, 0].get_ylim()[1], axes[row, 1].get_ylim()[1])
        for j in range(2):
            axes[row, j].set_ylim(lo, hi)
    return fig


def discrepancy_plots(fit_json: dict, state=None) -> str:
    """The discrepancy section's figures (residuals before and after, the binned maps, the
    misfit breakdown, the spectra) as HTML, or "": drawn from fit.json's discrepancy block
    and the state's arrays only (not from the posterior's estimates)."""
    d = (fit_json or {}).get("discrepancy") or {}
    effects = d.get("effects") or []
    plots = []
    try:
        st = state or {}
        if effects and "base_lug_res_x" in st:
            cap = ("Residuals before (left: base model) and after (right: with "
                   + ", ".join(html.escape(str(e["id"])) for e in effects)
                   + ") over time and along the belt coordinate u (position on the belt "
                   "loop: sag shows on the top run, sinkage on the bottom run); each row has "
                   "one y scale for both.")
            if len(effects) > 1:
                cap += " With several effects, 'before' is the base model, 'after' all of them."
            plots.append(figure_html(plot_before_after(st),
                                   "residuals before the effects were added and after",
                                   cap))
        if d.get("maps"):
            fig, shared = plot_maps(d["maps"])
            note = ("Both maps share one colour scale." if shared else
                    "The two maps have different colour scales (the after map is far weaker "
                    "and would be invisible on the before scale): read the numbers on "
                    "each colour bar.")
            plots.append(figure_html(fig, "binned residual maps before and after",
                                   "Mean residual (σ) per marker-axis series and 0.1 s bin. "
                                   "White is no bias; coloured stripes are structure. " + note))
        mb, ma = d.get("misfit_before") or {}, d.get("misfit_after") or {}
        if mb.get("breakdown"):
            after = ma.get("breakdown") if effects else None  # nothing added: no repeat
            plots.append(figure_html(plot_breakdown(mb["breakdown"], after),
                                   "structured misfit by segment, phase, axis and role",
                                   "Structured misfit (χ² of lag-1 products) per path "
                                   "segment, motion phase, axis and role, before and after, on "
                                   "a log scale (values at or below 1, i.e. noise, drawn at 1)."))
        if d.get("spectra"):
            fig, peaks = plot_spectra(d["spectra"])
            names = "; ".join(f"{k}: {fpk:.2f} Hz ({name})" for k, fpk, _, name in peaks)
            plots.append(figure_html(fig, "residual power spectrum before and after",
                                   "Power spectrum of the residuals (σ², log) before and after, "
                                   "with the lug-passing and wheel-revolution frequencies. "
                                   + (f"Peaks: {names}." if names else
                                      "No peak stands 8 times above the median.")))
    except Exception as exc:  # noqa: BLE001 - a plot must never sink the report
        plots.append(f"<p>(plots unavailable: {html.escape(str(exc))})</p>")
    return "<h3>Residuals before and after</h3>" + "".join(plots) if plots else ""
