"""Time map: the frames' true times are their stamps plus tau (MODEL.md §5; frame_drop is
its catalog case). Every marker of a frame then sits where the model puts it tau later:
its weighted residual moves by tau (v dr/dX + v_t dr/dpsi). A smooth tau(t) is the speed
profile's own freedom (X(t) absorbs it), so what a recording can show is a tau that
changes from frame to frame:

- every other frame late (an interlaced or double-buffered recorder): one parameter;
- a periodic tau at a free frequency, 1-3 harmonics (a clock that wobbles: told from a
  speed modulation in time by the slip, which answers a modulated speed and not a clock);
- a free tau per frame (a camera stamped by a host's clock that jitters): one per frame,
  counted by the directions the data see (frames with the robot at rest see none), shown
  and read less its smooth trend (the part of it the speed profile could hold).
"""

from __future__ import annotations

import math

import numpy as np

from ._base import Choice, Everywhere, best_size, names
from ._solve import best_of_seeds, distinct, peak_frequency

#: the per-frame form's columns are dense: at most this many cells (S x frames)
MAX_CELLS = 6e7


class TimeMap(Everywhere):
    """tau per frame: alternating, periodic, or free."""

    name = "time map"

    @classmethod
    def fit(cls, ctx, proj, parts):
        if not cls.enough(ctx):
            return None
        sel = ctx.valid
        v = np.interp(ctx.t, ctx.grid, ctx.v_nodes)
        vt = np.interp(ctx.t, ctx.grid, ctx.vt_nodes)
        d = np.where(sel, ctx.dr_dX * v + ctx.dr_dpsi * vt, 0.0)  # d r / d tau, per s
        k = ctx.frame  # 0, 1, 2 ... in time (the sorted stamps' index)
        nf = int(k.max()) + 1
        ts = np.zeros(nf)
        ts[k] = ctx.t  # the stamps, in order
        fps = 1.0 / float(np.median(np.diff(ts)))
        # the frame number from the stamp (a stamp's parity, robust to missing frames)
        num = np.round((ctx.t - ts[0]) * fps).astype(int)
        builds = [("alternate", (d * (num % 2))[:, None] * 1e-3, 0)]  # tau in ms
        # a frame sees its tau only through the markers' motion: frames where they barely
        # move (the robot at rest) get no column (their tau is not seen, not fitted)
        strength = np.bincount(k, weights=d * d, minlength=nf)
        live = strength > 1e-2 * np.median(strength[strength > 0]) if np.any(strength > 0) \
            else np.zeros(nf, bool)
        col = np.cumsum(live) - 1
        n_live = int(live.sum())
        G = None
        if n_live and len(ctx.r) * n_live <= MAX_CELLS:
            B = np.zeros((len(ctx.r), n_live))
            on = live[k]
            B[np.flatnonzero(on), col[k[on]]] = d[on] * 1e-3
            # less the slow taus, which are the fit's own X(t) (v tau in X's spline):
            # left in, their near-degenerate directions only spread the slip's error
            G = _slow_basis(ts[live], np.interp(ts[live], ctx.grid, ctx.v_nodes),
                            np.asarray(ctx.res.problem.lay.breaks, float))
            B -= (B @ G) @ np.linalg.pinv(G)
            builds.append(("free", B, 0))
        # a periodic tau at a free frequency (a clock that wobbles): to the data nearly a
        # speed modulation in time, but the robot's own motion is untouched (no slip
        # answering a modulated acceleration), which is how the criterion tells them apart
        T = float(np.ptp(ctx.t[sel]))
        body = sel & (ctx.segment == 4) & (ctx.axis == 0)
        seeds = [p["frequency_hz"] for p in parts if p.get("frequency_hz")]
        if body.sum() > 20:
            seeds.append(peak_frequency(ctx.t[body], ctx.r[body], fps / 2, T))
        seeds = distinct([f for f in seeds if f > 2.0 / T], 0.06)

        def periodic(f, n=1):
            ph = 2 * np.pi * f * np.outer(ctx.t, np.arange(1, n + 1))
            return d[:, None] * np.concatenate([np.sin(ph), np.cos(ph)], 1) * 1e-3

        f_per = None
        if seeds:
            f_per = best_of_seeds(proj, periodic, seeds, 0.06, T)
            builds += [(f"periodic{n}", periodic(f_per, n), 1) for n in (1, 2, 3)]
        found = best_size(proj, builds, rank=True)
        if found is None:
            return None
        form, fitted = found
        n_harm = int(form[-1]) if form.startswith("periodic") else 0
        detrend = _detrender(G, np.diag(fitted.cov)) if form == "free" else None

        def tau(x, c):  # ms at stamp times x (for the periodic form: cycle fraction x)
            x = np.asarray(x, float)
            if n_harm:
                ph = 2 * np.pi * np.outer(x, np.arange(1, n_harm + 1))
                return np.sin(ph) @ c[:n_harm] + np.cos(ph) @ c[n_harm:]
            if form == "alternate":
                return c[0] * (np.round((x - ts[0]) * fps).astype(int) % 2)
            j = np.clip(np.searchsorted(ts, x), 0, nf - 1)
            full = np.full(nf, np.nan)
            full[live] = detrend(np.asarray(c, float))
            return full[j]

        seen = np.diag(fitted.cov) > 0

        def describe(c):
            if n_harm:
                amp = float(np.max(np.abs(tau(np.linspace(0, 1, 61), c))))
                params = {"form": "periodic", "frequency_hz": f_per, "harmonics": n_harm,
                          "amplitude_ms": amp, "coefficients_ms": [float(q) for q in c]}
                text = (f"the frames' true times swing by {amp:.2g} ms about their stamps "
                        f"at {f_per:.2f} Hz, every marker displaced along its own motion "
                        f"and the robot's motion untouched: the camera's clock wobbles")
                return params, text
            if form == "alternate":
                params = {"form": form, "late_ms": float(c[0]),
                          "late_std_ms": float(math.sqrt(max(fitted.cov[0, 0], 0.0)))}
                text = (f"every other frame is {'late' if c[0] > 0 else 'early'} by "
                        f"{abs(c[0]):.2g} ms against its stamp: an interlaced or "
                        f"double-buffered recorder")
                return params, text
            # the frames that see their offset well (error within twice the median: not
            # those where the markers barely move), their scatter, and the same less what
            # each offset's own error adds
            var = np.diag(fitted.cov)
            err = np.sqrt(np.where(seen, var, np.inf))
            good = seen & (err <= 2.0 * np.median(err[seen])) if seen.any() else seen
            cs = detrend(np.asarray(c, float))[good]
            rms = float(np.sqrt(np.mean((cs - np.mean(cs)) ** 2))) if cs.size else 0.0
            sd = math.sqrt(max(rms ** 2 - float(np.mean(var[good])), 0.0)) if cs.size else 0.0
            params = {"form": form, "rms_ms": rms, "sd_ms": sd, "frames_seen": int(seen.sum()),
                      "frames_well_seen": int(good.sum()),
                      "max_abs_ms": float(np.max(np.abs(cs))) if cs.size else 0.0}
            text = (f"the frames' true times scatter by {rms:.2g} ms about their stamps "
                    f"(rms of the fitted offsets over the {int(good.sum())} frames that see "
                    f"them best): the camera's clock or a host's time stamps jitter")
            return params, text

        xs = (np.linspace(0.0, 1.0, 61) if n_harm else
              ts[live] if form == "free" else ts[:min(nf, 200)])
        return Choice(cls.name, "t", fitted, names(ctx, sel), None, None,
                      f_per if n_harm else None, tau, xs,
                      "ms", "cycle fraction" if n_harm else "s (frame stamp)", describe,
                      label=(f"{n_harm} harmonic(s) at {f_per:.2f} Hz" if n_harm else
                             "every other frame late" if form == "alternate" else
                             f"a free offset per frame ({nf} frames)"),
                      rows=sel & (ctx.axis == 0),
                      row_coord=np.mod(f_per * ctx.t, 1.0) if n_harm else ctx.t,
                      row_coord_name=(f"phase of the {f_per:.3g} Hz cycle (fraction), x rows"
                                      if n_harm else "time stamp (s), x rows"),
                      extra={"rank": True},
                      ambiguity=("a recording with the frame times from the camera's own "
                                 "clock (or a strobe in view) would tell a clock's error "
                                 "from the motion's" + (
                                     ", and one that accelerates harder would tell it from a "
                                     "speed modulation in time (the slip answers a modulated "
                                     "speed, not a clock)" if n_harm else "")))


def _slow_basis(ts, v, breaks):
    """(frames, m) the taus that X(t) takes up: X's spline (degree 4 on the speed
    spline's breaks) over v, at the frames `ts` (their speed v)."""
    from scipy.interpolate import BSpline

    lo, hi = float(ts[0]), float(ts[-1])
    br = np.unique(np.clip(np.r_[lo, breaks, hi], lo, hi))
    knots = np.r_[[lo] * 4, br, [hi] * 4]
    S = BSpline.design_matrix(np.clip(ts, lo, hi), knots, 4).toarray()
    S = S[:, np.any(S != 0, 0)]
    G = S / np.where(np.abs(v) > 1e-9, v, 1e-9)[:, None]
    return G / np.linalg.norm(G, axis=0)


def _detrender(G, var):
    """c -> c less what the fit's own X(t) could hold: v c fitted by X's spline, i.e. c by
    the slow taus G (:func:`_slow_basis`), weighted by 1 / var; the rest is the clock's."""
    w = 1.0 / np.sqrt(np.maximum(var, 1e-300))
    w = w / np.max(w)
    Gw = G * w[:, None]

    def detrend(c):
        return c - G @ np.linalg.lstsq(Gw, c * w, rcond=None)[0]
    return detrend
