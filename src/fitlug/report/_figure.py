"""The report's figure plumbing, shared by every section (and the campaign page).

A figure is made by :func:`new_figure` (the report's font sizes, no pyplot) and put into
the page by :func:`figure_html`: laid out, drawn once at DPI and embedded as a base64 PNG,
encoded in a helper thread inside :class:`_encoded_aside`. Also the common sizes and
colours: the page's figure width, the path segments' colours, a colorbar's slot, tick
locators.
"""

from __future__ import annotations

import base64
import html
import io

DPI = 96
FIG_W = 9.0  # inches: 864 px at 96 dpi, readable when the page is 800 px wide
SEGMENTS = ("bottom", "rear arc", "top", "front arc")
SEG_COLORS = ("#1b9e77", "#d95f02", "#7570b3", "#e7298a")
BODY_COLOR = "#444444"

#: a colorbar's slot beside its axes (fractions of the axes' cell) and its length/width:
#: a slim bar close to the axes, as constrained layout drew it
CBAR = {"fraction": 0.04, "pad": 0.04, "aspect": 16}
RC = {"font.size": 10, "axes.titlesize": 10.5, "axes.labelsize": 10, "legend.fontsize": 9,
      "xtick.labelsize": 9, "ytick.labelsize": 9, "figure.dpi": 96}

#: zlib level of the embedded PNGs: 3 encodes in 2/3 of the default's (6) time for 5 % more
#: bytes
PNG_COMPRESS_LEVEL = 3
_PENDING: list = []  # inside write_report: [executor, {token: future}] (PNGs encoded aside)


def new_figure(w, h, rows=1, cols=1, **kw):
    """(figure, axes[rows, cols]) with the report's font sizes, laid out by
    :func:`fitlug.report._layout.tidy` when it is saved (no pyplot)."""
    import matplotlib

    from ._layout import figure

    matplotlib.rcParams.update(RC)
    fig = figure(w, h)
    return fig, fig.subplots(rows, cols, squeeze=False, **kw)


def _fig(w, h, rows=1, cols=1, **kw):
    return new_figure(w, h, rows, cols, **kw)


def _ax(ax, figsize=(8, 4)):
    if ax is not None:
        return ax
    return new_figure(*figsize)[1][0, 0]


def _locator(n):
    from matplotlib.ticker import MaxNLocator

    return MaxNLocator(n)


_SUP = str.maketrans("0123456789-", "⁰¹²³⁴⁵⁶⁷⁸⁹⁻")


def log_axis(ax, axis: str = "y") -> None:
    """Put `axis` of ax on a log scale, its tick labels written as plain text ("2×10⁻¹")
    instead of matplotlib's mathtext, whose parser takes a third of a second to build
    the first time a process draws any (the same labels, the same choice of labels)."""
    from matplotlib.ticker import LogFormatterSciNotation

    class _Plain(LogFormatterSciNotation):
        def __call__(self, x, pos=None):
            return _plain_power(super().__call__(x, pos))

    getattr(ax, f"set_{axis}scale")("log")
    which = ax.yaxis if axis == "y" else ax.xaxis
    which.set_major_formatter(_Plain())
    which.set_minor_formatter(_Plain(labelOnlyBase=False))


def _plain_power(s: str) -> str:
    """'$\\mathdefault{2\\times10^{-1}}$' -> '2×10⁻¹' (matplotlib's log tick labels)."""
    import re

    s = s.replace("$", "").replace("\\mathdefault", "").replace("\\times", "×")
    s = re.sub(r"\^\{?(-?\d+)\}?", lambda m: m.group(1).translate(_SUP), s)
    return s.replace("{", "").replace("}", "").replace("-", "−")


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
