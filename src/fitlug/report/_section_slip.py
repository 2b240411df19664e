"""The report's "The slip drawn" section and its plots: the slip s(t) with its band, slip
against the traction load (measured from the lug markers on the ground) and one lug
marker's stall enlarged with its creep."""

from __future__ import annotations

import numpy as np

from . import _format as F
from ._figure import CBAR, FIG_W, _ax, _fig, figure_html
from ._section_summary import _sliding


def _slip_section(fj, st) -> str:
    out = []
    slip = (fj.get("slip") or {}).get("value")
    if slip is None:
        # no slip is read (the headline says why): the model's s(t) and its law would draw
        # a compromise fit's slip (-300 to +50 on a spinning track's run) as if it were one
        out.append("<p>No slip is read from this recording (the headline says why), so "
                   "neither the slip over time nor its law against the traction load is "
                   "drawn. The lug marker's stall below shows the data against the model "
                   "that could not describe them.</p>")
    else:
        out += _slip_figures(fj, st)
    fig, ax = _fig(FIG_W, 4.4)
    creep = plot_stall(st, ax=ax[0, 0], slip=slip, D_mm=(fj.get("geometry") or {}).get("D_mm"))
    cap = ("One lug marker's stall on the ground, enlarged: data (dots, coloured by time) "
           "and model (line). Without slip the marker would stand still on the ground while "
           "its lug is loaded (the dashed vertical no-slip path); with slip it creeps "
           "rearward by s·D over the contact.")
    if creep:
        cap += f" Measured creep {F.sig(creep['measured_mm'], 3)} mm" + (
            "." if not np.isfinite(creep.get("expected_mm", np.nan))
            else f"; s₀·D = {F.sig(creep['expected_mm'], 3)} mm.")
    out.append(figure_html(fig, "horizontal stall of one lug marker with creep length and "
                                "no-slip path", cap))
    return "".join(out)


def _slip_figures(fj, st) -> list[str]:
    """The slip s(t) with its band and the slip against the traction load."""
    out = []
    fig, ax = _fig(FIG_W, 3.4)
    plot_slip_time(st, fj, ax=ax[0, 0])
    _, _, lo, hi = slip_band(st)
    half = float(np.nanmedian(hi - lo)) / 2
    out.append(figure_html(
        fig, "steady slip s(t) over the recording with its 1 sigma band",
        "The model's slip s(t) = s₀ + β·a(t) over the recording (line) with its 1 σ band "
        "(shaded; from the posterior samples of s₀ and β, else the least-squares errors); "
        f"the dashed line is the steady slip s₀. The band is ± {F.sig(half, 2)} at cruise"
        + (", too narrow to see at this scale. " if half < 0.01 * np.ptp(st["fine_s"]) else ". ")
        + "Look for the slip rising while the robot "
        "accelerates and falling while it brakes; at rest the slip is undefined (grey)."
        + (" Under lug_sliding the law is nonlinear." if _sliding(fj) else "")
        + (" The slip law term found beyond the catalog is added: s(t) = s₀ + β·a(t) + g."
           if st.get("meta", {}).get("slip_law_term") else "")))
    fig, ax = _fig(FIG_W, 4.2)
    plot_slip_force(st, fj, ax=ax[0, 0])
    m = (fj.get("rig") or {}).get("mass_kg")
    out.append(figure_html(
        fig, "slip against traction force, data binned by phase and the fitted law",
        "Slip against the traction load F = m(a + C_rr g)"
        + ("" if m else " per kilogram (no mass given)")
        + ": points are the slip measured from the lug markers on the ground (their "
        "rearward creep relative to the body, binned, ±1 σ of each bin), coloured by phase "
        "(accelerating, cruising, braking); "
        + ("the dashed line is the model's law, whose k and C_rr are not identifiable here "
           "(see the estimates): a compromise, not a law the points should follow; the "
           "dotted line is the slip read, and the axis is the points' and its."
           if _law_not_identifiable(fj) else
           "the line is the fitted law. Look for the points following the line; a bend "
           "away from it at high load means the lugs slide.")))
    return out


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


def _law_not_identifiable(fj: dict | None) -> bool:
    """Whether fit.json says the slip law's stiffness is not identifiable."""
    ni = (fj or {}).get("not_identifiable") or {}
    return bool(ni.get("stiffness_N_per_mm") or ni.get("k_over_m_N_per_mm_kg"))


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
    law = st.get("meta", {}).get("slip_law_term")
    if law and "fine_s_linear" in st and law["form"] != "F":
        # a slip law in the speed: the law in F at the cruise in view, not s(t) sorted by F
        from ..explain.families._slip import slip_change

        s_lin = st["fine_s_linear"][moving][o]
        v_c = law.get("v_headline_mm_s") or law["v_ref_mm_s"]  # the headline's speed
        s_law = s_lin + slip_change(law, np.full(len(s_lin), v_c), s_lin, law["steady_slip"])
        ax.plot(Fm[o], s_law, "-", color="k", lw=1.5, label=f"fitted law s(F) at {v_c:.0f} mm/s")
    elif _law_not_identifiable(fj):
        # the model does not describe the path: its law's k and C_rr are a compromise, drawn
        # faint and said so, not as a law the points should follow
        ys = [ln.get_ydata() for ln in ax.get_lines()]  # the points' bins, before the law
        ax.plot(Fm[o], st["fine_s"][moving][o], "--", color="0.55", lw=1.0,
                label="the model's law (k, C_rr not identifiable)")
        head = (fj.get("slip") or {}).get("value")
        if head is not None:
            ax.axhline(head, color="k", lw=1.0, ls=":", label=f"the slip read ({head:.3g})")
            ys.append([head])
        y = np.concatenate([np.ravel(np.asarray(v, float)) for v in ys]) if ys else np.zeros(0)
        y = y[np.isfinite(y)]
        if len(y):  # the axis is the points' and the slip read, not the compromise's
            pad = 0.15 * max(float(np.ptp(y)), 0.01)
            ax.set_ylim(float(y.min()) - pad, float(y.max()) + pad)
    else:
        ax.plot(Fm[o], st["fine_s"][moving][o], "-", color="k", lw=1.5,
                label="fitted law s(F)")
    ax.set_xlabel(f"traction load F = m(a + C_rr g) ({unit})")
    ax.set_ylabel("slip s")
    ax.ticklabel_format(axis="y", useOffset=False)
    ax.legend(frameon=False, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return ax
