"""A tracker's correlated error: how much a slow misfit can be the tracker's (issue 42).

A sub-pixel tracker's error is not white. Besides the read noise it carries a bias periodic
in the marker's image position (pixel locking, ~0.005-0.01 px: a marker at rest keeps its
bias, so a lug on the ground is offset by a different amount at each contact) and a slow
drift per marker (lighting, focus: a few um over a second). The fit's noise comes from 4th
differences, which see only the white part; chi^2 then reads the correlated part as misfit,
and a smooth term (a ground dip, a warp, a sag) removes far more chi^2 than its k
parameters would from white noise: Delta chi^2 ~ c chi^2_k with c the residuals'
low-frequency variance over their total variance.

:func:`inflation` estimates c from residuals by batch means: per series (one marker, one
axis) the samples are cut into blocks of BLOCKS_S seconds; c = sum over blocks of (block
sum)^2 over sum of r^2, pooled over the series (1 for white residuals, up to the samples
per block for a constant offset per block), less twice its spread under white residuals,
the largest over the block lengths (at least 1). It is
measured on the residuals of the model *with* the candidate term: an effect the term models
leaves white residuals (c ~ 1, the criterion unchanged: the detection power kept), a term
fitted into the tracker's correlated error leaves it correlated, and its Delta chi^2 is
deflated by c before the criterion (:func:`effective_delta_bic`): evidence the tracker can
make is not evidence for physics.

:func:`describe` reports the correlated part of the base fit's residuals per role: c and
the equivalent correlated amplitude (um) beside the white noise.
"""

from __future__ import annotations

import numpy as np

BLOCKS_S = (0.25, 0.5, 1.0)
#: c at or below which the residuals count as white (the estimate's own scatter: ~0.1)
WHITE_C = 1.0


def inflation(series: np.ndarray, t: np.ndarray, r: np.ndarray, valid: np.ndarray,
              blocks_s=BLOCKS_S, change: np.ndarray | None = None) -> float:
    """c >= 1: the residuals' batch-means variance ratio (see the module), largest over
    `blocks_s`; 1 when there are too few blocks to tell.

    Per series s, c_s = sum over its blocks of (block sum)^2 over its sum of r^2; c is
    their average weighted by `change`'s energy per series (a candidate's change of the
    residuals: its Delta chi^2 is inflated by the correlation of the series it draws
    from: a term fitted into two body markers' drift by theirs, not by the lugs'), by
    r^2 without it (the pooled ratio). Less twice its spread under white residuals."""
    ok = valid & np.isfinite(r)
    if change is not None:
        ok &= np.isfinite(change)
    if ok.sum() < 20:
        return 1.0
    s, tt, rr = np.asarray(series)[ok], np.asarray(t)[ok], np.asarray(r, float)[ok]
    _, inv = np.unique(s, return_inverse=True)
    n_s = int(inv.max()) + 1
    r2 = np.bincount(inv, rr * rr, n_s)
    wt = r2 if change is None else np.bincount(inv, np.asarray(change, float)[ok] ** 2, n_s)
    if not wt.sum() > 0:
        return 1.0
    wt = np.where(r2 > 0, wt, 0.0) / wt.sum()
    t0 = np.full(n_s, np.inf)
    np.minimum.at(t0, inv, tt)
    best = 1.0
    for b in blocks_s:
        blk = np.floor((tt - t0[inv]) / b).astype(np.int64)
        key = inv.astype(np.int64) * (int(blk.max()) + 1) + blk
        ukey, kinv = np.unique(key, return_inverse=True)
        nb = len(ukey)
        if nb < 20:  # too few blocks for a variance
            continue
        sums = np.bincount(kinv, rr)
        ser = ukey // (int(blk.max()) + 1)  # the series of each block
        c_s = np.bincount(ser, sums * sums, n_s) / np.where(r2 > 0, r2, 1.0)
        nb_s = np.maximum(np.bincount(ser, minlength=n_s), 1)
        # less twice the estimate's spread under white residuals (per series relative
        # sqrt(2 / blocks)): white residuals give c = 1 but for a few per cent
        spread = float(np.sqrt(np.sum(wt * wt * 2.0 / nb_s)))
        best = max(best, float(wt @ c_s) - 2.0 * spread)
    return best


def inflation_geo(geo, r, change=None) -> float:
    """:func:`inflation` of residuals laid out as fitlug.explain.Geometry `geo`."""
    return inflation(geo.series, geo.t, np.asarray(r, float), geo.valid, change=change)


def effective_delta_bic(dchi2_removed: float, k: float, lnN: float, c: float) -> float:
    """Delta BIC with the chi^2 removed deflated by the correlated error's c."""
    return -dchi2_removed / max(c, 1.0) + k * lnN


