"""Segment vibration of the top run: lug-marker y on the top run += mode(xi) sin(2 pi f t +
phi), mode(xi) = sum_k (a_k, b_k) sin(k pi xi), the frequency free (MODEL.md §5)."""

from __future__ import annotations

import math

import numpy as np

from ._base import Choice, Family, best_size, names
from ._solve import best_of_seeds, distinct, peak_frequency

MAX_MODES = 3
ORDINAL = {1: "first", 2: "second", 3: "third"}


class SegmentVibration(Family):
    """The top run (the free span between the wheels) vibrating in its string modes."""

    name = "segment vibration"

    @classmethod
    def applies(cls, part):
        return part.get("segment") == "top" and part.get("axis") == "y"

    @classmethod
    def fit(cls, ctx, proj, parts):
        sel = (ctx.role == 0) & (ctx.axis == 1) & (ctx.segment == 2) & ctx.valid
        if sel.sum() < 40:
            return None
        t = ctx.t
        T = float(np.ptp(t[sel]))
        fps = 1.0 / float(np.median(np.diff(np.unique(t))))
        # seeds: the located parts' lines and the strongest line of the top run's own y
        # residuals (a part's line can be another one: on a 200 fps recording of a 28.3 Hz
        # flap the parts said 33.8 and 30.2 Hz, the top run's periodogram 28.3)
        seeds = [p["frequency_hz"] for p in parts if cls.applies(p) and p.get("frequency_hz")]
        seeds.append(peak_frequency(t[sel], proj_resid(ctx, sel), fps / 2, T))
        seeds = distinct(seeds, 0.03)
        if not seeds:
            return None

        def cols(f, n=1):
            return _cols(ctx, f, n)

        f = best_of_seeds(proj, cols, seeds, 0.03, T)
        found = best_size(proj, [(n, cols(f, n), 1) for n in range(1, MAX_MODES + 1)])
        if found is None:
            return None
        n, fitted = found
        f_std = _frequency_std(proj, lambda g: cols(g, n), f, T)
        xs = np.linspace(0.0, 1.0, 41)

        def amplitude(x, c):  # peak displacement along the run, mm
            s = np.sin(np.outer(np.arange(1, n + 1), np.pi * np.asarray(x)))  # (n, len)
            return np.hypot(c[0::2] @ s, c[1::2] @ s)

        def describe(c):
            amp_mid = float(amplitude(np.array([0.5]), c)[0])
            pw = np.hypot(c[0::2], c[1::2])
            mode = int(np.argmax(pw)) + 1
            params = {"frequency_hz": f, "frequency_std_hz": f_std, "modes": n,
                      "amplitude_mid_span_mm": amp_mid,
                      "amplitude_peak_mm": float(np.max(amplitude(xs, c))),
                      "mode_amplitudes_mm": pw.tolist(),
                      "phase_rad": float(math.atan2(c[1], c[0]))}
            text = (f"the top run vibrates at {f:.1f} Hz, {amp_mid:.2g} mm at mid-span, in "
                    f"its {ORDINAL.get(mode, str(mode) + 'th')} mode: the slack belt flaps")
            return params, text

        return Choice(cls.name, "xi", fitted, names(ctx, sel), "y", "top", f, amplitude, xs,
                      "mm", "0 rear wheel, 1 front wheel", describe,
                      label=f"{n} mode(s) at {f:.2f} Hz", rows=sel,
                      row_coord=np.mod(f * t, 1.0),
                      row_coord_name=f"phase of the {f:.3g} Hz cycle (fraction)",
                      ambiguity=("a recording at another belt tension or speed would tell a "
                                 "free vibration of the span (its frequency set by the "
                                 "tension) from one the drive forces (its frequency follows "
                                 "the speed)"),
                      columns=lambda c: _cols(c, f, n))


def _cols(ctx, f, n):
    """Columns of n standing modes sin(k pi xi) of the top run's y at frequency f."""
    sel = (ctx.role == 0) & (ctx.axis == 1) & (ctx.segment == 2) & ctx.valid
    xi = np.where(sel, np.nan_to_num(ctx.xi), 0.0)
    out = []
    for k in range(1, n + 1):
        m = np.where(sel, ctx.w * np.sin(k * np.pi * xi), 0.0)
        out += [m * np.sin(2 * np.pi * f * ctx.t), m * np.cos(2 * np.pi * f * ctx.t)]
    return np.stack(out, 1)


def proj_resid(ctx, sel) -> np.ndarray:
    """The residuals of rows `sel` (the periodogram's series)."""
    return ctx.r[sel]


def _frequency_std(proj, columns, f, T) -> float:
    """Standard error of a fitted frequency from the curvature of the chi^2 it removes."""
    h = 0.05 / T
    g0, gp, gm = (proj.gain(columns(f + d)) for d in (0.0, h, -h))
    curv = -(gp - 2 * g0 + gm) / h ** 2  # d^2 chi^2 / df^2
    return float(math.sqrt(2.0 / curv)) if curv > 0 else float("nan")
