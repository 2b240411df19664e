"""The report's figures: plain matplotlib, one function per panel, apart from the numerics.

Every function takes the arrays it draws (usually the state dict of
:mod:`fitlug.report._state`) and `ax=None` (a new figure when None) and returns the axes.
matplotlib is imported inside the functions, with the Agg backend: `import fitlug` never
pulls it in and no display is needed.
"""

from __future__ import annotations

import numpy as np

SEGMENTS = ("bottom", "rear arc", "top", "front arc")
SEG_COLORS = ("#1b9e77", "#d95f02", "#7570b3", "#e7298a")
BODY_COLOR = "#444444"


def _ax(ax, figsize=(8, 4)):
    if ax is not None:
        return ax
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt.figure(figsize=figsize).add_subplot()


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
        ax.annotate("stall, enlarged below", (x1, y1), fontsize=7, ha="left", va="bottom")
    ax.plot([], [], "k.", ms=3, label="data")
    ax.plot([], [], "k-", lw=0.8, label="model")
    ax.set_xlabel("x (mm, ground frame)")
    ax.set_ylabel("y (mm)")
    ax.set_aspect("equal", adjustable="box")
    ax.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=3, fontsize=8, frameon=False)
    return ax


def trajectory_figsize(st: dict, width: float = 14.0) -> tuple:
    """(width, height) in inches for :func:`plot_trajectories` at equal aspect."""
    xs = np.concatenate([st["lug_x"][st["lug_valid"]], st["body_x"][st["body_valid"]]])
    ys = np.concatenate([st["lug_y"][st["lug_valid"]], st["body_y"][st["body_valid"]]])
    if not len(xs):
        return width, 4.0
    ratio = (np.ptp(ys) + 10.0) / max(np.ptp(xs) + 10.0, 1e-9)
    return width, float(np.clip(width * ratio + 1.2, 2.6, 8.0))


def stall_window(st: dict):
    """(marker, t0, t1) of the longest bottom-run contact at high speed, or None."""
    seg, t, i = st["lug_seg"], st["lug_t"], st["lug_i"]
    ok = st["lug_valid"] & (seg == 0)
    v = np.interp(t, st["fine_t"], st["fine_v"])
    fast = v >= 0.8 * np.max(np.abs(st["fine_v"]))
    best = None
    for m in np.unique(i):
        sel = np.flatnonzero((i == m) & ok & fast)
        if len(sel) < 3:
            continue
        order = sel[np.argsort(t[sel])]
        tt = t[order]
        gaps = np.flatnonzero(np.diff(tt) > 1.5 * np.median(np.diff(tt)))
        starts = np.r_[0, gaps + 1]
        ends = np.r_[gaps, len(tt) - 1]
        k = int(np.argmax(ends - starts))
        span = (ends[k] - starts[k], int(m), tt[starts[k]], tt[ends[k]])
        if best is None or span[0] > best[0]:
            best = span
    return None if best is None else best[1:]


def stall_box(st: dict):
    """(x0, x1, y0, y1) mm around the stall of :func:`stall_window`, or None."""
    win = stall_window(st)
    if win is None:
        return None
    m, t0, t1 = win
    bot = (st["lug_valid"] & (st["lug_i"] == m) & (st["lug_t"] >= t0) & (st["lug_t"] <= t1)
           & (st["lug_seg"] == 0))
    xs, ys = st["lug_x"][bot], st["lug_y"][bot]
    if not len(xs):
        return None
    w = np.ptp(xs)
    return xs.min() - 0.6 * w - 0.5, xs.max() + 0.6 * w + 0.5, ys.min() - 2.0, ys.min() + 6.0


