"""Find the physics the base model left out: detect, locate, explain (MODEL.md §3).

Forward selection over the catalog. Each round scores every effect not yet in the model
(one Gauss-Newton step: :mod:`._candidates`), fits the most promising ones fully (same
model, only their parameters freed: :mod:`._engine`) and adds the best one if it earns
its place:

- Delta BIC = Delta chi^2 + Delta k ln N < -10 with the noise per role held at the base
  fit's values (they come from 4th differences, independent of slow misfit, so chi^2 is
  -2 ln L up to a constant for every candidate). -10 is "very strong" evidence on the
  Kass-Raftery scale (Bayes factor ~150); frame_drop's t* counts as a parameter;
- its parameters are the physics it names (a sag sags, a lost frame delays the stamps);
- when the misfit is strong (chi^2 - dof above 10 times its spread from noise alone), it
  removes at least 30 % of that excess: a disturbance outside the catalog can make a
  candidate's Delta BIC hugely negative while leaving most of the misfit in place, and
  that candidate does not explain it.

Rounds stop when the residuals pass detection or nothing more earns its place. With two
or more effects added, each must still earn its place in the final model (backward
check). The final model is polished with its exact Jacobian (:mod:`._final`); its
residuals decide the verdict: consistent -> 'explained', else 'unexplained' with the
located remaining mismatch, and its error bars widened (:mod:`._robust`).
A located misfit that per-marker-per-segment offsets and speed terms carry, below the
tracker-systematics floor and with a negligible effect on the slip, is the tracker's
own structured error (:mod:`._systematics`): reported as `systematics`, and the verdict
follows the effects.
'unexplained' needs a place: residuals that fail a test while no part of them stands
out (no cell of significant structured misfit, no spectral line or series with
p < 1e-4) are a false alarm of the tests (they allow 5 %), and the verdict follows the
effects ('none' without any).
"""

from __future__ import annotations

import math
import sys
import time

import numpy as np

from .. import _progress
from .._errors import FitlugError
from ..model import CATALOG
from . import _display
from ._candidates import in_picture, physical, screen, sliding_starts
from ._correlated import catalog_minus_family_bic, effective_delta_bic, inflation_geo
from ._criterion import BIC_THRESHOLD, LEFT_MISFIT_Z, MIN_SHARE_REMOVED, strong_misfit
from .families import after_catalog
from ._detect import ALPHA, detect
from ._engine import Engine
from ._explanation import BASE_EFFECTS, Explanation, Step, as_base
from ._final import final_fit, polished_theta, withdrawn
from ._locate import locate
from ._robust import nuisance_result, partial_shift, robust_result
from ._sliding_direct import direct_candidate
from ._straight import reads_straight_runs, withheld as _withheld
from ._systematics import tracker_systematics
from ._table import geometry, structured_misfit

MAX_FITS_PER_ROUND = 4
MAX_EFFECTS = 4
SLIDING_GRID_STEPS = 4
#: chi^2/dof that lug_sliding's search fit may leave under a strong misfit before its
#: direct fit from the data's own start is tried (:mod:`._sliding_direct`)
DIRECT_SLIDING_CHI2 = 2.0


def _noise_reached(fits, dof, eng, spread) -> bool:
    """Whether a candidate fitted this round (not rejected) has left no strong misfit: the
    direct lug_sliding fit could then remove nothing the catalog's rules would take."""
    return any(why is None and not strong_misfit(out.chi2, dof - eng.n_free(e), spread)
               for e, (out, _, _, why) in fits.items())


def _bar(progress, total, desc):
    if not progress or not sys.stderr.isatty():
        return None
    from tqdm import tqdm

    return tqdm(total=total, desc=desc, file=sys.stderr, leave=True, unit="effect",
                dynamic_ncols=True)


def explain(res, *, seed: int = 0, progress: bool = False, alpha: float = ALPHA) -> Explanation:
    """Detect, locate and explain the mismatch of a least-squares fit `res`.

    `seed` is accepted for a uniform CLI (the procedure is deterministic). Returns an
    :class:`Explanation`; never raises on a recording that `res` fitted. The base model's
    marker height h and relaxation tau (MODEL.md §2, `lug_shear`) are searched with the
    catalog and, where the data show them, reported as the base model's (`base_steps`),
    not as left-out physics.
    """
    return as_base(_explain(res, seed=seed, progress=progress, alpha=alpha))


