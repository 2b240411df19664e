"""What every plot shares: the axes (yours, or a new figure's) and marker colours."""

from __future__ import annotations

import numpy as np


def axes(ax, figsize=(8.0, 3.6)):
    """`ax`, or the axes of a new pyplot figure (so that a notebook shows it)."""
    if ax is not None:
        return ax
    import matplotlib.pyplot as plt

    return plt.subplots(figsize=figsize, layout="constrained")[1]


def colours(n: int):
    import matplotlib

    cmap = matplotlib.colormaps["tab10" if n <= 10 else "viridis"]
    return [cmap(i if n <= 10 else i / max(n - 1, 1)) for i in range(n)]


def legend(ax, n_items: int) -> None:
    """A legend inside the axes, in columns when there are many entries."""
    if n_items:
        ax.legend(loc="best", fontsize="small", ncols=1 if n_items <= 6 else 2,
                  framealpha=0.8)


def samples_of(res):
    """Per fitted sample: (marker name, role, t (s), raw residual x, y (data - model, mm),
    sigma (mm)) from a FitResult, valid samples only."""
    prob = res.problem
    lay, obs = prob.lay, prob.obs
    names = list(prob.rec.markers)
    w = np.asarray(res.residuals)
    Sl, Sb = int(lay.lug_t.shape[0]), int(lay.body_t.shape[0])
    wl, wb = np.asarray(obs["lug_w"]), np.asarray(obs["body_w"])
    parts = []
    for role, t, idx, ids, wt, rx, ry in (
            ("lug", lay.lug_t, lay.lug_i, prob.lug_ids, wl, w[:Sl], w[Sl:2 * Sl]),
            ("body", lay.body_t, lay.body_j, prob.body_ids, wb, w[2 * Sl:2 * Sl + Sb],
             w[2 * Sl + Sb:])):
        ok = wt > 0
        mk = np.array([names[ids[i]] for i in np.asarray(idx)], dtype=object)
        sig = np.where(ok, 1.0 / np.where(ok, wt, 1.0), np.nan)
        # the fit's residuals are (model - data) / sigma
        parts.append((mk[ok], np.full(ok.sum(), role), np.asarray(t)[ok], -(rx * sig)[ok],
                      -(ry * sig)[ok], sig[ok]))
    return tuple(np.concatenate([p[k] for p in parts]) for k in range(6))
