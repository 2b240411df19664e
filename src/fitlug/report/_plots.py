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


#: a colorbar's slot beside its axes (fractions of the axes' cell) and its length/width:
#: a slim bar close to the axes, as constrained layout drew it
CBAR = {"fraction": 0.04, "pad": 0.04, "aspect": 16}

RC = {"font.size": 10, "axes.titlesize": 10.5, "axes.labelsize": 10, "legend.fontsize": 9,
      "xtick.labelsize": 9, "ytick.labelsize": 9, "figure.dpi": 96}


def new_figure(w, h, rows=1, cols=1, **kw):
    """(figure, axes[rows, cols]) with the report's font sizes, laid out by
    :func:`fitlug.report._layout.tidy` when it is saved (no pyplot)."""
    import matplotlib

    from ._layout import figure

    matplotlib.rcParams.update(RC)
    fig = figure(w, h)
    return fig, fig.subplots(rows, cols, squeeze=False, **kw)


def _ax(ax, figsize=(8, 4)):
    if ax is not None:
        return ax
    return new_figure(*figsize)[1][0, 0]


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


def _contact_run(st: dict, m: int, t0: float, t1: float):
    """Indices (time order) of marker m's bottom-run samples in the contact holding [t0, t1]."""
    sel = np.flatnonzero((st["lug_i"] == m) & st["lug_valid"])
    sel = sel[np.argsort(st["lug_t"][sel])]
    on = st["lug_seg"][sel] == 0
    inside = (st["lug_t"][sel] >= t0) & (st["lug_t"][sel] <= t1)
    if not inside.any():
        return sel[:0]
    k = int(np.flatnonzero(inside)[0])
    lo = k
    while lo > 0 and on[lo - 1]:
        lo -= 1
    hi = k
    while hi < len(sel) - 1 and on[hi + 1]:
        hi += 1
    return sel[lo:hi + 1]


def creep(st: dict):
    """The stall's creep: {"marker", "t0", "t1", "x_touch", "x_lift", "measured_mm",
    "model_mm"} from the stall window's whole bottom-run contact, or None."""
    win = stall_window(st)
    if win is None:
        return None
    m, t0, t1 = win
    run = _contact_run(st, m, t0, t1)
    if len(run) < 3:
        return None
    t, x = st["lug_t"][run], st["lug_x"][run]
    cm = (st["curve_i"] == m) & (st["curve_t"] >= t[0]) & (st["curve_t"] <= t[-1])
    mx = st["curve_x"][cm]
    return {"marker": int(m), "t0": float(t[0]), "t1": float(t[-1]),
            "x_touch": float(x[0]), "x_lift": float(x[-1]),
            "measured_mm": float(x[0] - x[-1]),
            "model_mm": float(mx[0] - mx[-1]) if len(mx) > 1 else float("nan")}


