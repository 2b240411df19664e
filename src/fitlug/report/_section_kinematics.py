"""The report's "Body displacement and velocity" section and its plots (the paper's
Figs. 13 and 14)."""

from __future__ import annotations

import numpy as np

from ._figure import FIG_W, _ax, _fig, figure_html


def _kinematics(st) -> str:
    fig, ax = _fig(FIG_W, 6.0, 2, 1)
    plot_displacement(st, ax=ax[0, 0])
    plot_velocity(st, ax=ax[1, 0])
    return figure_html(fig, "body displacement and velocity over time",
                       "Top: body displacement X(t) (the paper's Fig. 13). Bottom: body "
                       "speed v and belt speed v_t = v/(1 − s) (Fig. 14); the gap between "
                       "them is the slip.")


def plot_displacement(st: dict, ax=None):
    """Body displacement X(t): model and every body sample (the paper's Fig. 13)."""
    ax = _ax(ax)
    b = st["body_valid"]
    ax.plot(st["body_t"][b], st["body_X_data"][b], ".", ms=2, color="#999999", label="data")
    ax.plot(st["fine_t"], st["fine_X"], "-", color="#1f77b4", lw=1.2, label="model X(t)")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("body displacement (mm)")
    ax.set_title("Body displacement")
    ax.legend(frameon=False, loc="upper left")
    return ax


def data_velocity(st: dict):
    """(t, v) of the body from central differences of each body marker (mm/s)."""
    ts, vs = [], []
    for j in np.unique(st["body_j"]):
        sel = (st["body_j"] == j) & st["body_valid"]
        t, x = st["body_t"][sel], st["body_x"][sel]
        o = np.argsort(t)
        t, x = t[o], x[o]
        if len(t) < 3:
            continue
        ts.append(t[1:-1])
        vs.append((x[2:] - x[:-2]) / (t[2:] - t[:-2]))
    if not ts:
        return np.empty(0), np.empty(0)
    return np.concatenate(ts), np.concatenate(vs)


def plot_velocity(st: dict, ax=None):
    """Body speed v(t) and belt speed v_t(t), model and data (the paper's Fig. 14)."""
    ax = _ax(ax)
    t, v = data_velocity(st)
    ax.plot(t, v, ".", ms=1.5, color="#999999", label="data (central differences)")
    ax.plot(st["fine_t"], st["fine_v"], "-", color="#1f77b4", lw=1.2, label="body speed v")
    ax.plot(st["fine_t"], st["fine_vt"], "--", color="#d62728", lw=1.0,
            label="belt speed vₜ = v/(1−s)")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("velocity (mm/s)")
    ax.set_title("Body velocity")
    ax.legend(frameon=False, loc="lower center", ncol=3)
    return ax
