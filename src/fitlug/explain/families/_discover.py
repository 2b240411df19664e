"""After the catalog, the families: fit the family terms a located mismatch points at and
keep those that earn their place by the catalog's criterion (MODEL.md §5).

Only the families whose place matches a located part are tried (:meth:`Family.applies`);
each is fitted at its best size (:mod:`._solve`), the best one kept when its Delta BIC is
below the catalog's threshold (and it removes 30 % of a strong misfit's excess, and moves
a marker by more than a tracker can), then a second one on what is left when the first
does not bring chi^2/dof to MODELLED_CHI2."""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field

import jax.numpy as jnp
import numpy as np

from ... import _progress
from ..._errors import FitlugError
from ...fit._glitches import MAX_RUN, threshold
from .._detect import detect
from .._locate import locate
from .._criterion import BIC_THRESHOLD, MIN_SHARE_REMOVED, MODELLED_CHI2, STRONG_MISFIT_Z
from ._body import BodyMotion
from ._context import context
from ._exact import base_residuals, refine
from ._extend import extended
from ._ground import GroundProfile
from ._image import ImageMap
from ._path import PathShape
from ._relin import relinearised
from .._correlated import implausible, inflation, peak_displacement_um
from ._solve import Projector, chooses
from ._slip import SlipLaw
from ._speed import SpeedModulation
from ._surge import BodySurge
from ._time import TimeMap
from ._vibration import SegmentVibration

FAMILIES = (SpeedModulation, SlipLaw, PathShape, BodyMotion, GroundProfile, SegmentVibration,
            ImageMap, TimeMap, BodySurge)  #: MODEL.md §5's in order, then §2's body surge
MAX_TERMS = 2
#: at most this share of the samples may be set aside as glitches after the terms
GLITCH_SHARE = 5e-3


@dataclass
class Term:
    """One kept family term, as fit.json's `discrepancy.discovered` reports it."""

    choice: object
    c: np.ndarray
    cov: np.ndarray
    delta_bic: float
    delta_chi2: float
    chi2_per_dof_before: float
    chi2_per_dof_after: float
    partial: bool = False
    residuals: dict | None = None  # Choice.binned: before/after at the term's rows

    def to_json(self) -> dict:
        ch = self.choice
        params, reading = ch.describe(self.c)
        if ch.ambiguity:
            reading += "; " + ch.ambiguity
        return {"family": ch.family, "coordinate": ch.coordinate, "markers": ch.markers,
                "axis": ch.axis, "segment": ch.segment, "frequency_hz": ch.frequency_hz,
                "shape": ch.shape(self.c, self.cov), "params": params,
                "n_parameters": int(ch.fitted.k), "form": ch.label,
                "delta_chi2": self.delta_chi2, "delta_bic": self.delta_bic,
                "chi2_per_dof_before": self.chi2_per_dof_before,
                "chi2_per_dof_after": self.chi2_per_dof_after,
                "partial": self.partial, "reading": reading + ".",
                "residuals": self.residuals}


@dataclass
class Discovery:
    """What the families found: the kept terms, the extended fit and what was tried."""

    terms: list
    final: object | None  # the extended FitResult (None without terms)
    tried: list = field(default_factory=list)
    why_not: str | None = None  # why no family was tried at all
    seconds: float = 0.0
    glitches: list = field(default_factory=list)  # samples set aside after the terms

    @property
    def modelled(self) -> bool:
        return bool(self.terms) and self.final.chi2_per_dof <= MODELLED_CHI2


