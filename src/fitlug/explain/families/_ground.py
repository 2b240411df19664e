"""Ground profile: the bottom run's lugs follow a profile y_g(x) of the ground, fixed in
the ground frame (a bump, a dip, a step), a cubic B-spline in ground position x whose knot
spacing the criterion picks (MODEL.md §5). Variant: the body rides on it too, resting on
the two wheels (y_body += mean of y_g under the wheels + c_x times their slope).

A lab floor's features are often sharp (a board's edge, a mat's): from the best equal
spacing, knots are added one at a time where the misfit left is largest, each kept only
when it lowers the BIC (:func:`_refined`): a 0.7 mm mat edge rounded over 0.5 mm needed 64
equal intervals and left chi^2/dof 7.7 to a second family; a board 0.5 mm high, 143 mm
wide, stayed `unexplained` at 1.6)."""

from __future__ import annotations

import numpy as np

from .._criterion import BIC_THRESHOLD, GROSS_CHI2, MIN_SHARE_REMOVED
from ._base import Choice, Family, best_size, bspline_on, names
from ._ride import ride_residuals

INTERVALS = (2, 4, 8, 16, 32, 64)
MIN_SPACING_MM = 4.0
MAX_ADDED = 24  # knots added where the ground changes fast
MIN_ADDED_SPACING_MM = 0.25
CANDIDATES = 3  # the intervals of most misfit tried for each added knot
#: knots are not added where the misfit is gross (chi^2/dof above GROSS_CHI2) and the
#: equal spacing's term removes less than MIN_SHARE_REMOVED / REACH of the excess: the share
#: rule rejects the term, and the added knots raised its gain 1.15-1.35-fold on the
#: engine's recordings (24 knots, ~4 s each time)
REACH = 3.0
#: where the profile acts (:func:`_cols`); "lugs" first: a profile the lugs do not show is
#: not the ground's
MODES = ("lugs", "shared", "separate", "frame", "frame_own")


