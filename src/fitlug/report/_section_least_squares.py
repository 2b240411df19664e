"""The report's "Least-squares statistics" section and its plot: χ², BIC, solver steps,
noise levels and the correlation matrix of the scalar parameters."""

from __future__ import annotations

import numpy as np

from . import _format as F
from ._figure import CBAR, FIG_W, _ax, _fig, figure_html
from ._markup import _e, _table


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
        plot_correlation(st["lsq_corr"], names, ax=ax[0, 0])
        out += figure_html(fig, "correlation matrix of the physical and effect parameters",
                           "Correlation of the least-squares fit's scalar parameters "
                           "(physical and effect ones; per-marker offsets and the speed "
                           "spline left out). |r| near 1 means the data barely tell the two "
                           "apart.")
    return out


def plot_correlation(corr, names, ax=None):
    """Correlation matrix as a colour grid with the values written in."""
    ax = _ax(ax, (5, 4))
    c = np.asarray(corr, float)
    im = ax.imshow(c, vmin=-1, vmax=1, cmap="RdBu_r")
    k = len(names)
    ax.set_xticks(range(k), names, rotation=90, fontsize=8)
    ax.set_yticks(range(k), names, fontsize=8)
    if k <= 14:
        for i in range(k):
            for j in range(k):
                ax.text(j, i, f"{c[i, j]:.2f}".replace("0.", ".").replace("-.", "−."),
                        ha="center", va="center", fontsize=7, clip_on=True,  # in its cell:
                        color="white" if abs(c[i, j]) > 0.6 else "black")  # not measured
    ax.figure.colorbar(im, ax=ax, label="correlation", shrink=0.8, **CBAR)
    return ax