def discover(res, parts: list, det, J=None) -> Discovery:
    """Fit the families the located `parts` point at, on top of FitResult `res`.

    Args:
        res: the fit after the catalog (its model, at its least-squares minimum).
        parts: DATA.md's `located` parts of its residuals.
        det: its :class:`fitlug.explain.Detection` (for the strong-misfit rule).
        J: its dense weighted Jacobian (computed when None).

    Returns:
        A :class:`Discovery`; its `terms` are empty when no family earns its place.
    """
    fams = [F for F in FAMILIES if any(F.applies(p) for p in parts)]
    if not fams:
        return Discovery([], None, why_not="no located part is at a family's place")
    if J is None:
        from ...fit._rowchunks import RowChunks
        from .._engine import jacobian_of

        fixed = {k: v for k, v in res.params.items() if k not in res.packing.names}
        J = jacobian_of(res.flat, fixed, res.packing, res.problem.lay, res.problem.obs)
        if isinstance(J, RowChunks):
            return Discovery([], None, why_not="a long recording (chunked Jacobian): "
                                               "families are not tried")
    ctx = context(res, J)
    proj = proj0 = Projector(ctx.J, ctx.r, ctx.valid)
    chi2, dof = float(ctx.r[ctx.valid] @ ctx.r[ctx.valid]), int(res.dof)
    excess = chi2 - dof
    strong = excess > STRONG_MISFIT_Z * det.chi2_spread * dof
    kept, tried = [], []
    B_all, k_all = np.zeros((len(ctx.r), 0)), 0
    r_cur, chi2_cur, dof_cur = ctx.r, chi2, dof
    early = None  # (final, joint) of an exact first term solved already
    for _ in range(MAX_TERMS):
        best = None
        passed = []
        for F in fams:
            if any(t.choice.family == F.name for t in kept):
                continue
            _progress.note("explaining", f"family terms: trying {F.name} (term {len(kept) + 1}, "
                           f"{len(tried) + 1} tried), {len(fams)} families apply")
            ch = F.fit(ctx, proj, parts)
            if ch is None:
                tried.append({"family": F.name, "rejected_because": (
                    "nothing to fit at its place (no samples there, or none that show it)")})
                continue
            moved = proj.moved(ch.fitted.B, ch.fitted.c)  # the tracker's error left (i. 42)
            c_corr = inflation(ctx.marker * 4 + ctx.role * 2 + ctx.axis, ctx.t,
                               r_cur + moved, ctx.valid, change=moved)
            peak_um = peak_displacement_um(moved, ctx.w, ctx.valid)  # a tracker can make it?
            why = chooses(ch.fitted, excess, strong, c_corr) or implausible(ch, res, peak_um)
            tried.append({"family": F.name, "coordinate": ch.coordinate, "form": ch.label,
                          "delta_bic": ch.fitted.delta_bic, "delta_chi2": ch.fitted.dchi2,
                          "correlation_inflation": c_corr, "peak_displacement_um": peak_um,
                          "rejected_because": why})
            if why is None:
                passed.append(ch)
            if why is None and (best is None or ch.fitted.delta_bic < best.fitted.delta_bic):
                best = ch
        if best is None:
            break
        close = [ch for ch in passed if ch is not best
                 and ch.fitted.delta_bic - best.fitted.delta_bic < -BIC_THRESHOLD]
        if close:  # the criterion cannot tell them apart: say so (issue 28, point 3)
            alt = "; ".join(f"a {ch.family} in {ch.coordinate}" for ch in close)
            best.ambiguity = "; ".join(q for q in (
                best.ambiguity, f"this recording reads almost as well as {alt} "
                                f"(delta BIC within {-BIC_THRESHOLD:g})") if q)
        f = best.fitted
        r_new = r_cur + proj.moved(f.B, f.c)
        chi2_new = chi2_cur - f.dchi2
        dof_new = dof_cur - f.k
        kept.append(Term(best, f.c, f.cov, f.delta_bic, f.dchi2, chi2_cur / dof_cur,
                         chi2_new / dof_new))
        B_all = np.hstack([B_all, f.B])
        k_all += f.k
        proj = proj.with_columns(f.B, r_new)
        r_cur, chi2_cur, dof_cur = r_new, chi2_new, dof_new
        excess = chi2_cur - dof_cur
        strong = excess > STRONG_MISFIT_Z * det.chi2_spread * dof_cur
        if chi2_cur / dof_cur <= MODELLED_CHI2:
            break
        if len(kept) == 1 and best.exact is not None and best.extra.get("exact_first"):
            # an exact term far from linear (the wheels' radii: the top run's tilt and the
            # arcs' lengths at second order) is refitted before a second term is sought:
            # its linear prediction (chi2/dof 38) drew a bogus second term where the exact
            # refit alone reaches the noise
            solved = _solve_terms(res, ctx, proj0, kept, B_all, k_all, _slip_h(kept), False,
                                  chi2_cur + 3.0 * math.sqrt(2.0 * dof))
            chi2_x = float(np.sum(np.asarray(solved[0].residuals)[ctx.valid] ** 2))
            if chi2_x / dof_cur <= MODELLED_CHI2:
                early = solved
                kept[0].chi2_per_dof_after = chi2_x / dof_cur
                chi2_cur = chi2_x
                break
    if not kept:
        return Discovery([], None, tried)
    # a term counted by its rank (an image or time map) is solved with its near-gauge
    # directions left out in the joint fit too
    rank = any(t.choice.extra.get("rank") for t in kept)
    slip_h = _slip_h(kept)
    held = 1.5 * chi2_cur + 10.0 * math.sqrt(2.0 * dof)
    if early is not None:
        final, joint = early
    else:
        final, joint = _solve_terms(res, ctx, proj0, kept, B_all, k_all, slip_h, rank,
                                    chi2_cur + 3.0 * math.sqrt(2.0 * dof))
    if not final.chi2 < held:
        # the exact model did not hold the linear prediction: no term is reported
        return Discovery([], None, tried, why_not=(
            f"the extended model's chi2/dof {final.chi2 / final.dof:.3g} did not hold its "
            f"linear prediction {chi2_cur / dof_cur:.3g}"))
    i = 0
    for t in kept:  # the slip law's form, for whoever draws the model's slip (the report)
        m = t.choice.fitted.B.shape[1]
        law = t.choice.extra.get("slip_law")
        if law and (final.robust or {}).get("slip_term") is not None:
            final.robust["slip_term"]["law"] = {**law, "coefficients":
                                                [float(q) for q in joint.c[i:i + m]]}
        i += m
    far = _far(final, ctx)
    if far.size:
        # samples far off the extended model alone: glitches the base fit's finder could
        # not see under the misfit, which pulled the fit (two 0.7 mm glitches under a
        # 15 Hz speed modulation: the slip 5 sigma off); the terms solved again without them
        drop = np.zeros(len(ctx.r), bool)
        for i in far:  # both rows (x and y) of the sample
            drop |= (ctx.marker == ctx.marker[i]) & (ctx.t == ctx.t[i]) & \
                (ctx.role == ctx.role[i])
        proj_g = Projector(ctx.J, ctx.r, ctx.valid & ~drop)
        kept_rows = ctx.valid & ~drop
        before = float(np.sum(np.asarray(final.residuals)[kept_rows] ** 2))
        again, joint_g = _solve_terms(res, ctx, proj_g, kept, B_all, k_all, slip_h, rank,
                                      before, drop)
        if float(np.sum(np.asarray(again.residuals)[kept_rows] ** 2)) < before:
            final, joint = again, joint_g
    final, glitches = _glitches(final, ctx)
    i = 0
    vt_final = _belt_speed(final) if any(t.choice.retuned for t in kept) else None
    for j, t in enumerate(kept):  # each term's coefficients from the joint fit
        m = t.choice.fitted.B.shape[1]
        t.c, t.cov = joint.c[i:i + m], joint.cov[i:i + m, i:i + m]
        if t.choice.retuned is not None:  # its refitted frequency, under the final fit
            t.choice = t.choice.retuned(joint.free.get(j, np.zeros(0)), vt_final)
        if t.choice.extra.get("at_final"):  # read with the final fit's geometry
            t.choice = t.choice.extra["at_final"](final)
        i += m
    kept[-1].chi2_per_dof_after = float(final.chi2_per_dof)
    for t in kept:
        t.residuals = t.choice.binned(ctx.r, np.asarray(final.residuals), ctx.w)
    partial = final.chi2_per_dof > MODELLED_CHI2
    for t in kept:
        t.partial = partial
    return Discovery(kept, final, tried, glitches=glitches)