class GroundProfile(Family):
    """y_g(x) under the bottom run (and, variant, under the wheels carrying the body)."""

    name = "ground profile"

    @classmethod
    def applies(cls, part):
        return part.get("axis") == "y" and part.get("segment") in ("bottom", "body")

    @classmethod
    def fit(cls, ctx, proj, parts):
        lug = (ctx.role == 0) & (ctx.axis == 1) & (ctx.segment == 0) & ctx.valid
        body = (ctx.role == 1) & (ctx.axis == 1) & ctx.valid
        if lug.sum() < 40:
            return None
        lo, hi = np.percentile(ctx.x_ground[lug], [0.5, 99.5])
        seen = (float(lo), float(hi))  # where the lugs show the ground
        front = ctx.X + ctx.x_off + ctx.D / 2  # the wheels' centres over the ground
        rear = ctx.X + ctx.x_off - ctx.D / 2
        if body.any():  # the profile spans where the wheels go too
            lo = min(lo, float(np.min(rear[body])))
            hi = max(hi, float(np.max(front[body])))

        def cols(n_int, mode):
            return _cols(ctx, np.linspace(lo, hi, n_int + 1), mode)

        sizes = [n for n in INTERVALS if (hi - lo) / n >= MIN_SPACING_MM]
        best = None
        # the lugs on the profile; the wheels (and the frame) on it too; or the wheels on
        # a profile of their own (a wheel rolling over a bump rides the bump's envelope
        # under its rim, wider and flatter than the bump itself)
        for mode in MODES:
            found = best_size(proj, [(n, cols(n, mode), 0) for n in sizes])
            if mode == "lugs" and (found is None or found[1].delta_bic > BIC_THRESHOLD):
                # the ground is where the bottom run's lugs are: a profile they do not
                # show is not the ground's (the body riding something that is not
                # straight under it is body motion in X, :mod:`._body`)
                return None
            if found and (best is None or found[1].delta_bic < best[2].delta_bic):
                best = (mode, *found)
        if best is None:
            return None
        mode, n_int, fitted = best
        breaks = np.linspace(lo, hi, n_int + 1)
        chi2, dof = float(proj.r @ proj.r), max(proj.n - proj.Js.shape[1], 1)
        share = MIN_SHARE_REMOVED * (chi2 - dof)  # what the share rule asks
        if not (chi2 > GROSS_CHI2 * dof and REACH * fitted.dchi2 < share):
            breaks, fitted = _refined(ctx, proj, breaks, mode, fitted)
        added = len(breaks) - n_int - 1
        with_body = mode != "lugs"
        nb = len(breaks) + 2
        # read where the ground was seen: the wheels roll over all of it where they ride
        # the same profile; the marked lugs touch it at a few places each pass, and between
        # them nothing holds a profile of the lugs alone (one read a 2.7 m 'dip' in a gap)
        full = np.unique(np.r_[np.linspace(lo, hi, 121), breaks])
        xs = full if mode in ("shared", "frame") else \
            _seen(ctx.x_ground[lug], np.unique(np.r_[np.linspace(*seen, 481), breaks]))
        # the profile's level and tilt are the fit's (y_off, the offsets): shown and read
        # relative to the floor, its robust straight line (Theil-Sen over the range; the
        # line through its two ends put a 0.70 mm board at 0.90 mm: an end where few lugs
        # were held the spline 0.2 mm off)
        grid = xs
        Bg = bspline_on(grid, breaks)

        def profile(x, c):
            from scipy.stats import theilslopes

            slope, icpt = theilslopes(Bg @ c[:nb], grid)[:2]
            return bspline_on(x, breaks) @ c[:nb] - (icpt + slope * np.asarray(x))

        def describe(c):
            y = profile(xs, c)
            k = int(np.argmax(np.abs(y)))
            h = float(y[k])
            above = np.abs(y) >= 0.5 * abs(h)
            # the contiguous run of half height round the peak
            i0 = k
            while i0 > 0 and above[i0 - 1]:
                i0 -= 1
            i1 = k
            while i1 < len(xs) - 1 and above[i1 + 1]:
                i1 += 1
            width = float(xs[i1] - xs[i0])
            params = {"peak_mm": h, "at_x_mm": float(xs[k]), "half_height_width_mm": width,
                      "intervals": n_int, "knot_spacing_mm": float((hi - lo) / n_int),
                      "knots_added": added,
                      "finest_spacing_mm": float(np.min(np.diff(breaks))),
                      "body_follows": mode,
                      "x_range_mm": [float(lo), float(hi)]}
            if mode in ("separate", "frame_own"):  # read where the wheels went
                from scipy.stats import theilslopes

                wg = np.linspace(lo, hi, 241)
                wl = bspline_on(wg, breaks) @ c[nb:]
                slope, icpt = theilslopes(wl, wg)[:2]
                wl = wl - (icpt + slope * wg)
                k = int(np.argmax(np.abs(wl)))
                params["wheel_lift_peak_mm"] = float(wl[k])
                params["wheel_lift_at_x_mm"] = float(wg[k])
                if mode == "frame_own" and (abs(wl[k]) > abs(h) or width < (hi - lo) / n_int):
                    # the lugs did not touch the bump (it lies between their places, and
                    # their profile is held only at those): the wheels' lift is what was
                    # seen of it
                    h = float(wl[k])
                    params.update(peak_mm=h, at_x_mm=float(wg[k]), half_height_width_mm=(
                        float(np.ptp(wg[np.abs(wl) >= 0.5 * abs(h)]))))
            kind = "a bump" if h > 0 else "a dip"
            text = (f"the ground {'rises' if h > 0 else 'falls'} {abs(h):.2g} mm at x = "
                    f"{params['at_x_mm']:.0f} mm over {params['half_height_width_mm']:.0f} mm "
                    f"under the bottom run{RIDE[mode]}: {kind} in the ground")
            return params, text

        sel = lug | (body if with_body else np.zeros_like(lug))
        return Choice(cls.name, "x", fitted, names(ctx, sel), "y", "bottom", None, profile,
                      xs, "mm", "mm (ground frame)", describe,
                      label=f"B-spline, {n_int} intervals"
                      + (f" + {added} knots where the ground changes fast" if added else "")
                      + {"lugs": "", "shared": ", body on the wheels",
                         "separate": ", the wheels' lift its own",
                         "frame": ", the frame heaving and pitching on the wheels",
                         "frame_own": ", the frame heaving and pitching on the wheels' lift"
                         }[mode],
                      rows=lug, row_coord=ctx.x_ground,
                      row_coord_name="ground x of the bottom-run lugs (mm)",
                      ambiguity=("a recording driving over the same place again (or in "
                                 "the other direction) would tell a feature of the ground "
                                 "from one of the belt"),
                      columns=lambda c: _cols(c, breaks, mode),
                      exact=ride_residuals(ctx, breaks, mode) if mode in ("frame", "frame_own")
                      else None, extra={"exact_first": mode in ("frame", "frame_own")})


#: a point of the profile is read where a lug sample lies this close (mm)
SEEN_MM = 2.0


def _seen(x_obs, grid) -> np.ndarray:
    """The points of `grid` within SEEN_MM of a lug sample's ground x (all of `grid` where
    fewer than 20 are)."""
    x_obs = np.sort(np.asarray(x_obs, float))
    i = np.clip(np.searchsorted(x_obs, grid), 1, len(x_obs) - 1)
    near = np.minimum(np.abs(grid - x_obs[i - 1]), np.abs(grid - x_obs[i])) <= SEEN_MM
    return grid[near] if near.sum() >= 20 else grid


