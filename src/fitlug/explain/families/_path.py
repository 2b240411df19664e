"""Path shape: the lug markers' path relative to the body departs from the stadium on one
part of it, a static shape of the place along that part (MODEL.md §5; belt_sag and
ground_sinkage are its catalog cases):

- a straight run, path_y += delta(xi), xi from 0 to 1 along the run (the top run from the
  rear wheel to the front, the bottom run from its start under the front wheel to the
  rear one), a cubic B-spline whose knot spacing the criterion picks;
- the arcs, the marker's distance from the wheel's centre += delta(phi / pi), each wheel
  its own B-spline in the place along its half-turn (a pitch radius per wheel, the lugs
  splaying as the belt bends round it);
- arc radii per wheel: the front and rear wheels' pitch radii differ (:mod:`._radii`, an
  exact term: the arcs' lengths and the top run's tilt change with them).
"""

from __future__ import annotations

import numpy as np
from ._base import Choice, Family, best_size, bspline, names
from ._radii import radii_choice

RUN_INTERVALS = (1, 2, 4, 8, 16)
ARC_INTERVALS = (0, 1, 2, 4, 8, 16)  # 0: a constant per wheel
PARTS = {"top": 2, "bottom": 0, "rear_arc": 1, "front_arc": 3}


def _design(x, n_int):
    """(len(x), n_int + 3) cubic B-spline basis on [0, 1] (a constant for n_int = 0)."""
    if n_int == 0:
        return np.ones((len(np.asarray(x)), 1))
    return bspline(x, 0.0, 1.0, n_int)


class PathShape(Family):
    """A static departure of the lug markers' path from the stadium on one of its parts."""

    name = "path shape"

    @classmethod
    def applies(cls, part):
        seg = part.get("segment")
        if seg in ("rear_arc", "front_arc"):
            return True
        return seg in ("top", "bottom") and part.get("axis") == "y"

    @classmethod
    def fit(cls, ctx, proj, parts):
        located = {p.get("segment") for p in parts if cls.applies(p)}
        lug = (ctx.role == 0) & ctx.valid
        cands = []
        for run in ("top", "bottom"):
            if run not in located:
                continue
            sel, xi = _run_rows(ctx, run)
            if sel.sum() < 40:
                continue
            found = best_size(proj, [(n, _run_cols(ctx, run, n), 0) for n in RUN_INTERVALS])
            if found:
                cands.append((run, found, xi, sel))
        arcs = [a for a in ("rear_arc", "front_arc") if a in located]
        if arcs:
            for which in {tuple(arcs), ("rear_arc", "front_arc")}:
                sel = lug & np.isin(ctx.segment, [PARTS[a] for a in which])
                if sel.sum() < 40:
                    continue
                found = best_size(proj, [(n, _arc_cols(ctx, which, n), 0)
                                         for n in ARC_INTERVALS])
                if found:
                    cands.append((which, found, None, sel))
        radii = radii_choice(ctx, proj, lug) if lug.sum() >= 40 else None
        if radii is not None:
            cands.append(("radii", (1, radii.fitted), None, lug))
        if not cands:
            return None
        where, (n, fitted), xi, sel = min(cands, key=lambda q: q[1][1].delta_bic)
        if where == "radii":
            return radii
        if isinstance(where, str):
            return _run_choice(ctx, where, n, fitted, xi, sel)
        return _arc_choice(ctx, where, n, fitted, sel)


def _run_rows(ctx, run):
    """The rows of the lugs' y on the straight run `run` and their place xi along it."""
    sel = (ctx.role == 0) & ctx.valid & (ctx.axis == 1) & (ctx.segment == PARTS[run])
    u = np.nan_to_num(ctx.u)
    xi = (u - ctx.D - np.pi * ctx.R) / ctx.D if run == "top" else u / ctx.D
    return sel, xi


def _run_cols(ctx, run, n):
    """Columns of the y offset on the straight run `run`: a spline of n intervals in xi."""
    sel, xi = _run_rows(ctx, run)
    B = np.zeros((len(ctx.r), n + 3))
    B[sel] = ctx.w[sel, None] * _design(xi[sel], n)
    return B


def _arc_cols(ctx, which, n):
    """Columns of the radial offset on the arcs `which`, each its own spline of n
    intervals in phi / pi."""
    D, R = ctx.D, ctx.R
    u = np.nan_to_num(ctx.u)
    nb = 1 if n == 0 else n + 3
    B = np.zeros((len(ctx.r), nb * len(which)))
    for k, arc in enumerate(which):
        seg = PARTS[arc]
        on = (ctx.role == 0) & ctx.valid & (ctx.segment == seg)
        start = D if arc == "rear_arc" else 2 * D + np.pi * R
        phi = np.clip((u - start) / R, 0.0, np.pi)
        sgn = -1.0 if arc == "rear_arc" else 1.0
        radial = np.where(ctx.axis == 0, sgn * np.sin(phi), sgn * np.cos(phi))
        B[on, k * nb:(k + 1) * nb] = (ctx.w * radial)[on, None] * _design(phi[on] / np.pi, n)
    return B


