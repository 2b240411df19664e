"""Make the documentation's figures from the committed reference fit (fits/reference/).

    python docs/make_figures.py

- docs/img/geometry.png: the track's stadium path (MODEL.md section 2) drawn with the
  reference fit's geometry (R, D, e, lug pitch from fits/reference/fit.json), the body and
  lug markers and the belt coordinate's origin;
- docs/img/<name>.png: figures the reference report embeds (fits/reference/report.html),
  taken out as they are, found by their alt text.

The report's screenshot docs/img/report.png is made with headless Chromium (see
docs/development.md). Nothing here fits anything: rerun after the reference fit changes.
"""

from __future__ import annotations

import base64
import json
import math
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
REF = ROOT / "fits" / "reference"
IMG = ROOT / "docs" / "img"

#: output name -> the start of the figure's alt text in report.html
FROM_REPORT = {
    "slip_t": "steady slip s(t) over the recording",
    "slip_force": "slip against traction force",
    "stall": "horizontal stall of one lug marker",
    "trajectories": "lug-marker trajectories in the ground frame",
    "kinematics": "body displacement and velocity",
    "residual_maps": "binned residual maps before and after",
    "spectrum": "residual power spectrum before and after",
    "corner": "corner plot of the physical",
    "slip_posterior": "slippage posterior histogram",
}


def report_figures() -> None:
    """Write the report's embedded PNGs named in FROM_REPORT; KeyError if one is missing."""
    html = (REF / "report.html").read_text(encoding="utf-8")
    found = {}
    for m in re.finditer(r'<img[^>]*?src="data:image/png;base64,([^"]+)"[^>]*?alt="([^"]*)"'
                         r'|<img[^>]*?alt="([^"]*)"[^>]*?src="data:image/png;base64,([^"]+)"', html):
        data, alt = (m.group(1), m.group(2)) if m.group(1) else (m.group(4), m.group(3))
        found[alt] = data
    for name, start in FROM_REPORT.items():
        alts = [a for a in found if a.startswith(start)]
        if not alts:
            raise KeyError(f"{REF / 'report.html'}: no figure whose alt text starts {start!r}")
        (IMG / f"{name}.png").write_bytes(base64.b64decode(found[alts[0]]))


def geometry_figure() -> None:
    """The stadium path of MODEL.md section 2 with the reference fit's R, D, e and pitch."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    fit = json.loads((REF / "fit.json").read_text(encoding="utf-8"))
    g = fit["geometry"]
    R, D, e, p = g["R_mm"], g["D_mm"], g["e_mm"], g["pitch_mm"]
    P = 2 * D + 2 * math.pi * R

    def path(u, off):
        u = np.mod(u, P)
        x = np.empty_like(u)
        y = np.empty_like(u)
        a = u < D
        b = (u >= D) & (u < D + math.pi * R)
        c = (u >= D + math.pi * R) & (u < 2 * D + math.pi * R)
        d = u >= 2 * D + math.pi * R
        x[a], y[a] = D / 2 - u[a], -off + 0 * u[a]
        phi = (u[b] - D) / R
        x[b], y[b] = -D / 2 - (R + off) * np.sin(phi), R - (R + off) * np.cos(phi)
        x[c], y[c] = -D / 2 + (u[c] - D - math.pi * R), 2 * R + off + 0 * u[c]
        phi = (u[d] - 2 * D - math.pi * R) / R
        x[d], y[d] = D / 2 + (R + off) * np.sin(phi), R + (R + off) * np.cos(phi)
        return x, y

    u = np.linspace(0, P, 2000)
    fig, ax = plt.subplots(figsize=(8, 3.6), dpi=110)
    ax.plot(*path(u, 0.0), color="0.3", lw=1.2, label="pitch line (e = 0)")
    ax.plot(*path(u, e), color="tab:blue", lw=1.0, ls="--", label=f"lug-marker path (e = {e:.2f} mm)")
    for xc in (-D / 2, D / 2):
        ax.add_patch(plt.Circle((xc, R), R, fill=False, color="0.6", lw=0.8))
        ax.plot([xc], [R], "+", color="0.5")
    lugs = np.arange(0, P, p)
    ax.plot(*path(lugs, e), "o", ms=4, color="tab:orange", label=f"lugs, pitch p = {p:.2f} mm")
    ax.plot(*path(np.array([0.0]), e), "o", ms=7, mfc="none", mec="k", label="u = 0 (start of bottom run)")
    ax.plot([-40, 40], [2 * R + 28, 2 * R + 28], "s", color="tab:green", ms=6, label="body markers (X(t) + c_j; placed for the picture)")
    ax.annotate("", xy=(D / 2 - 45, 6), xytext=(D / 2 - 15, 6),
                arrowprops=dict(arrowstyle="->", color="k"))
    ax.text(D / 2 - 30, 9, "bottom run: rearward", ha="center", fontsize=8)
    ax.annotate("", xy=(-D / 2 + 35, 2 * R + e + 9), xytext=(-D / 2 + 5, 2 * R + e + 9),
                arrowprops=dict(arrowstyle="->", color="k"))
    ax.text(-D / 2 + 20, 2 * R + e + 13, "top run: forward", ha="center", fontsize=8)
    ax.axhline(-e, color="saddlebrown", lw=0.6, alpha=0.5)
    ax.set_aspect("equal")
    ax.set_xlabel("x relative to the body, mm (travel to the right)")
    ax.set_ylabel("y, mm")
    ax.set_title(f"Reference fit: R = {R:.2f} mm, D = {D:.2f} mm, belt P = 2D + 2πR = {P:.1f} mm",
                 fontsize=9)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    fig.savefig(IMG / "geometry.png")
    plt.close(fig)


if __name__ == "__main__":
    IMG.mkdir(parents=True, exist_ok=True)
    report_figures()
    geometry_figure()