def catalog_minus_family_bic(geo, final, alt, lnN: float) -> tuple[float, float]:
    """(BIC of the catalog's fit `final` - BIC of the families' fit `alt`, c): the chi^2
    the family removes beyond the entries deflated by the residuals' correlation c with it
    in, as every candidate's (issue 42: an 18-parameter image map took a tracked
    recording's lens_distortion by a BIC 111 lower, fitting the tracker's correlated
    error; deflated, the lens stands). Positive: the family's fit is the better one."""
    dchi2 = float(final.chi2) - float(alt.chi2)
    c = 1.0
    if dchi2 > 0:
        try:
            c = max(1.0, inflation_geo(geo, alt.residuals, np.asarray(alt.residuals)
                                       - np.asarray(final.residuals)))
        except Exception:  # noqa: BLE001 - residuals laid out apart: the raw criterion
            c = 1.0
    # effective_delta_bic of the family over the entries, with its extra parameters
    return -effective_delta_bic(dchi2, final.dof - alt.dof, lnN, c), c


def describe(geo, r) -> dict:
    """The correlated part of residuals `r` (weighted, Geometry `geo`) per role: c, the
    white noise (um, the fit's) and the correlated amplitude that gives that c over
    blocks of 0.5 s (um; a constant offset per block of n samples: c = (1 + n q)/(1 + q),
    q the correlated over the white variance)."""
    out = {}
    r = np.asarray(r, float)
    for role, name in ((0, "lug"), (1, "body")):
        sel = geo.valid & (geo.role == role)
        if sel.sum() < 20:
            continue
        c = inflation(geo.series, geo.t, r, sel, (0.5,))
        white = 1000.0 / float(np.median(geo.weight[sel]))
        n = max(0.5 * geo.fps, 2.0)
        q = max(c - 1.0, 0.0) / max(n - c, 1.0)
        out[name] = {"inflation": c, "white_um": white,
                     "correlated_um": white * float(np.sqrt(q))}
    return out


#: the largest systematic error a sub-pixel tracker makes at one place: pixel locking up to
#: LOCK_PX px plus a drift of DRIFT_UM (issue 42: 0.004-0.012 px, 1-3 um)
LOCK_PX = 0.012
DRIFT_UM = 3.0
MM_PER_PX_DEFAULT = 0.45  # the coarsest image scale of the cameras


def tracker_level_um(rec) -> float:
    """The tracker's systematic level (um) for recording `rec`: LOCK_PX at its image scale
    (from its x_px column, else MM_PER_PX_DEFAULT) plus DRIFT_UM. A feature no larger than
    this, the tracker can make."""
    scale = MM_PER_PX_DEFAULT
    if getattr(rec, "x_px", None) is not None:
        ok = np.isfinite(rec.x_px) & np.isfinite(rec.x)
        if ok.sum() > 10 and np.ptp(rec.x_px[ok]) > 0:
            s = float(abs(np.polyfit(rec.x_px[ok], rec.x[ok], 1)[0]))
            if np.isfinite(s) and s > 0:
                scale = s
    return 1000.0 * LOCK_PX * scale + DRIFT_UM


def peak_displacement_um(moved, w, valid) -> float:
    """The largest displacement (um) a term makes on any marker: its change of the
    weighted residuals `moved` (r = w (model - obs)) over the weights `w`."""
    ok = np.asarray(valid, bool)
    return 1000.0 * float(np.max(np.abs(moved[ok] / w[ok]))) if np.any(ok) else 0.0


def implausible(choice, res, peak_um: float | None = None) -> str | None:
    """Why a family term's reading is not physics the rig can have (issue 42), or None:
    any term whose largest displacement of a marker (`peak_um`, what it moves the
    residuals by, in um) is no larger than the tracker's systematic level (a body motion
    of 4 um made of the body markers' own drifts: a tracked null was 'modelled' by it,
    its slip 4 sigma off); a ground profile whose peak is no larger than that level, or
    narrower than the grid it is read on (a spike of the spline, 'over 0 mm')."""
    level = tracker_level_um(res.problem.rec)
    if peak_um is not None and np.isfinite(peak_um) and peak_um <= level:
        return (f"the largest displacement it makes on a marker, {peak_um:.3g} um, is no "
                f"larger than the tracker's systematic level {level:.3g} um (pixel locking "
                f"and drift): the tracker can make it")
    if choice.family != "ground profile":
        return None
    params, _ = choice.describe(choice.fitted.c)
    peak = 1000.0 * abs(float(params["peak_mm"]))
    if peak <= level:
        return (f"its peak {peak:.3g} um is no larger than the tracker's systematic level "
                f"{level:.3g} um (pixel locking and drift): the tracker can make it")
    if not float(params["half_height_width_mm"]) > 0:
        return "its peak is narrower than the grid it is read on: a spike of the spline"
    return None