def _run_choice(ctx, run, n, fitted, xi, sel):
    xs = np.linspace(0.0, 1.0, 101)

    def shape(x, c):
        return _design(x, n) @ c

    def describe(c):
        y = shape(xs, c)
        # read relative to the straight line through its ends (the fit's R, e and y_off
        # hold a level; a tilt would be the wheels at different heights)
        line = y[0] + (y[-1] - y[0]) * xs
        d = y - line
        k = int(np.argmax(np.abs(d)))
        h = float(d[k])
        curv = np.abs(np.diff(d, 2))
        kink = float(curv.max() / max(np.median(curv), 1e-12)) if curv.size else 1.0
        params = {"peak_mm": h, "at_xi": float(xs[k]), "ends_mm": [float(y[0]), float(y[-1])],
                  "intervals": n, "segment": run, "kink_ratio": kink}
        up = h > 0
        if run == "top":
            what = ("a support roller or guide lifts the slack top run" if up else
                    "the top run sags or is pressed down")
            lead = (f"the top run is {'lifted' if up else 'lowered'} {abs(h):.2g} mm at "
                    f"xi = {xs[k]:.2f} of its span (a static shape, not a vibration)")
        else:
            what = ("a road wheel presses the belt or the lugs are uneven in height" if not up
                    else "the belt lifts off the ground between the wheels")
            lead = (f"the bottom run {'rises' if up else 'dips'} {abs(h):.2g} mm at "
                    f"xi = {xs[k]:.2f} of its length, fixed to the body")
        return params, f"{lead}: {what}"

    amb = ("a recording at another belt tension would tell a shape held by a support "
           "(it stays) from a sag (it deepens as the tension falls)" if run == "top" else
           "a recording driving over other ground would tell a shape fixed to the body "
           "(it stays) from one of the ground (it moves with the ground)")
    return Choice(PathShape.name, "xi", fitted, names(ctx, sel), "y", run, None, shape, xs,
                  "mm", ("0 rear wheel, 1 front wheel" if run == "top" else
                         "0 front wheel, 1 rear wheel"), describe,
                  label=f"B-spline on the {run} run, {n} interval(s)", rows=sel,
                  row_coord=xi, row_coord_name=f"place along the {run} run, xi",
                  ambiguity=amb, columns=lambda c: _run_cols(c, run, n))


def _arc_choice(ctx, which, n, fitted, sel):
    nb = 1 if n == 0 else n + 3
    m = len(which)
    xs = np.linspace(0.0, float(m), 61 * m)

    def shape(x, c):
        x = np.asarray(x, float)
        out = np.zeros(len(x))
        for k in range(m):
            on = (x >= k) & (x <= k + 1) if k == m - 1 else (x >= k) & (x < k + 1)
            out[on] = _design(x[on] - k, n) @ c[k * nb:(k + 1) * nb]
        return out

    def describe(c):
        y = shape(xs, c)
        mean = {}
        for k, arc in enumerate(which):
            on = (xs >= k) & (xs <= k + 1)
            mean[arc.split("_")[0]] = float(np.mean(y[on]))
        params = {"mean_radial_mm": mean, "peak_mm": float(y[np.argmax(np.abs(y))]),
                  "intervals": n, "arcs": list(which)}
        parts = ", ".join(f"{v:+.2g} mm round the {w} wheel" for w, v in mean.items())
        text = (f"the lug markers ride farther from the wheels' centres than the stadium "
                f"puts them ({parts}): the lugs splay as the belt bends round the wheel, or "
                f"the wheel's pitch radius differs from the runs' line")
        return params, text

    sel_coord = np.full(len(ctx.r), np.nan)
    u = np.nan_to_num(ctx.u)
    for k, arc in enumerate(which):
        start = ctx.D if arc == "rear_arc" else 2 * ctx.D + np.pi * ctx.R
        on = sel & (ctx.segment == PARTS[arc])
        sel_coord[on] = k + np.clip((u[on] - start) / (np.pi * ctx.R), 0, 1)
    unit = ("0-1 rear arc (bottom to top)" + (", 1-2 front arc (top to bottom)"
                                             if m > 1 else "")) if which[0] == "rear_arc" \
        else "0-1 front arc (top to bottom)"
    return Choice(PathShape.name, "xi", fitted, names(ctx, sel), None,
                  "arcs" if m > 1 else which[0], None, shape, xs, "mm (radial)", unit,
                  describe, label=f"radial offset on the {' and '.join(which)}, "
                                  f"{'constant' if n == 0 else f'{n} interval(s)'}",
                  rows=sel, row_coord=np.nan_to_num(sel_coord),
                  row_coord_name="place along the arcs",
                  ambiguity=("a recording of the wheel alone (no belt) would tell a pitch "
                             "radius from lugs that splay"),
                  columns=lambda c: _arc_cols(c, which, n))
