"""Plots of a posterior (a :class:`fitlug.posterior.Posterior`)."""

from __future__ import annotations

import numpy as np

from ._common import axes, legend


def posterior(post, name: str = "slip", *, ax=None, bins: int = 60):
    """Histogram of one sampled quantity with its median and 95 % interval.

    Args:
        post: a Posterior.
        name: a sampled parameter or derived quantity (``post.samples``' names).
        ax: matplotlib axes; None: a new figure.

    Returns:
        The axes.

    Raises:
        ValueError: an unknown name (naming the sampled ones).
    """
    if name not in post.samples:
        raise ValueError(f"no samples of {name!r}; sampled: {', '.join(post.samples)}")
    x = np.asarray(post.samples[name], float)
    x = x[np.isfinite(x)]
    lo, med, hi = np.percentile(x, [2.5, 50, 97.5])
    ax = axes(ax, (6.0, 3.4))
    ax.hist(x, bins=bins, density=True, color="#9ecae1", edgecolor="none", label="posterior")
    ax.axvline(med, color="#08519c", lw=1.5, label=f"median {med:.5g}")
    ax.axvspan(lo, hi, color="#08519c", alpha=0.12, label="95 % interval")
    why = (getattr(post, "not_identifiable", None) or {}).get(name)
    ax.set_title(f"{name}: not identifiable" if why else name, fontsize="medium")
    ax.set_xlabel(name)
    ax.set_yticks([])
    ax.ticklabel_format(axis="x", useOffset=False)
    legend(ax, 3)
    return ax


def corner(post, names=None, *, fig=None, truths=None):
    """Corner plot (pairs and marginals) of sampled quantities (corner.py).

    Args:
        post: a Posterior.
        names: quantities to draw (default: the sampled parameters, post.parameters).
        fig: a matplotlib figure with no axes, or None for a new one.
        truths: known values to mark, one per name (or None).

    Returns:
        The figure.
    """
    from ..report._section_posterior import plot_corner

    names = list(post.parameters if names is None else names)
    bad = [n for n in names if n not in post.samples]
    if bad:
        raise ValueError(f"no samples of {', '.join(map(repr, bad))}; sampled: "
                         f"{', '.join(post.samples)}")
    if fig is None:
        import matplotlib.pyplot as plt

        k = len(names)
        fig = plt.figure(figsize=(max(2.6 * k + 0.8, 5.0),) * 2)
    x = np.column_stack([np.asarray(post.samples[n], float) for n in names])
    return plot_corner(x, names, fig=fig, truths=truths)