def plot_stall(st: dict, ax=None):
    """One lug marker's horizontal stall on the ground, enlarged: data and model."""
    ax = _ax(ax, (5, 4))
    win = stall_window(st)
    if win is None:
        ax.text(0.5, 0.5, "no bottom-run contact at cruise speed", ha="center",
                transform=ax.transAxes)
        return ax
    m, t0, t1 = win
    pad = 0.15 * (t1 - t0)
    c = (st["curve_i"] == m) & (st["curve_t"] >= t0 - pad) & (st["curve_t"] <= t1 + pad)
    d = st["lug_valid"] & (st["lug_i"] == m) & (st["lug_t"] >= t0 - pad) & (
        st["lug_t"] <= t1 + pad)
    ax.plot(st["curve_x"][c], st["curve_y"][c], "-", color="#555555", lw=1, label="model")
    sc = ax.scatter(st["lug_x"][d], st["lug_y"][d], c=st["lug_t"][d], s=12, cmap="viridis",
                    label="data", zorder=3)
    box = stall_box(st)
    if box is not None:
        ax.set_xlim(box[0], box[1])
        ax.set_ylim(box[2], box[3])
    names = st.get("meta", {}).get("markers")
    ids = st.get("meta", {}).get("lug_ids")
    label = names[ids[m]] if names and ids else f"lug {m}"
    ax.figure.colorbar(sc, ax=ax, label="t (s)")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_title(f"Horizontal stall of {label}, enlarged")
    ax.legend(fontsize=8, frameon=False)
    return ax


def plot_displacement(st: dict, ax=None):
    """Body displacement X(t): model and every body sample (the paper's Fig. 13)."""
    ax = _ax(ax)
    b = st["body_valid"]
    ax.plot(st["body_t"][b], st["body_X_data"][b], ".", ms=2, color="#999999", label="data")
    ax.plot(st["fine_t"], st["fine_X"], "-", color="#1f77b4", lw=1.2, label="model X(t)")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("body displacement (mm)")
    ax.set_title("Body displacement")
    ax.legend(fontsize=8, frameon=False)
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
            label="belt speed v_t = v / (1 - s)")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("velocity (mm/s)")
    ax.set_title("Body velocity")
    ax.legend(fontsize=8, frameon=False)
    return ax


def _residual_groups(st: dict, axis: str, prefix: str = ""):
    """[(label, color, t, u, res_um)] per lug segment plus the body markers."""
    r = st[f"{prefix}lug_res_{axis}"] * 1000.0
    out = []
    for k, name in enumerate(SEGMENTS):
        sel = (st["lug_seg"] == k) & np.isfinite(r)
        out.append((name, SEG_COLORS[k], st["lug_t"][sel], st["lug_u"][sel], r[sel]))
    rb = st[f"{prefix}body_res_{axis}"] * 1000.0
    sel = np.isfinite(rb)
    out.append(("body", BODY_COLOR, st["body_t"][sel], None, rb[sel]))
    return out


def plot_residuals_time(st: dict, axis: str = "x", ax=None, prefix: str = ""):
    """Residuals (data - model, um) over time, coloured by path segment."""
    ax = _ax(ax, (10, 3))
    for name, col, t, _, r in _residual_groups(st, axis, prefix):
        ax.plot(t, r, ".", ms=1.2, color=col, label=name)
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xlabel("t (s)")
    ax.set_ylabel(f"{axis} residual (um)")
    ax.legend(fontsize=7, frameon=False, ncol=5, markerscale=5, loc="upper right")
    return ax


def plot_residuals_path(st: dict, axis: str = "x", ax=None):
    """Lug residuals (um) along the belt path u = sigma mod P, segment joins marked."""
    ax = _ax(ax, (10, 3))
    for name, col, _, u, r in _residual_groups(st, axis)[:4]:
        ax.plot(u, r, ".", ms=1.2, color=col, label=name)
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xlabel("belt coordinate u = sigma mod P (mm): bottom, rear arc, top, front arc")
    ax.set_ylabel(f"{axis} residual (um)")
    ax.legend(fontsize=7, frameon=False, ncol=4, markerscale=5, loc="upper right")
    return ax


