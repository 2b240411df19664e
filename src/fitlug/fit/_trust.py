"""The dense solver's Levenberg-Marquardt: optimistix's, with a trust region that ends the
solve where chi^2 has stopped changing (by rounding at a minimum; by less than DECREMENT_TOL
chi^2/dof over CONFIRM_STEPS steps at a gross misfit). Used by :mod:`._lsq` and
:mod:`._constrained`."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx

#: chi^2/dof above which a fit that did not converge is said to be far from the data (a
#: drive-through near the friction limit, slip 0.40, stopped at 8 952: issue 42's sweep)
GROSS_MISFIT = 100.0

#: relative change of chi^2 below which a nearly undamped step counts as rounding (the
#: bundled recording's chi^2 moves by 1e-14..1e-13 of itself between steps at its minimum)
FLAT_REL = 1e-11
#: chi^2 a further Gauss-Newton step (fit._fit's polish), or CONFIRM_STEPS more steps at a
#: gross misfit, may still remove at "converged", in units of chi^2/dof where that is
#: above 1: half the delta chi^2 = 1 at which intervals are drawn. Seen: cruise-only
#: recordings whose slip slope beta trades with s0 along a curved valley, where LM crawls
#: and a full step overshoots; the remaining decrement was 0.27
DECREMENT_TOL = 0.5
#: steps over which a fit at a gross misfit must lower chi^2 by DECREMENT_TOL chi^2/dof or
#: more to go on (_RoundingAwareTrustRegion: stationary at a gross misfit)
CONFIRM_STEPS = 30


class _StopState(eqx.Module):
    step_size: jax.Array
    stop: jax.Array  # the step just judged moved chi^2 by rounding only: the solve is over
    ck_loss: jax.Array  # the loss CONFIRM_STEPS steps ago at most (the stationarity window)
    ck_n: jax.Array  # steps since then


class _RoundingAwareTrustRegion(optx.ClassicalTrustRegion):
    """optimistix's classical trust region, except that

    - a step small enough to end the solve (inside the Cauchy tolerances in both y and the
      residuals) is accepted whatever its true/predicted reduction ratio. At the optimum
      that ratio is rounding noise, and the classical test rejects such steps at random,
      shrinking the region for many steps before an accepted one ends the solve
      (measured: up to 17 extra steps after converged Gauss-Newton steps);
    - a nearly undamped step (lambda at most its start) whose predicted and true changes of
      chi^2 are both below FLAT_REL of chi^2 ends the solve (:class:`_LevenbergMarquardt`
      reads `stop`): chi^2 is at its minimum to rounding, and the parameters are within
      sqrt(FLAT_REL chi^2) of it in units of their errors (4e-4 sigma on the bundled
      recording). The Cauchy test alone waited for the step in y itself to fall
      below rtol, which in the weakly constrained directions of an ill-conditioned
      Jacobian it does only once the damping has grown: the bundled recording's three
      solves took 18, 15 and 19 steps, 10-12 of each after chi^2 had stopped changing
      (2026-11-29: 6, 7 and 6 steps, the same digits).

    - with `dof` (the residual rows' degrees of freedom) the solve also ends where chi^2/dof
      is above GROSS_MISFIT and the last CONFIRM_STEPS steps lowered chi^2 by less than
      DECREMENT_TOL chi^2/dof: at residuals that large the Gauss-Newton model is poor and
      LM crawls (an engine's chain of links, chi^2/dof 5 847 after 60 steps, 5 840.05
      after 300: 0.12-0.2 of a chi^2/dof per 30 steps from step 150 on), and that point
      is stationary for every purpose the fit serves. It is the rule fitlug.fit._fit
      applied after the step limit (300 steps and 30 more to confirm, for the first fit
      and again for each refit from its optimum), applied as the solve goes.

    Any larger step is judged as before."""

    rtol: float = 1e-8
    atol: float = 1e-6
    dof: jax.Array | float = 0.0  # 0: no stationarity rule at a gross misfit

    def init(self, y, f_info_struct):
        return _StopState(step_size=jnp.array(1.0), stop=jnp.array(False),
                          ck_loss=jnp.array(jnp.inf), ck_n=jnp.array(0))

    def step(self, first_step, y, y_eval, f_info, f_eval_info, state):
        base = super().init(y, None)  # optimistix's own state type, for its step
        size, accept, result, _ = super().step(first_step, y, y_eval, f_info, f_eval_info,
                                               type(base)(step_size=state.step_size))
        r0, r1 = f_info.residual, f_eval_info.residual
        small_y = jnp.max(jnp.abs(y_eval - y) / (self.atol + self.rtol * jnp.abs(y))) < 1
        small_r = jnp.max(jnp.abs(r1 - r0) / (self.atol + self.rtol * jnp.abs(r0))) < 1
        finite = jnp.all(jnp.isfinite(r1))
        done = small_y & small_r & finite
        loss0, loss1 = f_info.as_min(), f_eval_info.as_min()
        tiny = FLAT_REL * loss0
        pred = self.predict_reduction(y_eval - y, f_info)
        flat = (~first_step & finite & (state.step_size >= 1.0)
                & (jnp.abs(pred) <= tiny) & (jnp.abs(loss1 - loss0) <= tiny))
        size = jnp.where((done | flat) & ~accept, state.step_size, size)
        accepted = accept | done | flat
        # the stationarity window at a gross misfit (loss = chi^2 / 2); the first step
        # evaluates the start (its f_info is a placeholder)
        now = jnp.where(accepted, loss1, loss0)
        ck = jnp.where(first_step, loss1, state.ck_loss)
        n = jnp.where(first_step, 0, state.ck_n + 1)
        dof = jnp.maximum(jnp.asarray(self.dof, float), 1.0)
        scale = 2.0 * now / dof
        due = n >= CONFIRM_STEPS
        still = (due & (jnp.asarray(self.dof) > 0) & finite & (scale > GROSS_MISFIT)
                 & (2.0 * (ck - now) < DECREMENT_TOL * scale))
        return size, accepted, result, _StopState(
            step_size=size, stop=flat | still, ck_loss=jnp.where(due, now, ck),
            ck_n=jnp.where(due, 0, n))


class _LevenbergMarquardt(optx.LevenbergMarquardt):
    """optimistix's LM that also ends where its trust region saw chi^2 stop changing."""

    def terminate(self, fn, y, args, options, state, tags):
        term, result = super().terminate(fn, y, args, options, state, tags)
        return term | state.search_state.stop, result


def _levenberg_marquardt(rtol, atol, linear_solver, dof=0.0):
    """LM with the trust region above; `dof` > 0 turns on its stationarity rule at a gross
    misfit (the degrees of freedom of the residual rows it is given)."""
    lm = _LevenbergMarquardt(rtol=rtol, atol=atol, linear_solver=linear_solver)
    return eqx.tree_at(lambda s: s.search, lm,
                       _RoundingAwareTrustRegion(rtol=rtol, atol=atol, dof=dof))


def valid_dof(obs, mask):
    """Degrees of freedom of a solve: valid residual rows (weight > 0; padded and flagged
    rows carry 0) less the free elements (`mask` > 0), traced (the host's count of the
    rows is :attr:`fitlug.fit._problem.Problem.n_valid`)."""
    n = 2.0 * (jnp.sum(obs["lug_w"] > 0) + jnp.sum(obs["body_w"] > 0))
    return n - jnp.sum(mask > 0)
