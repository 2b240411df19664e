"""The report's figures without pyplot and with a one-pass layout.

matplotlib's constrained layout measures every axes' decorations twice before the figure
is drawn (a third pass): on the report's 15 figures that was about a third of their cost.
The report's figures are plain grids (a colorbar at most beside an axes, a figure legend
above), so one measurement is enough: :func:`tidy` measures each axes' tight box once
(ticks, labels, titles, legends, colorbars) and sets the grid's margins and spacings so
that every decoration sits inside the figure with a small pad; the draw that follows
reuses the ticks and the text sizes that the measurement made.
"""

from __future__ import annotations

import numpy as np

DPI = 96
#: pad around the figure and between neighbouring axes' decorations, inches (constrained
#: layout's default)
PAD_IN = 3.0 / 72.0


def figure(w: float, h: float):
    """A matplotlib Figure on an Agg canvas (no pyplot: nothing to close, no global state),
    marked for :func:`tidy`."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(w, h), dpi=DPI)
    FigureCanvasAgg(fig)
    fig._fitlug_tidy = True
    return fig


def tidy(fig) -> None:
    """Lay out fig's grid of axes in one measurement (see the module docstring).

    Figures not made by :func:`figure` (or with a layout engine of their own) are left
    as they are; so is a grid whose decorations leave no room for the axes."""
    if not getattr(fig, "_fitlug_tidy", False) or fig.get_layout_engine() is not None:
        return
    axes = [a for a in fig.axes if a.get_visible() and a.get_subplotspec() is not None]
    if not axes:
        return
    gs = axes[0].get_subplotspec().get_topmost_subplotspec().get_gridspec()
    nr, nc = gs.get_geometry()
    r = fig.canvas.get_renderer()
    W, H = float(fig.bbox.width), float(fig.bbox.height)
    pad = PAD_IN * fig.dpi
    left, right = np.zeros(nc), np.zeros(nc)
    top, bottom = np.zeros(nr), np.zeros(nr)
    for a in axes:
        ss = a.get_subplotspec().get_topmost_subplotspec()
        if ss.get_gridspec() is not gs:
            continue
        tb = a.get_tightbbox(r, bbox_extra_artists=_outer_artists(a),
                             for_layout_only=True)  # long axis labels may overhang
        if tb is None:
            continue
        cell = ss.get_position(fig)  # the grid cell (a colorbar shares its axes' cell)
        if a.get_aspect() != "auto":
            # a fixed-aspect box sits inside its cell and grows with it: measure its
            # decorations from the box itself, so that they fit wherever it ends up
            cell = a.get_position(original=False)
        c0, c1 = ss.colspan.start, ss.colspan.stop - 1
        r0, r1 = ss.rowspan.start, ss.rowspan.stop - 1
        left[c0] = max(left[c0], cell.x0 * W - tb.x0)
        right[c1] = max(right[c1], tb.x1 - cell.x1 * W)
        top[r0] = max(top[r0], tb.y1 - cell.y1 * H)
        bottom[r1] = max(bottom[r1], cell.y0 * H - tb.y0)
    above = sum(leg.get_window_extent(r).height + pad for leg in fig.legends)
    L, R = left[0] + pad, right[-1] + pad
    T, B = top[0] + pad + above, bottom[-1] + pad
    ws = max([right[j] + left[j + 1] for j in range(nc - 1)], default=0.0) + 2 * pad
    hs = max([bottom[i] + top[i + 1] for i in range(nr - 1)], default=0.0) + 2 * pad
    aw = (W - L - R - (nc - 1) * ws) / nc
    ah = (H - T - B - (nr - 1) * hs) / nr
    if aw <= 0.1 * W / nc or ah <= 0.1 * H / nr:
        return  # decorations larger than the figure: leave matplotlib's defaults
    fig.subplots_adjust(left=L / W, right=1 - R / W, bottom=B / H, top=1 - T / H,
                        wspace=ws / aw if nc > 1 else None, hspace=hs / ah if nr > 1 else None)


def _outer_artists(ax) -> list:
    """The artists of ax that may reach outside its box, for its tight box: matplotlib's
    default list without the spines (on the box; their tick marks sit within the pads),
    legends anchored to the box itself (placed inside it) and texts clipped to a box
    (ax.text(..., clip_on=True) clips to the axes; matplotlib keeps those of an axes with
    a fixed aspect). Measuring those took a seventh of the layout's time and never moved
    a margin by more than the pads."""
    from matplotlib.legend import Legend
    from matplotlib.spines import Spine
    from matplotlib.text import Text

    return [c for c in ax.get_default_bbox_extra_artists()
            if not isinstance(c, Spine)
            and not (isinstance(c, Legend) and c.get_bbox_to_anchor() is ax.bbox)
            and not (isinstance(c, Text) and c.get_clip_on() and c.get_clip_box() is not None)]