def _slip_h(kept) -> np.ndarray:
    """d headline slip / d coefficient over the kept terms' columns."""
    return np.concatenate([t.choice.extra.get("slip_headline",
                                               np.zeros(t.choice.fitted.B.shape[1]))
                           for t in kept])


def _solve_terms(res, ctx, proj, kept, B_all, k_all, slip_h, rank, bar, drop=None):
    """The kept terms (columns B_all) fitted jointly with the fit on `proj`'s rows: the
    linear solution, refitted in an exact form where a term has one, relinearised where a
    term's place moves with the fit, and refitted with the fit's own exact model when the
    extended chi^2 (on `proj`'s rows) is not below `bar`. Returns (final FitResult, joint
    Fitted). `drop`: rows left out (glitches), kept out of the relinearised steps too."""
    joint = proj.fit(B_all, 0, rank=rank)
    flat = r_ex = None
    i = 0
    for j, t in enumerate(kept):  # a term with an exact (nonlinear) form is refitted in it
        m = t.choice.fitted.B.shape[1]
        if t.choice.exact is not None:
            done = t.choice.extra.get("refined")
            if done is not None and len(kept) == 1 and drop is None:  # refitted already
                flat, c, r_ex, free, jac = done
            else:
                flat, c, r_ex, free, jac = refine(proj, ctx, B_all, joint.c, t.choice.exact,
                                                  np.arange(i, i + m))
            final, joint = _exact_fit(res, ctx, proj, jac, c, free, k_all, flat, r_ex,
                                      slip_h, rank)
            if free.size:
                joint.free = {j: free}
            break
        i += m
    else:
        final = extended(res, ctx, proj, B_all, joint.c, joint.cov, k_all, flat, r_ex, slip_h)
    if flat is None and any(t.choice.columns is not None for t in kept):
        # a term whose place moves with the fit (segment, u, ground x): Gauss-Newton with
        # its columns rebuilt where the fit has moved
        final, relin = relinearised(res, kept, B_all, final, k_all, slip_h, rank, drop)
        if relin is not None:
            joint = relin

    def chi2(f):
        return float(np.sum(np.asarray(f.residuals)[proj.valid] ** 2))

    if not chi2(final) < bar and flat is None:
        # the linear step moved the fit's weakly held parameters where its Jacobian no
        # longer holds (a time map's lugs: chi2/dof 2.4 for a predicted 1.0; a keystone's
        # warp 1.36 for a predicted 1.3): the terms, linear in their coefficients, refitted
        # with the fit's own exact model
        flat, c, r_ex, free, jac = refine(proj, ctx, B_all, joint.c, base_residuals(res),
                                          np.arange(0))
        again, joint_x = _exact_fit(res, ctx, proj, jac, c, free, k_all, flat, r_ex,
                                    slip_h, rank)
        if chi2(again) < chi2(final):
            final, joint = again, joint_x
    return final, joint