def _refined(ctx, proj, breaks, mode, fitted):
    """Knots added one at a time in the interval (of the CANDIDATES with the most misfit
    left: lug samples by their ground x, body samples by their wheels') whose midpoint lowers
    the BIC most, while one does. Returns (breaks, Fitted)."""
    lug = (ctx.role == 0) & (ctx.axis == 1) & (ctx.segment == 0) & ctx.valid
    body = (ctx.role == 1) & (ctx.axis == 1) & ctx.valid & (mode != "lugs")
    front = ctx.X + ctx.x_off + ctx.D / 2
    where = [(lug, ctx.x_ground), (body, front), (body, front - ctx.D)]
    for _ in range(MAX_ADDED):
        r = ctx.r + proj.moved(fitted.B, fitted.c)
        excess = np.zeros(len(breaks) - 1)
        for sel, x in where:
            k = np.clip(np.searchsorted(breaks, x[sel]) - 1, 0, len(breaks) - 2)
            excess += np.bincount(k, weights=r[sel] ** 2 - 1.0, minlength=len(excess))
        wide = np.diff(breaks) >= 2 * MIN_ADDED_SPACING_MM
        order = [i for i in np.argsort(-excess) if wide[i] and excess[i] > 0][:CANDIDATES]
        best = None
        for i in order:
            b = np.insert(breaks, i + 1, 0.5 * (breaks[i] + breaks[i + 1]))
            f = proj.fit(_cols(ctx, b, mode), 0)
            if f.delta_bic < fitted.delta_bic and (best is None or
                                                   f.delta_bic < best[1].delta_bic):
                best = (b, f)
        if best is None:
            break
        breaks, fitted = best
    return breaks, fitted


RIDE = {"lugs": "", "shared": " and the wheels ride over it, lifting the body",
        "separate": " and the wheels ride over it, lifting the body",
        "frame": " and the wheels ride over it: the frame heaves and pitches on them",
        "frame_own": " and the wheels ride over it: the frame heaves and pitches on them"}


def _frame_cols(ctx, breaks):
    """Columns of the wheels' lift profile moving the frame rigidly: heave (l_f + l_r)/2 and
    pitch (l_f - l_r)/D, l the lift under the front and rear wheels, about the middle of
    the bottom run's pitch line; every point fixed to the frame (the body markers, the lug
    markers off the bottom run) moves in x by -pitch * its height and in y by heave +
    pitch * its x (the frame's pitch moves a body marker 70 mm up by 0.7 mm in x for a
    1 mm bump under one wheel)."""
    on = ctx.valid & ((ctx.role == 1) | (ctx.segment != 0))
    B = np.zeros((len(ctx.r), len(breaks) + 2))
    mid = ctx.X[on] + ctx.x_off
    gf = bspline_on(mid + ctx.D / 2, breaks)
    gr = bspline_on(mid - ctx.D / 2, breaks)
    qx = (ctx.qx[on] - mid)[:, None]
    qy = (ctx.qy[on] - float(ctx.res.params["y_off"]))[:, None]
    pitch = (gf - gr) / ctx.D
    y = (ctx.axis[on] == 1)[:, None]
    B[on] = ctx.w[on, None] * np.where(y, 0.5 * (gf + gr) + qx * pitch, -qy * pitch)
    return B


def _cols(ctx, breaks, mode):
    """Columns of the profile (cubic B-spline on `breaks` of ground x) at the bottom-run
    lugs' y, and with `mode` "shared" / "separate" at the body's y too; "frame" /
    "frame_own": the frame (body and lugs off the ground) heaving and pitching rigidly on
    the wheels riding the same profile / a lift profile of their own (:func:`_frame_cols`)."""
    lug = (ctx.role == 0) & (ctx.axis == 1) & (ctx.segment == 0) & ctx.valid
    body = (ctx.role == 1) & (ctx.axis == 1) & ctx.valid
    nb = len(breaks) + 2
    B = np.zeros((len(ctx.r), nb * (2 if mode in ("separate", "frame_own") else 1)))
    B[lug, :nb] = ctx.w[lug, None] * bspline_on(ctx.x_ground[lug], breaks)
    if mode in ("frame", "frame_own"):  # the lugs on the ground, the frame on the wheels
        B[:, nb * (mode == "frame_own"):] += _frame_cols(ctx, breaks)
        return B
    if mode != "lugs" and body.any():
        front = ctx.X[body] + ctx.x_off + ctx.D / 2  # the wheels' centres over the ground
        rear = front - ctx.D
        gf = bspline_on(front, breaks)
        gr = bspline_on(rear, breaks)
        # the frame rests on the two wheels: a marker at x = X + c_x sits on the
        # line through them, (c_x - x_off + D/2) / D of the way from the rear one
        q = ((ctx.cx[body] - ctx.x_off + ctx.D / 2) / ctx.D)[:, None]
        B[body, nb * (mode == "separate"):] = ctx.w[body, None] * (gr + q * (gf - gr))
    return B
