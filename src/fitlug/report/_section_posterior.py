"""The report's "Posterior" section and its plots: the corner plot of the physical (and
sampled effect) parameters and the slip's posterior histogram."""

from __future__ import annotations

import numpy as np

from ._figure import FIG_W, _ax, _fig, _locator, figure_html
from ._section_summary import is_reference_rig

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
        fig = plot_corner(S[:, cols], labels)
        out += figure_html(fig, "corner plot of the physical and sampled effect parameters",
                           "Posterior of the physical parameters (and any sampled effect "
                           "parameter): titles give the median ± 1 σ, dashed lines the 2.5, "
                           "50 and 97.5 % quantiles (the 95 % interval). Effect parameters "
                           "that enter linearly are marginalised, not sampled: their "
                           "errors are in the estimates.")
    fig, ax = _fig(FIG_W, 3.6)
    ref = fj.get("reference_paper_slip") if is_reference_rig(fj, meta) else None
    ls = meta.get("least_squares", {}).get("slip") or {}
    plot_slip_posterior(S[:, names.index("slip")], ax=ax[0, 0], reference=ref,
                        least_squares=(ls.get("value"), ls.get("std")))
    out += figure_html(fig, "slippage posterior histogram",
                       "Posterior of the steady slip s₀ (histogram) with its 95 % interval "
                       "(shaded) and the least-squares normal (dashed)"
                       + ("; the reference paper's value is the dash-dotted line." if ref
                          else "."))
    return out


def plot_slip_posterior(samples, ax=None, reference: float | None = None,
                        least_squares: tuple | None = None):
    """Histogram of the slippage posterior; median and 95 % interval; optional references.

    reference: the reference paper's value (drawn when given). least_squares: (value, std)
    drawn as a normal curve for comparison.
    """
    ax = _ax(ax, (6, 3.5))
    x = np.asarray(samples, float)
    lo, med, hi = np.percentile(x, [2.5, 50, 97.5])
    ax.hist(x, bins=60, density=True, color="#9ecae1", edgecolor="none", label="posterior")
    from ._format import pm

    ax.axvline(med, color="#08519c", lw=1.5, label=f"median {pm(med, np.std(x))}")
    ax.axvspan(lo, hi, color="#08519c", alpha=0.12, label="95 % interval")
    if least_squares is not None and least_squares[1]:
        m, s = least_squares
        g = np.linspace(m - 4 * s, m + 4 * s, 200)
        ax.plot(g, np.exp(-0.5 * ((g - m) / s) ** 2) / (s * np.sqrt(2 * np.pi)), "k--",
                lw=0.8, label="least squares (normal)")
    if reference is not None:
        ax.axvline(reference, color="#cb181d", lw=1.2, ls="-.",
                   label=f"reference paper {reference:g}")
    ax.set_xlabel("steady slippage s₀")
    ax.set_yticks([])
    ax.legend(frameon=False, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.ticklabel_format(axis="x", useOffset=False)
    ax.xaxis.set_major_locator(_locator(5))
    return ax


def plot_corner(samples, labels, fig=None, truths=None):
    """Corner plot of the physical parameters (corner.py); returns the figure.

    corner draws a grid of axes, so this one takes (and returns) a figure instead of an ax.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    from corner.core import corner_impl

    samples = np.asarray(samples, float)
    k = samples.shape[1]
    if fig is None:
        from ._layout import figure

        fig = figure(max(2.6 * k + 0.8, 5.0), max(2.6 * k + 0.8, 5.0))
        fig._fitlug_tidy = False  # corner sets its own margins
    from ._format import pm

    # corner.corner hands a numpy array to ArviZ (an xarray Dataset and back) before its
    # corner_impl draws it: the same figure, drawn from the array directly
    corner_impl(samples, labels=labels, fig=fig, quantiles=[0.025, 0.5, 0.975],
                show_titles=False, truths=truths, bins=30, max_n_ticks=3,
                plot_datapoints=False, smooth=0.8, label_kwargs={"fontsize": 10},
                labelpad=0.12)
    diag = [fig.axes[i * (k + 1)] for i in range(k)]
    for i, a in enumerate(diag):  # titles: median ± 1 sigma, digits set by the error
        col = samples[:, i]
        a.set_title(f"{labels[i]} =\n{pm(np.median(col), np.std(col))}", fontsize=9)
    for a in fig.axes:
        a.tick_params(labelsize=8)
        for axis in (a.xaxis, a.yaxis):  # offsets like "+1e-1" read badly on tiny spreads
            fmt = axis.get_major_formatter()
            if hasattr(fmt, "set_useOffset"):
                fmt.set_useOffset(False)
    return fig