def plot_stall(st: dict, ax=None, slip: float | None = None, D_mm: float | None = None):
    """One lug marker's horizontal stall on the ground, enlarged: data and model, the
    no-slip path (the marker standing still) and the measured creep length.

    Returns {"measured_mm", "expected_mm" (s0 D), ...} when a stall is found (the axes
    are then `ax`), else None. Called with ax=None it draws on a new figure.
    """
    ax = _ax(ax, (6, 4.5))
    win = stall_window(st)
    if win is None:
        ax.text(0.5, 0.5, "no bottom-run contact at cruise speed", ha="center",
                transform=ax.transAxes)
        return None
    m, t0, t1 = win
    cr = creep(st)
    if cr is not None:
        t0, t1 = cr["t0"], cr["t1"]
    pad = 0.15 * (t1 - t0)
    c = (st["curve_i"] == m) & (st["curve_t"] >= t0 - pad) & (st["curve_t"] <= t1 + pad)
    d = st["lug_valid"] & (st["lug_i"] == m) & (st["lug_t"] >= t0 - pad) & (
        st["lug_t"] <= t1 + pad)
    ax.plot(st["curve_x"][c], st["curve_y"][c], "-", color="#555555", lw=1, label="model")
    sc = ax.scatter(st["lug_x"][d], st["lug_y"][d], c=st["lug_t"][d], s=12, cmap="viridis",
                    label="data", zorder=3)
    bot = d & (st["lug_seg"] == 0)
    ys = st["lug_y"][bot] if bot.any() else st["lug_y"][d]
    y0 = float(ys.min())
    xs = st["lug_x"][bot] if bot.any() else st["lug_x"][d]
    w = float(np.ptp(xs)) if len(xs) else 1.0
    ax.set_xlim(xs.min() - 0.5 * w - 0.5, xs.max() + 0.5 * w + 0.5)
    ax.set_ylim(y0 - 2.5, y0 + 6.0)
    out = None
    if cr is not None:
        ax.axvline(cr["x_touch"], color="#c92a2a", ls="--", lw=1,
                   label="no-slip path (s = 0: the marker stands still)")
        ya = y0 - 1.2
        ax.annotate("", xy=(cr["x_lift"], ya), xytext=(cr["x_touch"], ya),
                    arrowprops={"arrowstyle": "<->", "color": "k", "lw": 0.8})
        txt = f"creep {cr['measured_mm']:.2f} mm"
        out = dict(cr)
        out["expected_mm"] = (float(slip) * float(D_mm) if slip is not None and D_mm
                              else float("nan"))
        if np.isfinite(out["expected_mm"]):
            txt += f"  (s₀·D = {out['expected_mm']:.2f} mm)"
        ax.text(0.5 * (cr["x_touch"] + cr["x_lift"]), ya - 0.25, txt, ha="center", va="top",
                fontsize=9)
    names = st.get("meta", {}).get("markers")
    ids = st.get("meta", {}).get("lug_ids")
    label = names[ids[m]] if names and ids else f"lug {m}"
    ax.figure.colorbar(sc, ax=ax, label="t (s)", **CBAR)
    ax.set_xlabel("x (mm, ground frame)")
    ax.set_ylabel("y (mm)")
    ax.set_title(f"Stall of {label} on the ground, enlarged")
    ax.legend(frameon=False, loc="upper left")
    return out


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
            label="belt speed $v_t = v/(1-s)$")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("velocity (mm/s)")
    ax.set_title("Body velocity")
    ax.legend(frameon=False, loc="lower center", ncol=3)
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
    """Residuals (data - model, µm) over time, coloured by path segment; the legend sits
    above the axes, never over the data."""
    ax = _ax(ax, (10, 3))
    for name, col, t, _, r in _residual_groups(st, axis, prefix):
        ax.plot(t, r, ".", ms=1.2, color=col, label=name)
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xlabel("t (s)")
    ax.set_ylabel(f"{axis} residual (µm)")
    ax.legend(frameon=False, ncol=5, markerscale=6, loc="lower right",
              bbox_to_anchor=(1.0, 1.0), borderaxespad=0.1)
    return ax