def _exact_fit(res, ctx, proj, jac, c, free, k_all, flat, r_ex, slip_h, rank):
    """The extended fit at an exact refit's solution (:func:`._exact.refine`: parameters
    `flat`, coefficients `c`, the term's own `free`, residuals `r_ex`), its covariance from
    the extended model's Jacobian `jac` there, not the base fit's: where a term acts at
    second order its coefficients and the fit's parameters are correlated at the solution
    though not at the base fit (a cogging's mean belt rate and the slip). Returns (FitResult,
    Fitted of the coefficients)."""
    J, B = jac
    proj_x = Projector(J, r_ex, proj.valid)
    at = proj_x.fit(B, 0, rank=rank)
    n_c = len(c)
    h = np.r_[slip_h, np.zeros(len(free))]
    final = extended(res, ctx, proj_x, B, np.r_[c, free], at.cov, k_all, flat, r_ex, h)
    joint = dataclasses.replace(at, B=B[:, :n_c], c=np.asarray(c, float),
                                cov=at.cov[:n_c, :n_c])
    return final, joint


def _belt_speed(fit) -> float:
    """The largest belt speed |d psi / dt| of `fit`'s model on its grid, mm/s."""
    from ...model._host import integrate_host

    p = {k: jnp.asarray(v, float) for k, v in fit.params.items()}
    return float(np.max(np.abs(np.asarray(integrate_host(p, fit.problem.lay)[3]))))


