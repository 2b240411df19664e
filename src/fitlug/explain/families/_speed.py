"""Speed modulation: v -> v (1 + m) everywhere, m a Fourier series in time t (a fixed
frequency) or in belt travel psi (locked to the drive), the frequency free (MODEL.md §5;
lug_ripple and wheel_runout are its catalog cases). The term's columns are the change of
X and psi it makes, int v m dt and int v_t m dt, through the fit's d r / d X and d r / d psi.
"""

from __future__ import annotations

import numpy as np

from ._base import Choice, Family, best_size, names
from ._exact import speed_residuals
from ._solve import best_of_seeds, distinct, peak_frequency
from ._vibration import _frequency_std

MAX_HARMONICS = 3


class SpeedModulation(Family):
    """m = sum_k a_k sin(2 pi k f c) + b_k cos(...), c = t (f in Hz) or psi / (v_t / f)."""

    name = "speed modulation"

    @classmethod
    def applies(cls, part):
        return part.get("axis") == "x" and part.get("frequency_hz") is not None

    @classmethod
    def fit(cls, ctx, proj, parts):
        sel = (ctx.axis == 0) & ctx.valid
        T = float(np.ptp(ctx.t[sel]))
        fps = 1.0 / float(np.median(np.diff(np.unique(ctx.t))))
        vt = float(np.max(np.abs(ctx.vt_nodes)))
        # seeds: the located parts' peaks, and the strongest line of the body's x residuals
        # (X carries the modulation's integral directly) in t and in belt travel
        body = sel & (ctx.segment == 4)
        u_rows = np.interp(ctx.t, ctx.grid, ctx.psi_nodes) / vt
        seeds = [p["frequency_hz"] for p in parts if cls.applies(p)]
        if body.sum() > 20:
            seeds += [peak_frequency(ctx.t[body], ctx.r[body], fps / 2, T),
                      peak_frequency(u_rows[body], ctx.r[body], fps / 2, T)]
        seeds = distinct(seeds, 0.06)
        if not seeds:
            return None
        v, vtn = ctx.v_nodes, ctx.vt_nodes
        a = np.gradient(v, ctx.grid)
        s = 1.0 - v / np.where(vtn == 0, 1.0, vtn)
        # the slip answers the modulated acceleration (s = s0 + beta a): v_t changes by
        # v_t m + v_t beta (a m + v dm/dt) / (1 - s), which at tens of Hz outweighs v_t m
        gain_s = vtn * float(np.asarray(ctx.res.params["beta"])) / (1.0 - s)
        out = []
        for coord in ("t", "psi"):
            node_c = ctx.grid if coord == "t" else ctx.psi_nodes / vt  # psi in s at cruise
            rate = np.ones_like(v) if coord == "t" else vtn / vt  # d node_c / dt

            def cols(f, n=1, node_c=node_c, rate=rate):
                k = np.arange(1, n + 1)
                ph = 2 * np.pi * f * np.outer(node_c, k)
                w = 2 * np.pi * f * k[None, :] * rate[:, None]
                m = np.concatenate([np.sin(ph), np.cos(ph)], 1)  # (G, 2n)
                dm = np.concatenate([w * np.cos(ph), -w * np.sin(ph)], 1)  # d m / dt
                dX = ctx.cumulative(m, v)
                dpsi = ctx.cumulative(m, vtn) + ctx.cumulative(
                    a[:, None] * m + v[:, None] * dm, gain_s)
                return np.where(ctx.valid[:, None],
                                ctx.dr_dX[:, None] * dX + ctx.dr_dpsi[:, None] * dpsi, 0.0)

            f = best_of_seeds(proj, cols, seeds, 0.06, T)
            found = best_size(proj, [(n, cols(f, n), 1) for n in range(1, MAX_HARMONICS + 1)])
            if found is not None:
                out.append((coord, f, found, cols))
        if not out:
            return None
        out.sort(key=lambda q: q[2][1].delta_bic)
        coord, f, (n, fitted), cols = out[0]
        f_std = _frequency_std(proj, lambda g: cols(g, n), f, T)
        ambiguous = len(out) > 1 and out[1][2][1].delta_bic - fitted.delta_bic < 10.0
        amb = ("" if not ambiguous else
               "this recording cannot tell a modulation locked to the belt travel from one "
               "at a fixed frequency in time; a recording at another speed would (a "
               "locked one moves its frequency with the speed)")
        exact = speed_residuals(ctx.res, ctx, coord, f, n)
        return _choice(ctx, sel, coord, fitted, n, f_std, vt, ambiguous, amb, exact,
                       np.zeros(exact.n_free), vt)


def _choice(ctx, sel, coord, fitted, n, f_std, vt, ambiguous, amb, exact, free, vt_now):
    """The term with the exact term's frequency at `free` (0: the linear search's; its
    exact refit's in `retuned`); `vt_now` the cruise belt speed of the fit it reports
    under (in psi the term is locked to the belt: one cycle per vt / f mm of the base
    fit's belt travel, at vt_now / that in Hz under the extended fit, whose slip moved)."""
    f_u = exact.free_frequency(free)  # cycles per vt mm of belt travel, or Hz in t
    period = vt / f_u  # mm of belt travel per cycle (psi coordinate)
    f = f_u if coord == "t" else vt_now / period
    xs = np.linspace(0.0, 1.0, 61)  # one cycle, as a fraction

    def m_of(x, c):
        ph = 2 * np.pi * np.outer(np.asarray(x), np.arange(1, n + 1))
        return np.sin(ph) @ c[:n] + np.cos(ph) @ c[n:]

    def describe(c):
        amp = float(np.max(np.abs(m_of(xs, c))))
        params = {"frequency_hz": f, "frequency_std_hz": f_std, "harmonics": n,
                  "amplitude": amp, "coefficients": [float(v) for v in c]}
        if coord == "psi":
            params["period_mm"] = period
            where = f"locked to the belt travel (one cycle per {period:.3g} mm)"
            why = "the motor cogs or a gear meshes"
        else:
            where = "at a fixed frequency in time"
            why = "a drive resonance or the motor's supply ripples"
        if ambiguous:
            why = "the motor cogs, a gear meshes or the drive resonates"
        text = (f"the speed is modulated by {100 * amp:.2g} % at {f:.1f} Hz, {where}: "
                f"{why}")
        return params, text

    u_rows = ctx.t if coord == "t" else np.interp(ctx.t, ctx.grid, ctx.psi_nodes) / vt
    return Choice(SpeedModulation.name, coord, fitted, names(ctx, sel), "x", None, f, m_of, xs,
                  "relative speed change",
                  "cycle fraction" + (f" (period {period:.3g} mm of belt travel)"
                                      if coord == "psi" else f" (period {1 / f:.3g} s)"),
                  describe, label=f"{n} harmonic(s) at {f:.2f} Hz in {coord}",
                  rows=sel & (ctx.segment == 4),
                  row_coord=np.mod(exact.cycles(u_rows, free), 1.0),
                  row_coord_name=f"phase of the {f:.3g} Hz cycle (fraction), body x",
                  ambiguity=amb, exact=exact,
                  retuned=lambda new, vt_new: _choice(ctx, sel, coord, fitted, n, f_std,
                                                      vt, ambiguous, amb, exact, new,
                                                      vt_new))
