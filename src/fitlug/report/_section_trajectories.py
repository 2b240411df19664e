"""The report's "Lug-marker trajectories" section and its plot: every marker's path in the
ground frame, data and model."""

from __future__ import annotations

import numpy as np

from ._figure import BODY_COLOR, FIG_W, _ax, _fig, figure_html
from ._section_slip import stall_box


def _trajectories(st) -> str:
    w, h = trajectory_figsize(st, width=FIG_W)
    fig, ax = _fig(w, h)
    plot_trajectories(st, ax=ax[0, 0])
    return figure_html(fig, "lug-marker trajectories in the ground frame, data and model",
                       "Every lug marker's path in the ground frame (dots: data, lines: "
                       "model) and the body markers (grey). The box marks the stall enlarged "
                       "above. Look for model lines through every cusp.")


def _marker_colors(n):
    import matplotlib

    cmap = matplotlib.colormaps["tab10" if n <= 10 else "tab20"]
    return [cmap(i % cmap.N) for i in range(n)]


def plot_trajectories(st: dict, ax=None, mark_stall: bool = True):
    """Lug-marker (and body-marker) paths in the ground frame: data dots, model lines.

    mark_stall: outline the region that :func:`plot_stall` enlarges.
    """
    ax = _ax(ax, (10, 4))
    n_lug = int(st["lug_i"].max()) + 1 if len(st["lug_i"]) else 0
    cols = _marker_colors(n_lug)
    ok = st["lug_valid"]
    for i in range(n_lug):
        c = st["curve_i"] == i
        ax.plot(st["curve_x"][c], st["curve_y"][c], "-", lw=0.6, color=cols[i], alpha=0.9)
        d = ok & (st["lug_i"] == i)
        ax.plot(st["lug_x"][d], st["lug_y"][d], ".", ms=1.5, color=cols[i])
    b = st["body_valid"]
    ax.plot(st["body_x"][b], st["body_y"][b], ".", ms=1, color=BODY_COLOR, label="body markers")
    box = stall_box(st) if mark_stall else None
    if box is not None:
        from matplotlib.patches import Rectangle

        x0, x1, y0, y1 = box
        ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ec="k", lw=0.8))
        ax.annotate("stall", (x1, y1), fontsize=8, ha="left", va="bottom")
    ax.plot([], [], "k.", ms=3, label="data")
    ax.plot([], [], "k-", lw=0.8, label="model")
    ax.set_xlabel("x (mm, ground frame)")
    ax.set_ylabel("y (mm)")
    ax.set_aspect("equal", adjustable="box")
    ax.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=3, frameon=False)
    return ax


def trajectory_figsize(st: dict, width: float = 14.0) -> tuple:
    """(width, height) in inches for :func:`plot_trajectories` at equal aspect."""
    xs = np.concatenate([st["lug_x"][st["lug_valid"]], st["body_x"][st["body_valid"]]])
    ys = np.concatenate([st["lug_y"][st["lug_valid"]], st["body_y"][st["body_valid"]]])
    if not len(xs):
        return width, 4.0
    ratio = (np.ptp(ys) + 10.0) / max(np.ptp(xs) + 10.0, 1e-9)
    return width, float(np.clip(width * ratio + 1.2, 2.2, 8.0))