def _explain(res, *, seed: int = 0, progress: bool = False, alpha: float = ALPHA) -> Explanation:
    t_start = time.perf_counter()
    timing = {}
    _display.check_result(res)
    geo = geometry(res)
    sig_est = res.problem.noise_source in ("differences", "residual differences")
    det0 = detect(geo, res.residuals, res.dof, sigma_estimated=sig_est, alpha=alpha)
    loc0 = locate(geo, res.residuals, det0)
    timing["detect_locate"] = time.perf_counter() - t_start
    if det0.consistent:
        timing["total"] = time.perf_counter() - t_start
        return Explanation("none", res, res, [], [], detection_before=det0,
                           detection_after=det0, location_before=loc0, timing_s=timing,
                           geometry=geo)

    eng = Engine(res)
    N = res.n_data
    lnN = math.log(N)
    theta = eng.theta0
    r = eng.residuals(theta)[0]
    chi2 = float(r @ r)
    k_cur = res.n_params
    accepted, extra, steps, rounds = [], [], [], []
    bar = _bar(progress, MAX_EFFECTS, "explain")
    det_cur = det0
    for rnd in range(MAX_EFFECTS):
        cands = [e for e in CATALOG if CATALOG[e].searched and e not in res.effects
                 and e not in accepted]
        if not cands:
            break
        t0 = time.perf_counter()
        J = eng.jacobian(theta, extra, r)  # r: the residuals at theta
        scr = screen(eng, theta, r, J, cands, extra, geo)
        lin = {e: -s.dchi2 + eng.n_free(e) * lnN for e, s in scr.items()}
        order = sorted(cands, key=lambda e: lin[e])
        to_fit = [e for e in order if lin[e] < BIC_THRESHOLD][:MAX_FITS_PER_ROUND]
        dof_cur = N - k_cur
        excess = chi2 - dof_cur  # chi^2 the misfit carries (noise scale known to ~2 %)
        strong = strong_misfit(chi2, dof_cur, det_cur.chi2_spread)
        # after an effect, a further one must account for what is left, not nibble at it
        # (issue 42: a 16 us 'frame drop' took 3 % of the 8 spreads a lens left)
        share_rule = strong or (bool(accepted) and
                                excess > LEFT_MISFIT_Z * det_cur.chi2_spread * dof_cur)
        direct = strong and chi2 > DIRECT_SLIDING_CHI2 * dof_cur and "lug_sliding" in cands
        if direct and "lug_sliding" not in to_fit:
            # a base that the sliding law distorts can hide it from the screening's
            # linear step (issue 32): its direct fit below decides
            to_fit.append("lug_sliding")
        if direct:
            # lug_sliding last: its direct fit (seconds: ~2 000 model evaluations) is needed
            # only where no other candidate has taken the misfit down to the noise
            to_fit.sort(key=lambda e: e == "lug_sliding")
        _progress.note("explaining", f"round {rnd + 1}: {len(cands)} candidates screened, "
                       f"{len(to_fit)} to fit")
        M_cur, _ = structured_misfit(geo, r)
        tried = {e: {"id": e, "delta_bic_linear": lin[e], "start": scr[e].label}
                 for e in order}
        fits = {}
        bar_bic = BIC_THRESHOLD  # what a candidate must beat: the threshold, then the best

        def give_up(c2, predicted, k_e):
            # even 3 times the Gauss-Newton prediction cannot beat the bar or (share rule)
            # remove its share of the excess (an engine's lug_sliding: 30 steps for 1 %)
            reach = chi2 - (c2 - 3.0 * predicted)
            return (reach - k_e * lnN < -bar_bic
                    or (share_rule and reach < MIN_SHARE_REMOVED * max(excess, reach)))

        for i_fit, e in enumerate(to_fit):
            _progress.note("explaining", f"round {rnd + 1}: fitting candidate {i_fit + 1}/"
                           f"{len(to_fit)} ({e})")
            t1, k_e = time.perf_counter(), eng.n_free(e)
            stop = lambda c2, pr, k_e=k_e: give_up(c2, pr, k_e)  # noqa: E731
            out = eng.fit(_start(eng, scr[e], chi2, extra + eng.free_names(e), stop),
                          extra + eng.free_names(e), give_up=stop)
            if e == "lug_sliding" and direct and \
                    out.chi2 > DIRECT_SLIDING_CHI2 * (dof_cur - k_e) and \
                    not _noise_reached(fits, dof_cur, eng, det_cur.chi2_spread):
                out = direct_candidate(res, eng, theta, out)
            dbic = out.chi2 - chi2 + eng.n_free(e) * lnN
            M_new, _ = structured_misfit(geo, out.r)
            gain = chi2 - out.chi2
            removed = gain / max(excess, gain) if gain > 0 else 0.0
            # the tracker's correlated error left with the effect in (issue 42)
            c_corr = inflation_geo(geo, out.r, np.asarray(out.r) - np.asarray(r))
            dbic_corr = effective_delta_bic(gain, eng.n_free(e), lnN, c_corr)
            why = physical(e, eng.params(out.theta)) or in_picture(
                e, eng.params(out.theta), res.problem.rec)
            if why is None and dbic >= BIC_THRESHOLD:
                why = f"delta BIC {dbic:.1f} is not below {BIC_THRESHOLD:g}"
            if why is None and dbic_corr >= BIC_THRESHOLD:
                why = (f"delta BIC {dbic_corr:.1f} with the chi2 it removes deflated by the "
                       f"residuals' correlation ({c_corr:.3g}, what a tracker's correlated "
                       f"error makes) is not below {BIC_THRESHOLD:g}")
            if why is None and share_rule and removed < MIN_SHARE_REMOVED:
                why = (f"removes {100 * removed:.0f} % of the excess chi2 (needs "
                       f"{100 * MIN_SHARE_REMOVED:.0f} %)")
            if why is None and not out.converged and dbic > bar_bic:
                why = f"cannot beat delta BIC {bar_bic:.1f} (fit abandoned)"
            fits[e] = (out, dbic, removed, why)
            if why is None:
                bar_bic = min(bar_bic, dbic)
            tried[e].update({"delta_bic": dbic, "correlation_inflation": c_corr,
                             "delta_bic_correlated": dbic_corr,
                             "chi2_per_dof": out.chi2 / (N - k_cur - eng.n_free(e)),
                             "misfit_removed_share": removed,
                             "structured_misfit_removed_share":
                                 (M_cur - M_new) / M_cur if M_cur > 0 else None,
                             "rejected_because": why,
                             "iterations": out.iterations, "time_s": time.perf_counter() - t1,
                             "params": CATALOG[e].report(eng.params(out.theta))})
        rounds.append({"round": rnd + 1, "tried": list(tried.values()),
                       "time_s": time.perf_counter() - t0})
        ok = [e for e in fits if fits[e][3] is None]
        if not ok:
            break
        best = min(ok, key=lambda e: fits[e][1])
        out, dbic, removed, _ = fits[best]
        dof_before = N - k_cur
        k_cur += eng.n_free(best)
        steps.append(Step(best, CATALOG[best].report(eng.params(out.theta)), float(dbic),
                          chi2 / dof_before, out.chi2 / (N - k_cur), float(removed)))
        rounds[-1]["accepted"] = best
        accepted.append(best)
        extra = extra + eng.free_names(best)
        theta, r, chi2 = out.theta, out.r, out.chi2
        if not out.converged:  # the search's fit stopped short: finish it exactly
            try:
                th_p = polished_theta(res, eng, accepted, theta)
            except FitlugError:  # the search's own fit stands
                th_p = theta
            r_p = eng.residuals(th_p)[0]
            if float(r_p @ r_p) < chi2:
                theta, r, chi2 = th_p, r_p, float(r_p @ r_p)
                steps[-1].chi2_per_dof_after = chi2 / (N - k_cur)
        if bar:
            bar.update(1)
        det_cur = detect(geo, r, N - k_cur, sigma_estimated=sig_est, alpha=alpha)
        if det_cur.consistent:
            break
    if bar:
        bar.total = bar.n  # ends at what was done ("2/2"), not at the cap ("1/4")
        bar.refresh()
        bar.close()
    timing["search"] = time.perf_counter() - t_start - timing["detect_locate"]

    if len(accepted) >= 2:
        accepted, steps, theta = _backward(eng, accepted, steps, theta, chi2, lnN)

    if accepted:
        t0 = time.perf_counter()
        final = final_fit(res, eng, accepted, theta)
        timing["final_fit"] = time.perf_counter() - t0
        if withdrawn(res, final, accepted, rounds):  # worse than without them
            accepted, steps = [], []
    if not accepted:
        timing["total"] = time.perf_counter() - t_start
        if not loc0.parts:  # a marginal test result that points nowhere: noise
            final, method = _correlated_errors(res, geo, alpha)
            return Explanation("none", res, final, [], [], [], det0, det0, loc0, loc0, rounds,
                               method, timing, geo)
        sysb = tracker_systematics(res, geo, alpha)
        timing["total"] = time.perf_counter() - t_start
        if sysb["why_not"] is None:  # below the tracker's floor: a measurement, not physics
            final = nuisance_result(res, sysb)  # its errors carry the tracker's systematics
            return Explanation("none", res, final, [], [], [], det0, det0, loc0, loc0, rounds,
                               _method(final), timing, geo, sysb)
        how, final, det_f, loc_f, disc = after_catalog(res, geo, loc0.parts, det0, sig_est,
                                                       alpha)  # the families (MODEL.md §5)
        timing["total"] = time.perf_counter() - t_start
        if how == "modelled":
            return Explanation("modelled", res, final, [], loc0.parts, [], det0, det_f, loc0,
                               loc_f, rounds, _method(final), timing, geo, sysb, disc)
        final, method = partial_shift(*robust_result(res, geo, alpha), disc)
        final, _, _, disc = _withheld(final, [], [], disc)
        return Explanation("unexplained", res, final, [], loc0.parts, [], det0, det0, loc0,
                           loc0, rounds, method, timing, geo, sysb, disc)

    det1 = detect(geo, final.residuals, final.dof, sigma_estimated=sig_est, alpha=alpha)
    loc1 = locate(geo, final.residuals, det1)
    if steps:  # the last step's chi2 from the exact final fit
        steps[-1].chi2_per_dof_after = float(final.chi2_per_dof)
        steps[-1].params = final.effect_params(steps[-1].effect)
    sysb = disc = None
    if det1.consistent:
        verdict, located, method = "explained", loc0.parts, "least squares"
    elif not loc1.parts:
        verdict, located = "explained", loc0.parts
        final, method = _correlated_errors(final, geo, alpha)
    else:
        sysb = tracker_systematics(final, geo, alpha)
        if sysb["why_not"] is None:  # what is left sits below the tracker's floor
            final = nuisance_result(final, sysb)
            verdict, located, method = "explained", loc0.parts, _method(final)
        else:
            fam = after_catalog(final, geo, loc1.parts, det1, sig_est, alpha)
            disc = fam[-1]
            if fam[0] == "modelled":
                _, final, det1, loc1, disc = fam
                verdict, located, method = "modelled", loc0.parts, _method(final)
            else:
                verdict, located = "unexplained", loc1.parts
                final, method = partial_shift(*robust_result(final, geo, alpha), disc)
                final, accepted, steps, disc = _withheld(final, accepted, steps, disc)
    alt = _family_instead(res, geo, loc0, det0, sig_est, alpha, final, accepted, verdict)
    if alt is not None:
        _, final, det1, loc1, disc = alt
        verdict, located, method, accepted, steps = "modelled", loc0.parts, _method(final), [], []
    timing["total"] = time.perf_counter() - t_start
    return Explanation(verdict, res, final, list(accepted), located, steps, det0, det1, loc0,
                       loc1, rounds, method, timing, geo, sysb, disc)