def plot_residuals_path(st: dict, axis: str = "x", ax=None, prefix: str = "",
                        P: float | None = None):
    """Lug residuals (µm) along the belt coordinate u (0 .. belt length P), by segment."""
    ax = _ax(ax, (10, 3))
    for name, col, _, u, r in _residual_groups(st, axis, prefix)[:4]:
        ax.plot(u, r, ".", ms=1.2, color=col, label=name)
    ax.axhline(0, color="k", lw=0.5)
    Ptxt = f", P = {P:.1f} mm" if P else ""
    ax.set_xlabel(f"belt coordinate u: position on the belt loop (mm{Ptxt})")
    ax.set_ylabel(f"{axis} residual (µm)")
    ax.legend(frameon=False, ncol=4, markerscale=6, loc="lower right",
              bbox_to_anchor=(1.0, 1.0), borderaxespad=0.1)
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
        ax.bar(xs + (k - 0.5) * 0.38, vals, width=0.38, label=f"{axis} residual",
               color=("#4c72b0", "#dd8452")[k])
    if noise_mm:
        for role, ls in (("lug", "--"), ("body", ":")):
            if noise_mm.get(role):
                ax.axhline(1000 * noise_mm[role], color="k", ls=ls, lw=0.8,
                           label=f"{role} noise")
    ax.set_xticks(xs, groups)
    ax.set_ylabel("RMS residual (µm)")
    ax.legend(frameon=False, ncol=4, loc="lower right", bbox_to_anchor=(1.0, 1.0),
              borderaxespad=0.1)
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
    ax.set_xlabel("steady slippage $s_0$")
    ax.set_yticks([])
    ax.legend(frameon=False, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.ticklabel_format(axis="x", useOffset=False)
    ax.xaxis.set_major_locator(_locator(5))
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
        from ._layout import figure

        fig = figure(max(2.6 * k + 0.8, 5.0), max(2.6 * k + 0.8, 5.0))
        fig._fitlug_tidy = False  # corner sets its own margins
    from ._format import pm

    corner.corner(samples, labels=labels, fig=fig, quantiles=[0.025, 0.5, 0.975],
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


def _locator(n):
    from matplotlib.ticker import MaxNLocator

    return MaxNLocator(n)


# ----- the slip drawn ---------------------------------------------------------------------

G_MM_S2 = 9806.65


def _accel(st):
    t, v = st["fine_t"], st["fine_v"]
    return np.gradient(v, t)


def _post(st, name):
    meta = st.get("meta", {})
    names = meta.get("post_names") or []
    if "post_samples" in st and name in names:
        return st["post_samples"][:, names.index(name)]
    return None


def slip_band(st: dict, n: int = 400):
    """(t, s_model, lo, hi): the model's slip over the fine grid and its 1 σ band from the
    posterior samples of s0 and beta (linear law s0 + beta a), else the least squares."""
    t, s = st["fine_t"], st["fine_s"]
    a = _accel(st)
    s0, be = _post(st, "s0"), _post(st, "beta")
    if s0 is not None and be is not None:
        idx = np.linspace(0, len(s0) - 1, min(n, len(s0))).astype(int)
        lin = s0[idx, None] + be[idx, None] * a[None, :]
        sd = np.std(lin, axis=0)
    else:
        ls = st.get("meta", {}).get("least_squares", {})
        e0, eb = ls.get("s0_linear") or ls.get("slip") or {}, ls.get("beta") or {}
        sd = np.sqrt((e0.get("std") or 0) ** 2 + ((eb.get("std") or 0) * a) ** 2)
    return t, s, s - sd, s + sd


def plot_slip_time(st: dict, fj: dict | None = None, ax=None):
    """The slip s(t) over the recording with its 1 σ band; rest shaded grey."""
    from ._format import pm

    ax = _ax(ax, (9, 3.4))
    t, s, lo, hi = slip_band(st)
    v = st["fine_v"]
    moving = np.abs(v) > 0.05 * np.max(np.abs(v))
    sm = np.where(moving, s, np.nan)
    ax.fill_between(t, np.where(moving, lo, np.nan), np.where(moving, hi, np.nan),
                    color="#08519c", alpha=0.25, lw=0, label="1 σ band")
    ax.plot(t, sm, "-", color="#08519c", lw=1.3, label="slip s(t)")
    slip = (fj or {}).get("slip") or {}
    if slip.get("value") is not None:
        ax.axhline(slip["value"], color="k", ls="--", lw=0.8,
                   label=f"steady slip s₀ = {pm(slip['value'], slip.get('std'))}")
    # rest: slip undefined
    edges = np.flatnonzero(np.diff(np.r_[0, (~moving).astype(int), 0]))
    for k in range(0, len(edges), 2):
        i0, i1 = edges[k], min(edges[k + 1], len(t)) - 1
        ax.axvspan(t[i0], t[i1], color="#bbbbbb", alpha=0.35, lw=0,
                   label="at rest" if k == 0 else None)
    ax.set_xlabel("t (s)")
    ax.set_ylabel("slip s")
    ax.ticklabel_format(axis="y", useOffset=False)
    ax.legend(frameon=False, ncol=4, loc="lower left", bbox_to_anchor=(0.0, 1.0),
              borderaxespad=0.1)
    return ax


def slip_from_lugs(st: dict):
    """Per-sample slip measured from lug markers on the ground: a bottom-run marker moves
    at -s v_t = -s v/(1-s), so s = -u/(v - u) with u its ground speed (central differences
    within one contact) and v the body speed. Returns (t, s) at samples with v > 20 % of
    the top speed."""
    ts, ss = [], []
    vmax = np.max(np.abs(st["fine_v"]))
    for m in np.unique(st["lug_i"]):
        sel = np.flatnonzero((st["lug_i"] == m) & st["lug_valid"])
        sel = sel[np.argsort(st["lug_t"][sel])]
        if len(sel) < 3:
            continue
        t, x, g = st["lug_t"][sel], st["lug_x"][sel], st["lug_seg"][sel]
        dt = np.diff(t)
        step = np.median(dt)
        ok = (g[:-2] == 0) & (g[1:-1] == 0) & (g[2:] == 0) & (dt[:-1] < 1.5 * step) & (
            dt[1:] < 1.5 * step)
        u = (x[2:] - x[:-2]) / (t[2:] - t[:-2])
        tc = t[1:-1]
        v = np.interp(tc, st["fine_t"], st["fine_v"])
        keep = ok & (v > 0.2 * vmax)
        ts.append(tc[keep])
        ss.append(-u[keep] / (v[keep] - u[keep]))
    if not ts:
        return np.empty(0), np.empty(0)
    return np.concatenate(ts), np.concatenate(ss)


def plot_slip_force(st: dict, fj: dict | None = None, ax=None, bins: int = 14):
    """Slip against the traction load F = m (a + C_rr g): the lug markers' measured slip,
    binned per phase (mean ± 1 σ of the mean), and the model's law."""
    ax = _ax(ax, (9, 4.2))
    fj = fj or {}
    mass = (fj.get("rig") or {}).get("mass_kg") or st.get("meta", {}).get("mass_kg")
    crr = ((fj.get("rolling_resistance") or {}).get("value")
           or (st.get("meta", {}).get("least_squares", {}).get("rolling_resistance")
               or {}).get("value") or 0.0)
    scale = float(mass) if mass else 1.0
    unit = "N" if mass else "N/kg"

    def force(a_mm):
        return scale * (a_mm + crr * G_MM_S2) / 1000.0

    a = _accel(st)
    v = st["fine_v"]
    moving = np.abs(v) > 0.2 * np.max(np.abs(v))
    Fm = force(a)[moving]
    o = np.argsort(Fm)
    amax = np.max(np.abs(a[moving])) if moving.any() else 1.0
    t, s = slip_from_lugs(st)
    if len(t):
        at = np.interp(t, st["fine_t"], a)
        Ft = force(at)
        phase = np.where(at > 0.1 * amax, 0, np.where(at < -0.1 * amax, 2, 1))
        lo, hi = np.percentile(s, [1, 99])
        for k, (name, col) in enumerate((("accelerating", "#e6550d"), ("cruising", "#31a354"),
                                         ("braking", "#3182bd"))):
            sel = (phase == k) & (s >= lo) & (s <= hi)
            if sel.sum() < 5:
                continue
            edges = np.unique(np.quantile(Ft[sel], np.linspace(0, 1, bins + 1)))
            which = np.clip(np.searchsorted(edges, Ft[sel], side="right") - 1, 0,
                            len(edges) - 2)
            xs, ys, es = [], [], []
            for b in range(len(edges) - 1):
                q = which == b
                if q.sum() >= 3:
                    xs.append(np.mean(Ft[sel][q]))
                    ys.append(np.mean(s[sel][q]))
                    es.append(np.std(s[sel][q]) / np.sqrt(q.sum()))
            ax.errorbar(xs, ys, yerr=es, fmt="o", ms=4, color=col, lw=1, capsize=2,
                        label=f"lug markers, {name}")
    ax.plot(Fm[o], st["fine_s"][moving][o], "-", color="k", lw=1.5, label="fitted law s(F)")
    ax.set_xlabel(f"traction load F = m(a + C_rr g) ({unit})")
    ax.set_ylabel("slip s")
    ax.ticklabel_format(axis="y", useOffset=False)
    ax.legend(frameon=False, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return ax


# ----- per marker --------------------------------------------------------------------------

def marker_coverage(st: dict) -> dict:
    """{marker name: {"role", "coverage", "n", "t_range", "rms_sigma"}} from the state."""
    meta = st.get("meta", {})
    names = meta.get("markers") or []
    noise = meta.get("noise_mm") or {}
    frames = np.unique(np.r_[st["lug_t"], st["body_t"]])
    out = {}
    for role, key, ids in (("lug", "lug_i", meta.get("lug_ids") or []),
                           ("body", "body_j", meta.get("body_ids") or [])):
        pre = "lug" if role == "lug" else "body"
        for i in np.unique(st[key]):
            sel = (st[key] == i) & st[f"{pre}_valid"]
            name = names[ids[i]] if ids and i < len(ids) and ids[i] < len(names) else f"{role} {i}"
            rx, ry = st[f"{pre}_res_x"][sel], st[f"{pre}_res_y"][sel]
            sig = noise.get(role) or 1.0
            t = st[f"{pre}_t"][sel]
            out[str(name)] = {"role": role, "coverage": sel.sum() / max(len(frames), 1),
                              "n": int(sel.sum()),
                              "t_range": [float(t.min()), float(t.max())] if len(t) else [],
                              "rms_sigma": float(np.sqrt(np.nanmean(rx ** 2 + ry ** 2) / 2)) / sig
                              if len(t) else float("nan")}
    return out


def plot_marker_residuals(st: dict, glitches=None, cols: int = 4):
    """Small multiples: |r|/σ over time, one panel per marker, shared scales."""
    meta = st.get("meta", {})
    names = meta.get("markers") or []
    noise = meta.get("noise_mm") or {}
    panels = []
    for role, key, ids in (("lug", "lug_i", meta.get("lug_ids") or []),
                           ("body", "body_j", meta.get("body_ids") or [])):
        for i in np.unique(st[key]):
            sel = (st[key] == i) & st[f"{role}_valid"]
            name = names[ids[i]] if ids and i < len(ids) and ids[i] < len(names) else f"{role} {i}"
            r = np.hypot(st[f"{role}_res_x"][sel], st[f"{role}_res_y"][sel]) / (
                noise.get(role) or 1.0) / np.sqrt(2)
            panels.append((str(name), role, st[f"{role}_t"][sel], r))
    n = max(len(panels), 1)
    rows = int(np.ceil(n / cols))
    fig, axes = new_figure(9.0, 0.3 + 1.25 * rows, rows, cols, sharex=True, sharey=True)
    top = max([np.nanpercentile(p[3], 99.5) for p in panels if len(p[3])] + [4.0])
    tlo = float(np.min(st["fine_t"]))
    thi = float(np.max(st["fine_t"]))
    gl = {}
    for g in glitches or []:
        gl.setdefault(str(g.get("marker")), []).append(g)
    for k, ax in enumerate(axes.flat):
        if k >= len(panels):
            ax.set_visible(False)
            continue
        name, role, t, r = panels[k]
        ax.plot(t, r, ".", ms=0.8, color="#4c72b0" if role == "lug" else BODY_COLOR)
        for g in gl.get(name, []):
            ax.plot([g.get("time_s")], [top * 0.9], "x", color="#c92a2a", ms=5)
        ax.set_ylim(0, top)
        ax.set_xlim(tlo, thi)
        ax.text(0.02, 0.95, name, transform=ax.transAxes, ha="left", va="top", fontsize=8,
                bbox={"fc": "white", "ec": "none", "alpha": 0.7, "pad": 1}, clip_on=True)
        ax.tick_params(labelsize=7)
    for ax in axes[-1]:
        ax.set_xlabel("t (s)", fontsize=8)
    for ax in axes[:, 0]:
        ax.set_ylabel("|r|/σ", fontsize=8)
    return fig


# ----- diagnostics -------------------------------------------------------------------------

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


def plot_traces(chains: dict):
    """Walker traces, one panel per parameter: chains {name: (walkers, draws)}."""
    k = max(len(chains), 1)
    fig, axes = new_figure(9.0, 0.4 + 1.6 * k, k, 1, sharex=True)
    for ax, (name, c) in zip(axes[:, 0], chains.items()):
        c = np.asarray(c)
        ax.plot(c.T, lw=0.3, alpha=0.5)
        ax.set_ylabel(name)
        ax.ticklabel_format(axis="y", useOffset=False)
        ax.yaxis.set_major_locator(_locator(4))
    axes[-1, 0].set_xlabel("draw after burn-in")
    return fig