def segment_rms(st: dict, prefix: str = "") -> dict:
    """RMS residual (um) per group and axis: {(group, axis): (rms, count)}."""
    out = {}
    for axis in ("x", "y"):
        for name, _, _, _, r in _residual_groups(st, axis, prefix):
            out[(name, axis)] = (float(np.sqrt(np.mean(r ** 2))) if len(r) else float("nan"),
                                 int(len(r)))
    return out


def plot_segment_rms(st: dict, ax=None, noise_mm: dict | None = None):
    """RMS residual per segment and axis (bars), with the fitted noise levels."""
    ax = _ax(ax, (6, 3))
    rms = segment_rms(st)
    groups = list(SEGMENTS) + ["body"]
    xs = np.arange(len(groups))
    for k, axis in enumerate(("x", "y")):
        vals = [rms[(g, axis)][0] for g in groups]
        ax.bar(xs + (k - 0.5) * 0.38, vals, width=0.38, label=f"{axis}",
               color=("#4c72b0", "#dd8452")[k])
    if noise_mm:
        for role, ls in (("lug", "--"), ("body", ":")):
            if noise_mm.get(role):
                ax.axhline(1000 * noise_mm[role], color="k", ls=ls, lw=0.8,
                           label=f"{role} noise")
    ax.set_xticks(xs, groups)
    ax.set_ylabel("RMS residual (um)")
    ax.legend(fontsize=8, frameon=False)
    return ax


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
    ax.axvline(med, color="#08519c", lw=1.5, label=f"median {med:.6g}")
    ax.axvspan(lo, hi, color="#08519c", alpha=0.12, label="95 % interval")
    if least_squares is not None and least_squares[1]:
        m, s = least_squares
        g = np.linspace(m - 4 * s, m + 4 * s, 200)
        ax.plot(g, np.exp(-0.5 * ((g - m) / s) ** 2) / (s * np.sqrt(2 * np.pi)), "k--",
                lw=0.8, label="least squares (normal)")
    if reference is not None:
        ax.axvline(reference, color="#cb181d", lw=1.2, ls="-.",
                   label=f"reference paper {reference:g}")
    ax.set_xlabel("steady slippage s0")
    ax.set_yticks([])
    ax.legend(fontsize=7, frameon=False)
    ax.ticklabel_format(axis="x", useOffset=False)
    return ax


def plot_trace(chain, ax=None, name: str = "s0"):
    """Walker traces of one sampled parameter (draws after burn-in)."""
    ax = _ax(ax, (6, 2.5))
    chain = np.asarray(chain)
    ax.plot(chain, lw=0.3, alpha=0.6)
    ax.set_xlabel("step after burn-in")
    ax.set_ylabel(name)
    ax.ticklabel_format(axis="y", useOffset=False)
    return ax


def plot_corner(samples, labels, fig=None, truths=None):
    """Corner plot of the physical parameters (corner.py); returns the figure.

    corner draws a grid of axes, so this one takes (and returns) a figure instead of an ax.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import corner

    samples = np.asarray(samples, float)
    k = samples.shape[1]
    if fig is None:
        import matplotlib.pyplot as plt

        fig = plt.figure(figsize=(2.3 * k + 0.5, 2.3 * k + 0.5))
    corner.corner(samples, labels=labels, fig=fig, quantiles=[0.025, 0.5, 0.975],
                  show_titles=True, title_fmt=".4g", truths=truths, bins=30,
                  plot_datapoints=False, smooth=0.8, title_kwargs={"fontsize": 8},
                  label_kwargs={"fontsize": 9})
    for a in fig.axes:
        a.tick_params(labelsize=7)
        for axis in (a.xaxis, a.yaxis):  # offsets like "+1e-1" read badly on tiny spreads
            fmt = axis.get_major_formatter()
            if hasattr(fmt, "set_useOffset"):
                fmt.set_useOffset(False)
    return fig