#: the catalog's image effects: MODEL.md §5's image map holds each of them
IMAGE_EFFECTS = ("lens_distortion", "camera_tilt", "marker_depth")


def _family_instead(res, geo, loc0, det0, sig_est, alpha, final, accepted, verdict):
    """Catalog entries that one family term does better (issue 28).

    When the catalog's entries needed a family term beside them, or still left a
    mismatch, they may only imitate physics that no entry has (a squat taken in part for
    body_bounce and camera_tilt; lugs that splay round the wheels, in part for belt_sag);
    and a stack of image effects, even one that explains the recording, may imitate a warp
    none of them is (a keystone: the camera not square to the track, read as
    lens_distortion + camera_tilt + marker_depth with the slip 4.7 sigma off). The
    families are then tried on the base fit instead, and win when they model the
    recording (chi^2/dof to the noise) with a BIC lower by more than the catalog's
    threshold, or, where the entries stood beside a family term, unless the entries lower
    the BIC by more than it. Returns after_catalog's tuple, or None when the catalog's
    answer stands."""
    image_stack = len(accepted) >= 2 and any(e in IMAGE_EFFECTS for e in accepted)
    if not accepted or (verdict == "explained" and not image_stack):
        return None
    if verdict == "unexplained" and set(accepted) <= set(BASE_EFFECTS) and \
            reads_straight_runs(final):
        # only the base model's marker placement was taken, the families already failed
        # beside it, and the whole-path model misfits grossly (chi2/dof > GROSS_CHI2): the
        # base fit without the placement is further from the path still (the engine's
        # recordings: 10-14 s CPU for nothing)
        return None
    fam = after_catalog(res, geo, loc0.parts, det0, sig_est, alpha)
    if fam[0] != "modelled":
        return None
    alt = fam[1]
    lnN = math.log(res.n_data)
    gap, c_corr = catalog_minus_family_bic(geo, final, alt, lnN)  # deflated (issue 42)
    if verdict == "modelled":
        # the entries stand beside a family term: they must earn their place by the
        # criterion (a ground bump's frame pitch was taken in part for camera_tilt, the
        # bump's profile then modelling the rest: chi2/dof 1.04 either way)
        if gap < BIC_THRESHOLD:
            return None
    elif not gap > -BIC_THRESHOLD:
        return None
    fam[-1].tried.append({"catalog": list(accepted), "delta_bic": gap,
                          "correlation_inflation": c_corr,
                          "rejected_because": (f"the family term(s) model the recording "
                                               f"with a BIC {gap:.0f} lower "
                                               f"than these catalog entries together")})
    return fam


