"""The least-squares fit of a recording: one verb, one structured result.

fit() fits, re-estimates the noise from the residuals and keeps glitches (isolated gross
errors, found by the rule of :mod:`._glitches`) out with zero weight.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from ..model import param_names
from ..model.effects import CATALOG
from ._covariance import covariance, covariance_normal, gauss_newton_polish
from ._lsq import least_squares
from ._on_bound import held_on_bound
from . import _glitches
from ._noise import fourth_differences, noise_from_differences
from ._boundary import check_effects, check_free, check_noise
from ._problem import Problem, build_problem
from ._result import FitResult, compute_quantities, not_converged
from ._trust import CONFIRM_STEPS, DECREMENT_TOL, GROSS_MISFIT


def free_parameters(lay) -> list[str]:
    """All parameters of the layout except those its effects hold fixed in fits."""
    fixed = {k for e in lay.effects for k in CATALOG[e].fixed_in_fit}
    return [k for k in param_names(lay) if k not in fixed]


#: a fit that would fail unconverged at a gross misfit goes on for this many times its steps
EXTRA_STEPS = 3


#: fit from the data-derived start with beta held at 0 first (see fit_problem)
HOLD_BETA_FIRST = True


def _long(prob: Problem, p0: dict, free) -> bool:
    """Whether the fit takes the long-recording (chunked) path, which needs beta free: the
    held stage would fall back to a dense Jacobian there (a 5000-frame recording's peak
    went 0.70 -> 1.56 GB), so long recordings start with every parameter free."""
    from ._lsq import LARGE_ENTRIES
    from ._residuals import Packing

    n_res = 2 * (prob.lay.lug_t.shape[0] + prob.lay.body_t.shape[0])
    return n_res * sum(Packing.of(p0, free).sizes) > LARGE_ENTRIES


def _misfit_scale(out, prob: Problem) -> float:
    """chi^2/dof of `out` where it is above 1, else 1: the unit of chi^2 in which the
    decrement left at "converged" is read. Under a misfit the errors that matter are the
    scaled ones (explain's robust errors, sqrt(chi^2/dof) wider), so a step that would
    remove 19 of chi^2 = 3.2e6 (chi^2/dof 288: a slip law far from linear, bench_discovery
    slip_speed seed 1014, LM at its step limit) moves nothing an interval could show, and
    a FitError there kept explain from ever seeing the misfit."""
    dof = max(int(prob.n_valid) - len(out.flat), 1)
    return max(1.0, float(np.sum(np.asarray(out.r) ** 2)) / dof)


def fit_problem(prob: Problem, p_start: dict | None = None, *, free=None, max_steps: int = 300,
                require_convergence: bool = True, params=None) -> FitResult:
    """Fit `prob` from `p_start` (default: the data-derived start) by Levenberg-Marquardt.

    `params`: a :class:`fitlug.Parameters` whose held elements, bounds and priors the fit
    honours (:mod:`fitlug.fit._constrained`, one compiled solver for every choice).

    Raises FitError when the solver does not converge (unless require_convergence=False,
    in which case the result says converged=False).
    """
    p0 = dict(prob.p0 if p_start is None else p_start)
    free = check_free(free, list(p0))
    if params is not None:
        from ._constrained import fit_constrained

        return fit_constrained(prob, p_start, params, free=free, max_steps=max_steps,
                               require_convergence=require_convergence,
                               hold_beta_first=HOLD_BETA_FIRST)
    free = free_parameters(prob.lay) if free is None else list(free)
    held_steps = 0
    if p_start is None and "beta" in free and len(free) > 1 and HOLD_BETA_FIRST \
            and not _long(prob, p0, free):
        # from the data-derived start, first with the slip slope beta held at 0: where the
        # picture shows little or no speed change (the robot drives through it in the
        # cruise, or enters during a ramp) beta is nearly free, and from a start whose
        # speed spline is only extrapolated where no body marker is seen, LM traded beta
        # against spurious accelerations and stopped at chi2/dof 1e4..1e7 (issue 26); with
        # beta held the geometry, phases and speed converge in a few steps, and beta then
        # moves from a point where the accelerations are the data's own
        held = least_squares(p0, free, prob.lay, prob.obs, max_steps=max_steps,
                             hold=("beta",))
        if np.all(np.isfinite(held.r)):
            p0 = {**p0, **held.params}
            held_steps = held.steps
    out = _solve(p0, free, prob, max_steps)
    out = _finish(out._replace(steps=out.steps + held_steps), prob, free, max_steps)
    if require_convergence and EXTRA_STEPS and not out.converged \
            and np.all(np.isfinite(out.r)) and _misfit_scale(out, prob) > GROSS_MISFIT:
        # where the fit would fail: at a gross misfit LM still walking at its step limit
        # (an engine crawler whose tips slide, two lug markers: chi^2/dof 3 130 after 328
        # steps, the check's 30 more still lowering it; converged at 2 863 after 1 216)
        # goes on for EXTRA_STEPS x its budget before the user is told it failed
        more = _solve(out.params, free, prob, EXTRA_STEPS * max_steps)
        more = _finish(more._replace(steps=out.steps + more.steps), prob, free, max_steps)
        if np.all(np.isfinite(more.r)) and (more.converged or
                                            np.sum(more.r ** 2) < np.sum(out.r ** 2)):
            out = more
    chi2 = float(np.sum(out.r ** 2))
    n_data = prob.n_valid
    cov = covariance(out.J) if out.J is not None else covariance_normal(out.normal)
    fixed = {k: v for k, v in out.params.items() if k not in out.packing.names}
    q = compute_quantities(out.params, out.packing, out.flat, cov, prob.lay, prob.rig.mass_kg,
                           fixed, prob.rig.drawbar_pull_N)
    converged = bool(out.converged)
    res = FitResult(problem=prob, params={k: np.asarray(v) for k, v in out.params.items()},
                    packing=out.packing, flat=out.flat, cov=cov, residuals=out.r, chi2=chi2,
                    dof=n_data - len(out.flat), converged=converged, steps=out.steps,
                    quantities=q)
    if require_convergence and not (converged and np.isfinite(chi2)):
        raise not_converged(res, out.steps, "check the marker roles and the rig file")
    return res


def _solve(p0: dict, free, prob: Problem, max_steps: int):
    """least_squares, refitted with beta held on its bound where the solver ended far
    below it (:mod:`._on_bound`: else the reported parameters do not give the residuals)."""
    out = least_squares(p0, free, prob.lay, prob.obs, max_steps=max_steps)
    return held_on_bound(out, prob.lay, prob.obs, free, max_steps=max_steps,
                         tol=DECREMENT_TOL * _misfit_scale(out, prob),
                         finish=lambda o, fr: _finish(o, prob, fr, max_steps))


def _finish(out, prob: Problem, free, max_steps: int):
    """A fit LM left at its step limit, finished: Gauss-Newton polish, else stationarity at
    a gross misfit; `out` unchanged when converged."""
    if not out.converged and out.J is not None and np.all(np.isfinite(out.r)):
        # LM stopped at its step limit (a direction the data hardly constrain, e.g. the slip
        # slope beta of a cruise-only recording, creeps on for hundreds of steps): full
        # Gauss-Newton steps finish the walk; converged once a further step could remove
        # less than DECREMENT_TOL of chi^2 (intervals are drawn at delta chi^2 = 1 and more)
        out, _ = gauss_newton_polish(out, prob.lay, prob.obs,
                                     tol=DECREMENT_TOL * _misfit_scale(out, prob),
                                     max_iter=min(12, max_steps // 10))
    if not out.converged and np.all(np.isfinite(out.r)):
        out = _stationary_at_gross_misfit(out, prob, free)
    return out


def _stationary_at_gross_misfit(out, prob: Problem, free):
    """LM's output at its step limit, said converged where the misfit is gross (chi^2/dof
    above GROSS_MISFIT) and CONFIRM_STEPS more steps remove less than DECREMENT_TOL of
    chi^2 in the misfit's own units (chi^2/dof): at residuals that large the Gauss-Newton
    model is poor, LM crawls (an engine's 250-fps drive-through: chi^2 5.7078e7 after 50
    steps, 5.7077915e7 after 579) and the polish cannot step; the point is stationary for
    every purpose the fit serves. Else `out` unchanged."""
    scale = _misfit_scale(out, prob)
    if scale <= GROSS_MISFIT:
        return out
    more = _solve(out.params, free, prob, CONFIRM_STEPS)
    c0, c1 = float(np.sum(out.r ** 2)), float(np.sum(np.asarray(more.r) ** 2))
    if not (np.all(np.isfinite(more.r)) and c0 - c1 < DECREMENT_TOL * scale):
        return out
    best = more if c1 < c0 else out
    return best._replace(converged=True, steps=out.steps + more.steps)


def residual_noise(res: FitResult) -> dict:
    """Noise per role from 4th differences of the fit's (unweighted) residuals per marker.

    The model removes the path's curvature jumps that bias the raw-data estimate, and
    4th differences remove any slow misfit, so this measures the noise alone.
    """
    prob = res.problem
    w = prob.weights
    raw = np.where(w > 0, res.residuals / np.where(w > 0, w, 1.0), np.nan)
    S_l, S_b = len(prob.lug_rows), len(prob.body_rows)
    parts = {"lug": (raw[:S_l], raw[S_l:2 * S_l], np.asarray(prob.lay.lug_i),
                     np.asarray(prob.lay.lug_t)),
             "body": (raw[2 * S_l:2 * S_l + S_b], raw[2 * S_l + S_b:],
                      np.asarray(prob.lay.body_j), np.asarray(prob.lay.body_t))}
    out = {}
    for role, (rx, ry, idx, t) in parts.items():
        diffs = []
        for m in np.unique(idx):
            sel = (idx == m) & np.isfinite(rx)
            for v in (rx[sel], ry[sel]):
                diffs.append(fourth_differences(t[sel], v))
        out[role] = noise_from_differences(diffs)[0]
    return out


def reweighted(prob: Problem, noise: dict) -> Problem:
    """The same problem with per-role noise `noise` in its weights."""
    obs = dict(prob.obs)
    for role, key in (("lug", "lug_w"), ("body", "body_w")):
        # a strong float64 array: a weak-typed one (both branches Python floats) made
        # equinox retrace and recompile the solver for the refit (~15 s of a cold run)
        # (in numpy: an op on the recording's shapes compiles for every new length)
        obs[key] = jnp.asarray(np.where(np.asarray(obs[key]) > 0, 1.0 / noise[role], 0.0),
                               float)
    return Problem(**{**prob.__dict__, "obs": obs, "noise": dict(noise),
                      "noise_source": "residual differences"})


def fit(rec, rig=None, *, effects=(), noise: float | dict | None = None, glitches: bool = True,
        params=None, **kw) -> FitResult:
    """Fit the base model (plus `effects`) to a recording.

    Without a sigma_mm column or a given `noise`, the noise per role is re-estimated
    from the first fit's residuals and the fit repeated with those weights. Glitches
    (isolated gross errors of the tracker, :mod:`fitlug.fit._glitches`) are then found,
    given zero weight and listed in ``problem.init_info['glitches']``; the fit is
    repeated until their set is stable. ``glitches=False`` keeps every sample.

    Args:
        rec: a :class:`fitlug.io.Recording`, a pandas DataFrame
            (:meth:`~fitlug.io.Recording.from_dataframe`) or a trajectory file's path.
        rig: a :class:`fitlug.io.Rig`, a dict of its fields, a rig.toml path, or None
            (the reference rig).
        effects: a list of catalog effect ids (MODEL.md §3) fitted with the base model.
        noise: position noise, mm: one number for both roles or {'lug': , 'body': };
            None estimates it from the data.
        glitches: find and zero-weight isolated gross errors.
        params: a :class:`fitlug.Parameters` (:func:`fitlug.parameters`): held
            parameters or elements, bounds and priors, honoured without recompiling.
        **kw: `free` (parameter names), `max_steps`, `require_convergence`, `p_start`
            of :func:`fit_problem`.

    Returns:
        FitResult.

    Raises:
        TypeError, ValueError: arguments of the wrong type or unknown names (naming the
            valid ones), before any work.
        InputError: a recording or rig that cannot be fitted (naming the file).
        FitError: the solver did not converge.
    """
    from ..io import Rig
    from ..io._coerce import as_recording, as_rig

    effects = check_effects(effects)
    noise = check_noise(noise)
    rig = as_rig(rig)
    rig = Rig.reference(assumed=True) if rig is None else rig
    rec = as_recording(rec, rig=rig)
    if params is not None:
        kw["params"] = params
    prob = build_problem(rec, rig, effects=effects, noise=noise)
    return finish_fit(fit_problem(prob, **kw), prob, noise=noise, glitches=glitches, **kw)


def finish_fit(res, prob, *, noise, glitches: bool, **kw):
    """What follows a problem's first fit in :func:`fit` (and `fit_many`): the lug-count
    check, then the glitch rounds, or a refit with the residuals' noise when the noise came
    from frame differences."""
    res = _check_lug_count(res, **kw)
    renoise = noise is None and prob.noise_source == "differences"
    if glitches:
        return remove_glitches(res, renoise=renoise, **kw)
    if renoise:
        return refit_noise(res, **kw)
    return res


def with_flags(prob: Problem, flags: dict) -> Problem:
    """`prob` with zero weight on the flagged samples ({'lug': mask, 'body': mask}) and its
    nominal weight (valid / sigma) on every other valid sample."""
    rec = prob.rec
    obs = dict(prob.obs)
    for role, rows, key in (("lug", prob.lug_rows, "lug_w"), ("body", prob.body_rows, "body_w")):
        valid = np.isfinite(rec.x[rows]) & np.isfinite(rec.y[rows])
        if prob.noise_source == "sigma_mm column":
            w = 1.0 / np.asarray(rec.sigma[rows], float)
        else:
            w = np.full(len(rows), 1.0 / prob.noise[role])
        obs[key] = jnp.asarray(np.where(valid & ~flags[role], w, 0.0), float)
    return Problem(**{**prob.__dict__, "obs": obs})


def remove_glitches(res: FitResult, *, renoise: bool = True, **kw) -> FitResult:
    """Find glitches (:func:`fitlug.fit._glitches.find`), zero their weights and refit,
    until the flagged set is stable (at most _glitches.MAX_ROUNDS refits; one where the
    refit still misfits at chi^2/dof above _glitches.GROSS_ROUNDS_CHI2). With `renoise`
    the noise per role is re-estimated from the residuals (flagged samples left out)
    before each refit, so a clean recording costs the one refit of :func:`refit_noise`.

    The result's problem carries the zero weights and, in its init_info, the list
    ('glitches'), the rule ('glitch_rule') and the threshold in sigma ('glitch_threshold').
    A refit that does not converge where the fit before it did ends the rounds on that fit
    and its flags, so a converged `res` gives a converged result (the callers: fit, from a
    converged first fit, and the explanation's final fit, which accepts either).
    """
    kw.pop("p_start", None)
    none = {k: np.zeros(len(getattr(res.problem, k + "_rows")), bool) for k in ("lug", "body")}
    applied = none  # the flags the current fit's weights carry
    found = _glitches.find(res)
    flagged_by = (res, found)  # the fit and the search that set `applied`: their sizes
    for rnd in range(_glitches.MAX_ROUNDS):
        # the set is stable when at most a couple of samples (or 2 % of it) flip: samples
        # at the threshold that a refit moves across it and back (an engine recording's
        # 59-60 flags changed by 1, then 2, and took two refits more, 2.3 s)
        flips = sum(int(np.sum(found[k] != applied[k])) for k in ("lug", "body"))
        n_flag = sum(int(np.sum(applied[k])) for k in ("lug", "body"))
        same = flips <= max(_glitches.SETTLED_FLIPS, 0.02 * n_flag) and (
            rnd > 0 or flips == 0)
        if same and (rnd > 0 or not renoise):
            break
        prob = with_flags(res.problem, found)
        if renoise:  # the noise from the residuals, without the flagged samples
            new = residual_noise(dataclasses.replace(res, problem=prob))
            if all(np.isfinite(v) and v > 0 for v in new.values()):
                prob = reweighted(prob, new)
        new_res = fit_problem(prob, p_start=res.params, **{**kw, "require_convergence": False})
        if res.converged and not new_res.converged:
            # the flags' refit crawled to its step limit (a misfit in the thousands whose
            # structure the finder took for glitches: an engine's drive-through, 3 of 17):
            # the last converged fit and its flags stand
            break
        flagged_by = (res, found)
        res = new_res
        applied = found
        if res.chi2_per_dof > _glitches.GROSS_ROUNDS_CHI2:
            break  # the misfit's structure, not glitches, would decide further rounds
        found = _glitches.find(res)
    # what the weights hold, each flag with its size in the search that set it (the last
    # search may no longer find a flag that the settle rule left: 0-2 sigma there)
    src_res, src = flagged_by
    src = {**src, "lug": applied["lug"], "body": applied["body"]}
    info = {**res.problem.init_info, "glitches": _glitches.listing(src_res, src),
            "glitch_rule": _glitches.RULE, "glitch_threshold_sigma": float(src["c"])}
    prob = Problem(**{**res.problem.__dict__, "init_info": info})
    return dataclasses.replace(res, problem=prob)


def _check_lug_count(res: FitResult, **kw) -> FitResult:
    """N = round(P / pitch) again with the fitted belt length P (the start's P may be off)."""
    prob = res.problem
    pitch = prob.rig.lug_pitch_mm
    if pitch is None:
        return res
    P = float(2 * res.params["D"] + 2 * np.pi * res.params["R"])
    N = max(int(round(P / pitch)), 1)
    if N == int(prob.lay.n_belt):
        return res
    lay = dataclasses.replace(prob.lay, n_belt=jax.device_put(np.float64(N)))
    prob2 = Problem(**{**prob.__dict__, "lay": lay,
                       "init_info": {**prob.init_info, "n_belt": N}})
    kw.pop("p_start", None)
    return fit_problem(prob2, p_start=res.params, **kw)


def refit_noise(res: FitResult, **kw) -> FitResult:
    """Re-estimate the noise from `res`'s residuals and refit from its parameters."""
    new = residual_noise(res)
    if not all(np.isfinite(v) and v > 0 for v in new.values()):
        return res
    kw.pop("p_start", None)
    return fit_problem(reweighted(res.problem, new), p_start=res.params, **kw)
