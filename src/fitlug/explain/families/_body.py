"""Body motion: body-marker y += A(.) + B(.) c_x (heave and pitch) in acceleration a (the
suspension squats under acceleration and dives under braking), in belt travel psi with a
free period (a wheel, a sprocket or a lug pattern lifting the frame once per turn), in
time t at a free frequency (the frame vibrates) or in the ground position X (B-splines:
the body rides a guide rail or carriage track that is not straight); the coordinate with
the lower Delta BIC is kept (MODEL.md §5). body_bounce is the catalog's case at the lug
pitch."""

from __future__ import annotations

import numpy as np

from ._base import Choice, Family, best_size, bspline, names
from ._solve import best_of_seeds, distinct, peak_frequency
from ._vibration import _frequency_std

MAX_POWER = 3
MAX_HARMONICS = 3
#: least cycles of a periodic body motion in view: in time (t), in belt travel (psi)
MIN_CYCLES_T = 3
MIN_CYCLES_PSI = 1.5
X_INTERVALS = (1, 2, 4, 8, 16)
X_MIN_SPACING_MM = 20.0


class BodyMotion(Family):
    """A(a) = sum_k A_k (a/a_s)^k, B(a) likewise (pitch, two or more body markers)."""

    name = "body motion"

    @classmethod
    def applies(cls, part):
        return part.get("segment") == "body" and part.get("axis") == "y"

    @classmethod
    def fit(cls, ctx, proj, parts):
        found = [c for c in (cls.fit_a(ctx, proj), cls.fit_periodic(ctx, proj, parts),
                             cls.fit_periodic(ctx, proj, parts, "t"), cls.fit_x(ctx, proj))
                 if c]
        return min(found, key=lambda c: c.fitted.delta_bic) if found else None

    @classmethod
    def fit_periodic(cls, ctx, proj, parts, coord="psi"):
        """Heave and pitch periodic in belt travel (or, coord 't', in time: a frame that
        vibrates at a fixed frequency), the period free (seeded by the located frequency
        at cruise)."""
        sel = (ctx.role == 1) & (ctx.axis == 1) & ctx.valid
        if sel.sum() < 20:
            return None
        T = float(np.ptp(ctx.t[sel]))
        fps = 1.0 / float(np.median(np.diff(np.unique(ctx.t))))
        vt = float(np.max(np.abs(ctx.vt_nodes)))
        # belt travel in s at cruise, or time
        u = np.interp(ctx.t, ctx.grid, ctx.psi_nodes) / vt if coord == "psi" else ctx.t
        # seeds: the located parts' lines and the strongest line of the body's y residuals
        # in this coordinate (a part's line can be another one)
        seeds = [p["frequency_hz"] for p in parts if cls.applies(p) and p.get("frequency_hz")]
        seeds.append(peak_frequency(u[sel], ctx.r[sel], fps / 2, T))
        # cycles seen: over the time in view, or (psi) over the belt travel in view; a
        # robot at rest in view adds time but no belt travel (a rail's bow of 1 m, seen
        # over 0.5 m of travel, read as "periodic in psi, 979 mm")
        span = T if coord == "t" else float(np.ptp(u[sel]))
        least = MIN_CYCLES_T if coord == "t" else MIN_CYCLES_PSI
        seeds = distinct([f for f in seeds if f * span >= least], 0.03)
        if not seeds:
            return None
        pitch = ctx.n_body >= 2 and np.ptp(ctx.cx[sel]) > 1.0

        def cols(f, n=1):
            out = []
            for k in range(1, n + 1):
                for g in (np.sin(2 * np.pi * k * f * u), np.cos(2 * np.pi * k * f * u)):
                    g = np.where(sel, ctx.w * g, 0.0)
                    out += [g, g * ctx.cx] if pitch else [g]
            return np.stack(out, 1)

        f = best_of_seeds(proj, cols, seeds, 0.06, T)
        if f * span < least:
            return None
        found = best_size(proj, [(n, cols(f, n), 1) for n in range(1, MAX_HARMONICS + 1)])
        if found is None:
            return None
        n, fitted = found
        f_std = _frequency_std(proj, lambda g: cols(g, n), f, T)
        per = 2 if pitch else 1
        cmid = float(np.mean(np.unique(ctx.cx[sel]))) if pitch else 0.0
        period = vt / f if coord == "psi" else 1.0 / f  # mm of belt travel, or s
        xs = np.linspace(0.0, period, 61)

        def series(x, c, j):  # j = 0: heave at c_x = 0, 1: pitch (rad)
            ph = 2 * np.pi * np.outer(np.asarray(x), np.arange(1, n + 1)) / period
            cs = np.asarray(c)[j::per]  # per harmonic: sin, cos
            return np.sin(ph) @ cs[0::2] + np.cos(ph) @ cs[1::2]

        def heave(x, c):  # body y at the markers' centre over one period of belt travel
            return series(x, c, 0) + (cmid * series(x, c, 1) if pitch else 0.0)

        def describe(c):
            grid = np.linspace(0, period, 241)
            amp = 0.5 * float(np.ptp(heave(grid, c)))
            params = {"frequency_hz": f, "frequency_std_hz": f_std,
                      "harmonics": n, "heave_amplitude_mm": amp,
                      "at_body_x_offset_mm": cmid,
                      "coefficients": [float(v) for v in c]}
            if coord == "psi":
                params["period_mm"] = period
                text = (f"body y heaves {amp:.2g} mm once per {period:.3g} mm of belt "
                        f"travel ({f:.2f} Hz at cruise)")
            else:
                text = f"body y heaves {amp:.2g} mm at {f:.2f} Hz, a fixed frequency in time"
            if pitch:
                pa = 0.5 * float(np.ptp(series(grid, c, 1)))
                params["pitch_amplitude_rad"] = pa
                text += f" and pitches {pa:.2g} rad"
            wheel = 2 * np.pi * ctx.R
            if coord == "t":
                text += (": the frame vibrates (a motor, a gearbox or the rig's own "
                         "resonance)")
            elif abs(period / wheel - 1) < 0.03:
                text += ": once per wheel turn, an eccentric wheel or idler lifts the frame"
            elif abs(period / ctx.pitch - 1) < 0.03:
                text += ": once per lug, the lugs lift the frame as they pass the wheels"
            else:
                text += (f": something turning with the belt ({period / wheel:.3g} times per "
                         "wheel turn) lifts the frame")
            return params, text

        unit = "mm of belt travel" if coord == "psi" else "s"
        return Choice(cls.name, coord, fitted, names(ctx, sel), "y", "body", f, heave, xs,
                      "mm", unit, describe,
                      label=f"{n} harmonic(s) in {coord}, period {period:.3g} "
                            f"{'mm' if coord == 'psi' else 's'}", rows=sel,
                      row_coord=np.mod(f * u, 1.0),
                      row_coord_name=(f"phase of the {period:.3g} {unit.split()[0]} cycle "
                                      "(fraction)"),
                      ambiguity=("a recording at another speed would tell a motion locked "
                                 "to the belt from one at a fixed frequency in time"))

    @classmethod
    def fit_a(cls, ctx, proj):
        """Heave and pitch as powers of the acceleration."""
        sel = (ctx.role == 1) & (ctx.axis == 1) & ctx.valid
        if sel.sum() < 20:
            return None
        a_s = float(np.max(np.abs(ctx.a[sel]))) or 1.0
        z = np.where(sel, ctx.a / a_s, 0.0)
        pitch = ctx.n_body >= 2 and np.ptp(ctx.cx[sel]) > 1.0

        def cols(n):
            out = []
            for k in range(1, n + 1):
                g = np.where(sel, ctx.w * z ** k, 0.0)
                out.append(g)
                if pitch:
                    out.append(g * ctx.cx)
            return np.stack(out, 1)

        found = best_size(proj, [(n, cols(n), 0) for n in range(1, MAX_POWER + 1)])
        if found is None:
            return None
        n, fitted = found
        per = 2 if pitch else 1
        a_lo, a_hi = float(np.min(ctx.a[sel])), float(np.max(ctx.a[sel]))
        xs = np.linspace(a_lo, a_hi, 61) / 1000.0  # m/s^2
        # read at the body markers' centre (the reference point c_x = 0 is arbitrary)
        cmid = float(np.mean(np.unique(ctx.cx[sel]))) if pitch else 0.0

        def heave(x, c):  # body y at the markers' centre, mm
            zz = np.asarray(x) * 1000.0 / a_s
            return sum((c[per * k] + (c[per * k + 1] * cmid if pitch else 0.0))
                       * zz ** (k + 1) for k in range(n))

        def describe(c):
            A1 = (c[0] + (c[1] * cmid if pitch else 0.0)) * 1000.0 / a_s  # mm per m/s^2
            params = {"powers": n, "a_scale_m_s2": a_s / 1000.0,
                      "heave_mm_per_m_s2": A1, "at_body_x_offset_mm": cmid,
                      "coefficients": [float(v) for v in c]}
            text = (f"body y {'dips' if A1 < 0 else 'rises'} {abs(A1):.3g} mm per m/s² "
                    "of acceleration")
            if pitch:
                B1 = c[1] * 1000.0 / a_s  # rad per m/s^2
                params["pitch_rad_per_m_s2"] = B1
                text += f" and pitches {abs(B1):.2g} rad per m/s²"
            text += (": the suspension squats under acceleration (and dives under braking)"
                     if A1 < 0 else ": the body lifts as the robot accelerates")
            return params, text

        return Choice(cls.name, "a", fitted, names(ctx, sel), "y", "body", None, heave, xs,
                      "mm", "m/s^2", describe, label=f"{n} power(s) of a", rows=sel,
                      row_coord=ctx.a / 1000.0, row_coord_name="acceleration a (m/s²)")

    @classmethod
    def fit_x(cls, ctx, proj):
        """Heave and pitch as B-splines in the body's ground position X."""
        sel = (ctx.role == 1) & (ctx.axis == 1) & ctx.valid
        if sel.sum() < 20:
            return None
        lo, hi = float(np.min(ctx.X[sel])), float(np.max(ctx.X[sel]))
        sizes = [n for n in X_INTERVALS if (hi - lo) / n >= X_MIN_SPACING_MM]
        if not sizes:
            return None
        pitch = bool(ctx.n_body >= 2 and np.ptp(ctx.cx[sel]) > 1.0)
        found = best_size(proj, [(n, _x_cols(ctx, lo, hi, n, pitch), 0) for n in sizes])
        if found is None:
            return None
        n, fitted = found
        per = 2 if pitch else 1
        cmid = float(np.mean(np.unique(ctx.cx[sel]))) if pitch else 0.0
        xs = np.linspace(lo, hi, 121)

        def line(x, c, j):  # j = 0: heave at c_x = 0, 1: pitch (rad)
            return bspline(x, lo, hi, n) @ np.asarray(c)[j::per]

        def centre(x, c):  # heave at the markers' centre
            return line(x, c, 0) + (cmid * line(x, c, 1) if pitch else 0.0)

        def heave(x, c):
            # relative to the straight line through its ends (a level and a tilt of the
            # body's path are the base model's and the camera's)
            x = np.asarray(x, float)
            e = centre(np.array([lo, hi]), c)
            return centre(x, c) - (e[0] + (e[1] - e[0]) * (x - lo) / (hi - lo))

        def describe(c):
            y = heave(xs, c)
            k = int(np.argmax(np.abs(y)))
            h = float(y[k])
            params = {"peak_mm": h, "at_X_mm": float(xs[k]), "intervals": n,
                      "knot_spacing_mm": (hi - lo) / n, "X_range_mm": [lo, hi],
                      "at_body_x_offset_mm": cmid, "coefficients": [float(v) for v in c]}
            text = (f"body y {'rises' if h > 0 else 'falls'} {abs(h):.2g} mm at X = "
                    f"{xs[k]:.0f} mm of the body's travel, fixed to its position over the "
                    "ground")
            if pitch:
                pr = line(xs, c, 1)
                pa = 0.5 * float(np.ptp(pr))
                params["pitch_range_rad"] = pa
                text += f" and pitches {pa:.2g} rad"
            text += (": the body rides something that is not straight under it (a guide "
                     "rail or a carriage track that bows, the rig's floor under the frame)")
            return params, text

        return Choice(cls.name, "X", fitted, names(ctx, sel), "y", "body", None, heave, xs,
                      "mm", "mm (body position over the ground)", describe,
                      label=f"B-spline in X, {n} interval(s)", rows=sel, row_coord=ctx.X,
                      row_coord_name="body position over the ground X (mm)",
                      ambiguity=("a recording over the same stretch at another speed (or "
                                 "in the other direction) would tell a motion fixed to the "
                                 "ground position from one in acceleration or time"),
                      columns=lambda c: _x_cols(c, lo, hi, n, pitch))


def _x_cols(ctx, lo, hi, n, pitch):
    """Columns of the body's heave (and pitch, times c_x) as B-splines of n intervals in
    the ground position X on [lo, hi]."""
    sel = (ctx.role == 1) & (ctx.axis == 1) & ctx.valid
    G = ctx.w[sel, None] * bspline(ctx.X[sel], lo, hi, n)
    B = np.zeros((len(ctx.r), G.shape[1] * (2 if pitch else 1)))
    if pitch:
        B[sel, 0::2] = G
        B[sel, 1::2] = G * ctx.cx[sel, None]
    else:
        B[sel] = G
    return B