#: the residuals' correlation (explain._correlated) above which a fit whose residuals fail
#: detection without a located part carries robust errors: a tracker's drift and pixel
#: locking shift the slip by far more than the least-squares error (issue 42: z 17)
ROBUST_C = 2.0


def _correlated_errors(res, geo, alpha):
    """(result, method): `res` with robust errors when its residuals are correlated in
    time beyond ROBUST_C, else as it is."""
    if inflation_geo(geo, res.residuals) <= ROBUST_C:
        return res, _method(res)
    return robust_result(res, geo, alpha)


def _method(res) -> str:
    info = getattr(res, "robust", None)
    return info["label"] if info else "least squares"


def _start(eng, scr, chi2_cur, names, give_up=None):
    """The best of: the screening's Gauss-Newton step, its effect part alone, half of that
    (and, for lug_sliding, the grid of :func:`._candidates.sliding_starts`; `give_up`).

    A large nonlinear effect can make the linear step overshoot; the fit then starts
    from whichever of these is lowest in chi^2.
    """
    th_gn = scr.theta_start
    cur = scr.theta_current
    th_eff = eng.with_values(cur, {k: eng.get(th_gn, k) for k in names})
    th_half = eng.with_values(cur, {k: 0.5 * (eng.get(th_gn, k) + eng.get(cur, k))
                                    for k in names})
    cands = np.array([th_gn, th_eff, th_half])
    c2, k, _ = eng.chi2_best(cands)  # one batch of residual vectors in memory at a time
    best, best_c2 = cands[k], c2[k]
    if scr.effect == "lug_sliding":
        # the grid over F0/F_max (issue 32): each point after SLIDING_GRID_STEPS steps of
        # the fit (the first moves the belt coordinates by millimetres, the next ones
        # settle the law; after one step the order of the grid points is still wrong)
        for th in sliding_starts(eng, cur):
            out = eng.fit(th, names, max_iter=SLIDING_GRID_STEPS, give_up=give_up)
            if np.isfinite(out.chi2) and out.chi2 < best_c2:
                best, best_c2 = out.theta, out.chi2
    return best


def _backward(eng, accepted, steps, theta, chi2, lnN):
    """Drop added effects that no longer earn their place next to the others."""
    changed = True
    while changed and len(accepted) >= 2:
        changed = False
        for e in list(accepted):
            others = [a for a in accepted if a != e]
            extra = [k for a in others for k in eng.free_names(a)]
            th0 = eng.with_values(theta, {k: v for k, v in CATALOG[e].defaults.items()})
            out = eng.fit(th0, extra)
            dbic = chi2 - out.chi2 + eng.n_free(e) * lnN
            if dbic >= BIC_THRESHOLD:
                accepted = others
                steps = [s for s in steps if s.effect != e]
                theta, chi2 = out.theta, out.chi2
                changed = True
                break
    return accepted, steps, theta