def _far(final, ctx) -> np.ndarray:
    """Rows far off the extended model (the Bonferroni bound of :func:`_glitches`) whose
    samples are glitches: isolated in their marker's time (runs of at most the base
    finder's MAX_RUN frames) and few (at most GLITCH_SHARE of the samples); empty
    otherwise. Counted in samples, not rows: a glitch moves x and y (five glitches in a
    cogging of 2.2 %, drawn at 0.2 % of the samples, were ten rows, over a bound of five
    rows, and held chi^2/dof at 5.9)."""
    r = np.asarray(final.residuals, float)
    n = int(ctx.valid.sum())
    far = np.flatnonzero(ctx.valid & (np.abs(r) > threshold(n)))
    if far.size == 0:
        return far
    # a sample: (role, marker, frame), ordered by its track (role, marker), then frame
    span = int(ctx.frame.max()) + 1
    key = (ctx.role[far].astype(np.int64) * (int(ctx.marker.max()) + 1)
           + ctx.marker[far]) * span + ctx.frame[far]
    samples, inverse = np.unique(key, return_inverse=True)
    n_samples = int(np.count_nonzero(ctx.valid & (ctx.axis == 0)))
    if len(samples) > max(5, GLITCH_SHARE * n_samples):
        return far[:0]
    track, frame = samples // span, samples % span
    # runs of consecutive frames of one marker: longer than MAX_RUN is misfit, not glitches
    new_run = np.r_[True, (np.diff(track) != 0) | (np.diff(frame) != 1)]
    run = np.cumsum(new_run) - 1
    length = np.bincount(run)
    isolated = length[run] <= MAX_RUN
    return far[isolated[inverse]]


def _glitches(final, ctx):
    """Samples the extended model leaves far off alone: a tracker glitch the base fit's
    finder (fitlug.fit._glitches) could not see under the misfit (its local level follows a
    steep misfit, a bump's flank). The same Bonferroni bound, c = sqrt(2 ln(N / 0.01)),
    on the extended model's residuals; only when they are few (at most GLITCH_SHARE of
    the samples, else they are misfit, not glitches). Their residuals are set to zero and
    the dof lowered; they are listed (Discovery.glitches)."""
    far = _far(final, ctx)
    if far.size == 0:
        return final, []
    r = np.asarray(final.residuals, float).copy()
    listed = [{"marker": ctx.markers[ctx.marker[i]], "t_s": float(ctx.t[i]),
               "axis": "xy"[ctx.axis[i]], "residual_sigma": float(r[i])} for i in far]
    r[far] = 0.0
    return dataclasses.replace(final, residuals=r, chi2=float(r @ r),
                               dof=int(final.dof - far.size)), listed


def after_catalog(res, geo, parts, det, sig_est, alpha):
    """The families after the catalog, on fit `res` whose located `parts` the catalog left.

    Returns ("modelled" | "partial", the extended fit, its detection, its location, the
    :class:`Discovery`), the middle three None without a kept term. 'modelled' when the
    extended model brings chi^2/dof to MODELLED_CHI2 or passes detection (`det`, `geo`,
    `sig_est`, `alpha`: fitlug.explain's detection of `res` and its settings)."""
    t0 = time.perf_counter()
    try:
        disc = discover(res, parts, det)
    except (FitlugError, np.linalg.LinAlgError, ValueError, IndexError,
            FloatingPointError) as err:  # a family's failure never sinks explain
        return ("partial", None, None, None,
                Discovery([], None, why_not=f"the families' fit failed: {err}"))
    if not disc.terms:
        return ("partial", None, None, None, disc)
    final = disc.final
    det_f = detect(geo, final.residuals, final.dof, sigma_estimated=sig_est, alpha=alpha)
    loc_f = locate(geo, final.residuals, det_f)
    disc.seconds = time.perf_counter() - t0
    before = disc.terms[0].chi2_per_dof_before
    share = (before - final.chi2_per_dof) / (before - 1.0) if before > 1.0 else 1.0
    # chi^2/dof under MODELLED_CHI2 counts only for terms that removed a fair share of the
    # excess (issue 42: a body motion took a tracker's drift from just above 1.3 to 1.299)
    ok = (final.chi2_per_dof <= MODELLED_CHI2 and share >= MIN_SHARE_REMOVED) \
        or det_f.consistent
    if not ok and share < MIN_SHARE_REMOVED:
        # a partial reading that leaves most of the misfit is no reading (issue 42: a
        # speed modulation fitted into a tracker's drift)
        disc.tried.append({"family": ", ".join(t.choice.family for t in disc.terms),
                           "rejected_because": (
                               f"partial: removes {100 * share:.0f} % of the excess chi2 "
                               f"(a partial reading needs {100 * MIN_SHARE_REMOVED:.0f} %)")})
        disc.terms = []
        disc.final = None
        return ("partial", None, None, None, disc)
    for t in disc.terms:
        t.partial = not ok
    return ("modelled" if ok else "partial", final, det_f, loc_f, disc)

