"""The posterior of the slippage: emcee over the slip-law parameters, the rest marginalised.

What is sampled: the slip law's parameters theta = (s0, beta) (plus those of a replacing
law), every other parameter marginalised linearly around the least-squares optimum; the
derivation is at the top of :mod:`._marginal`, with its two evaluations, 'exact' and 'gaussian'.
method='auto' (default) evaluates the exact marginal at 2-sigma points around the
optimum (principal axes and diagonals) and uses the Gaussian limit only when it agrees
to `LINEARITY_TOL` in delta-chi^2 everywhere there; otherwise it samples the exact
marginal. The check's largest discrepancy is reported. The chain stops on effective
samples (`._mcmc`): the same seed gives the same digits on a quiet or a busy machine.
The exact marginal of a replacing slip law (lug_sliding) is sampled in the law's own
coordinates from the marginal's mode (`._reparam`): in theta it is a thin curved ridge.

When fitlug.explain leaves a misfit unexplained (res.robust set), the white-noise
likelihood is orders of magnitude too confident: it is stretched to the cluster-robust
covariance of the slip law (see `tempering`), so the posterior is never narrower than the
robust least-squares errors. What the data cannot fix is found from the samples
(`._identify`) and reported, not printed as a number (Posterior.not_identifiable).
Priors: :mod:`._priors`; the walkers start inside them (`_start`).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from .. import _jaxconfig  # noqa: F401
from .._errors import FitError
from ..model._physics import C_RR_MIN, beta_max
from ..fit._reading import misses_the_data
from ..fit._result import Estimate, FitResult
from ._derived import REPORTED, _derived_samples, _estimate
from ._identify import not_identifiable, read_apart
from ._marginal import LINEARITY_TOL, _Marginal, slip_law_parameters
from ._mcmc import GUARD_S, MAX_STEPS, run_ensemble
from ._posterior import Posterior
from ._priors import _log_prior
from ._reparam import SlipCoordinates, has_own_coordinates
from ._tempering import reads_straight_runs, tempered_marginal


def _gaussian_log_prob(marg: _Marginal):
    th0, F, names = (jax.device_put(np.asarray(marg.theta_hat)),
                     jax.device_put(np.asarray(marg.F)), marg.names)

    def one(th, th0, F):
        z = th - th0
        return -0.5 * z @ F @ z + _log_prior(th, names)

    # theta_hat and F as arguments, not constants of the program: one compile serves
    # every recording (issue 43, item 2)
    f = jax.jit(jax.vmap(one, in_axes=(0, None, None)))
    return lambda x: np.asarray(f(x, th0, F))


def _exact_log_prob(marg: _Marginal):
    names = marg.names

    def lp(x):
        x = np.asarray(x)
        prior = np.asarray(_log_prior(jnp.asarray(x), names))
        out = np.full(len(x), -np.inf)
        ok = np.isfinite(prior)
        if ok.any():
            out[ok] = -0.5 * (marg.exact_chi2(marg.map_theta(x[ok])) - marg.chi2_hat)
        return out

    return lp



def sample_posterior(res: FitResult, *, seed: int = 0, progress: bool = False,
                     time_budget_s: float = GUARD_S, walkers: int = 32,
                     min_tau_multiple: float = 50.0, target_ess: float = 1000.0,
                     method: str = "auto", prior=None,
                     max_steps: int = MAX_STEPS) -> Posterior:
    """Sample the posterior of the slip law of a least-squares fit; see the module docstring.

    res: a converged FitResult. seed: everything random (walker starts, emcee moves).
    progress: a tqdm bar on stderr (only on a terminal). The chain stops once its effective
    sample size reaches `target_ess` and it is `min_tau_multiple` autocorrelation times
    long, or at `max_steps` (then converged=False and the reason in mcmc_json()): a
    function of the seed, not of the machine's speed. time_budget_s: a wall-clock guard
    in seconds, reached only when something is wrong (it warns; see `._mcmc`).
    method: 'auto',
    'gaussian' or 'exact'. prior: fitlug.Parameters or {name: fitlug.Prior} on s0, beta,
    k, C_rr or a replacing slip law's parameters (default: the priors `res` was fitted
    with, ``res.constraints``); parameters the fit held stay held.
    Raises ValueError for bad arguments, FitError when the slip law is not identifiable.
    """
    import time

    if method not in ("auto", "gaussian", "exact"):
        raise ValueError(f"method must be 'auto', 'gaussian' or 'exact', not {method!r}")
    if walkers < 4 or walkers % 2:
        raise ValueError(f"walkers must be an even number >= 4, not {walkers}")
    if not (time_budget_s > 0 and min_tau_multiple > 0 and target_ess > 0):
        raise ValueError("time_budget_s, min_tau_multiple and target_ess must be positive")
    from ._user_prior import as_priors, mass_prior, user_log_prior

    if not isinstance(res, FitResult):
        raise TypeError(f"sample_posterior needs a FitResult (fitlug.fit(...), or an "
                        f"Explanation's .final), got {type(res).__name__}")
    priors = as_priors(getattr(res, "constraints", None) if prior is None else prior)
    t0 = time.perf_counter()
    names = slip_law_parameters(res)
    user_lp = user_log_prior(priors, names, res)
    robust = getattr(res, "robust", None) or {}
    straight = reads_straight_runs(res)
    marg, temper = tempered_marginal(res, names, batch=walkers // 2)
    # the slip read off the straight runs: the model does not describe the path, its slip
    # law's quantities are reported not identifiable (explain._robust.SLIP_LAW) and the
    # exact marginal of that model (its Gauss-Newton profile 10^6 in chi^2 off its
    # Gaussian limit on an engine recording, 170 s of chain) says nothing more: the
    # Gaussian limit, stretched like the exact one, is sampled without a check
    # a model that misses the markers by a tenth of a pitch (explain._straight
    # .far_from_data): its slip is not read, its law sampled like the straight runs' case
    far = misses_the_data(res)
    check = None if method == "auto" and (straight or far) else marg.linearity_check()
    use = method
    if method == "auto":
        use = ("gaussian" if straight or far or check["max_delta_chi2"] <= LINEARITY_TOL
               else "exact")
        if robust.get("method") == "family term":
            # the model extended by a family term (fitlug.explain.families) has no exact
            # marginal here (res.problem is the catalog's model, without the term): the
            # Gaussian limit at the extended fit, stretched to its covariance
            use = "gaussian"
    log_prob = _gaussian_log_prob(marg) if use == "gaussian" else _exact_log_prob(marg)
    if user_lp is not None:
        base = log_prob
        log_prob = lambda x: base(x) + user_lp(x)  # noqa: E731
    t1 = time.perf_counter()

    rng = np.random.default_rng(seed)
    coords, p0, where, proposal = None, None, {}, None
    if use == "exact" and has_own_coordinates(res, names):
        # a replacing slip law: its own coordinates, from the exact marginal's mode
        # (._reparam: a curved ridge in theta that emcee's affine moves crawl along)
        coords = SlipCoordinates(res, names)
        coords.whiten(marg.theta_hat, marg.cov)
        sampled = coords.log_prob(log_prob)
        z0, Cz, iters = coords.mode(sampled)
        p0 = coords.start(z0, Cz, sampled, walkers, rng)
        if p0 is not None:
            log_prob, proposal = sampled, (z0, Cz)
            near = coords.linearity_check(z0, Cz, sampled, LINEARITY_TOL)
            if (method == "auto" and near["max_delta_chi2"] is not None
                    and near["max_delta_chi2"] <= LINEARITY_TOL):
                # its Gaussian limit there is as good as the check asks: sample that
                use = "gaussian"
                log_prob = coords.gaussian_log_prob(z0, Cz)
            mode = coords.theta(z0[None])[0]
            where = {"sampled": "the slip law's own coordinates (steady slip, its slope in "
                                "the acceleration, " + ", ".join(names[2:]) + "), whitened",
                     "start": "the Laplace approximation at the exact marginal's mode",
                     "mode": {k: float(v) for k, v in zip(names, mode)},
                     "mode_iterations": int(iters),
                     "mode_delta_chi2": float(-2.0 * (sampled(z0[None])[0]
                                                      - sampled(np.zeros((1, len(z0))))[0])),
                     "linearity_check_at_mode": near}
        else:
            coords = None
    if coords is None:
        p0 = _start(marg, walkers, rng)
    chain = run_ensemble(log_prob, p0, names=names, seed=int(rng.integers(2 ** 31)),
                         time_budget_s=time_budget_s, min_tau_multiple=min_tau_multiple,
                         target_ess=target_ess, max_steps=max_steps, progress=progress,
                         proposal=proposal)
    if coords is not None:  # the samples back in theta, their log density with them
        shape = chain.samples.shape
        th = coords.theta(chain.samples.reshape(-1, shape[-1]))
        lp = chain.log_prob + coords.log_jacobian(th).reshape(shape[:2])
        chain = dataclasses.replace(chain, samples=th.reshape(shape), log_prob=lp)
    t2 = time.perf_counter()
    samples = _derived_samples(res, names, chain.flat())
    _slip_term(samples, res, rng)
    mass_prior(samples, priors, rng)
    estimates = {k: _estimate(samples[k]) for k in REPORTED if k in samples}
    unident = not_identifiable(samples, names, read_apart(res))
    for k, why in unident.items():  # never a number for what the data cannot fix
        if k in estimates:
            estimates[k] = Estimate(None, None, reason=why)
    if straight or far:
        # the slip law's quantities of a model that does not describe the path (and its
        # slip, where it misses the markers by a tenth of a pitch): left not identifiable
        # as the explanation said (explain._robust.SLIP_LAW, explain._straight.far_from_data)
        for k, e in res.quantities.items():
            if k in estimates and e.value is None and e.reason:
                estimates[k] = e
                unident[k] = e.reason  # the reason printed and in fit.json: the same
    t3 = time.perf_counter()
    desc = {"gaussian": "emcee on the Gaussian limit of the linearly marginalised likelihood",
            "exact": "emcee on the exact-model, linearly marginalised likelihood"}[use]
    if check is None:  # 'auto' on a straight-runs headline: no check was made
        desc += (" (the slip read off the straight runs: the model does not describe the "
                 "path, its slip law is sampled only in its Gaussian limit)")
    if where and use == "gaussian":
        desc = ("emcee on the Gaussian limit of the exact-model, linearly marginalised "
                "likelihood in the slip law's own coordinates at its mode")
    elif where:
        desc += "; sampled in the slip law's own coordinates from the marginal's mode"
    how = "posterior (emcee)"
    headline = robust.get("headline")
    if headline:  # a nuisance taken out, a free speed profile: the fit is another model's
        how += "; " + robust["uncertainty_method"]
        if temper["factor"] > 1.01:  # an error 0.5 % wider or more
            what = ("the family term's" if robust.get("method") == "family term"
                    else "the unexplained misfit's" if headline == "straight runs"
                    else "the nuisance's own")
            how += (f"; likelihood stretched (steady-slip error x "
                    f"{math.sqrt(temper['factor']):.3g}) to carry {what} uncertainty")
    elif temper["factor"] > 1.0:
        how += (f", likelihood tempered (stretched) to the {temper['method']} covariance "
                f"({temper['note']}; slip error x {math.sqrt(temper['factor']):.3g} the "
                "white-noise one): " + ("tracker systematics carried" if "nuisance" in
                                        temper["method"] else "unexplained misfit"))
    return Posterior(estimates=estimates, samples=samples, chain=chain,
                     method=f"{use}: {desc}", check=check, seed=seed,
                     not_identifiable=unident, uncertainty_method=how, temper=temper,
                     coordinates=where,
                     seconds=time.perf_counter() - t0, n_marginalised=marg.n_marginalised,
                     settings={"time_budget_s": time_budget_s, "max_steps": max_steps,
                               "min_tau_multiple":
                               min_tau_multiple, "target_ess": target_ess,
                               "requested_method": method},
                     timings={"marginal_and_check": t1 - t0, "chain": t2 - t1,
                              "derived": t3 - t2})


def _start(marg: _Marginal, walkers: int, rng) -> np.ndarray:
    """Walkers drawn from the least-squares solution's Gaussian, inside the prior.

    When the prior holds only a sliver of that Gaussian (beta unfixed by the data: a
    cruise), beta is drawn uniformly over its physical range (0, s0 / (1000 g C_RR_MIN)]
    and the other parameters from the Gaussian conditional on it.
    """
    names = list(marg.names)
    d = len(names)

    prior = jax.jit(lambda th: _log_prior(th, names))  # one program, not one per op

    def inside(th):
        return np.isfinite(np.asarray(prior(jax.device_put(np.asarray(th)))))

    got = []
    for _ in range(8):
        th = marg.theta_hat + rng.standard_normal((4096, d)) @ marg.chol.T
        got.append(th[inside(th)])
        if sum(len(g) for g in got) >= walkers:
            return np.vstack(got)[:walkers]
    if "beta" in names and "s0" in names and d > 1:
        ib, i0 = names.index("beta"), names.index("s0")
        rest = [i for i in range(d) if i != ib]
        C = 0.5 * (marg.cov + marg.cov.T)
        c_bb = C[ib, ib]
        gain = C[rest, ib] / c_bb
        Cc = C[np.ix_(rest, rest)] - np.outer(gain, C[ib, rest])
        w, V = np.linalg.eigh(0.5 * (Cc + Cc.T))
        root = V * np.sqrt(np.clip(w, 0.0, None))
        s0_top = max(float(marg.theta_hat[i0]) + 3.0 * math.sqrt(max(C[i0, i0], 0.0)), 1e-6)
        cap = beta_max(s0_top)
        for _ in range(8):
            beta = rng.uniform(0.0, cap, 4096)
            th = np.empty((4096, d))
            th[:, ib] = beta
            th[:, rest] = (marg.theta_hat[rest] + np.outer(beta - marg.theta_hat[ib], gain)
                           + rng.standard_normal((4096, len(rest))) @ root.T)
            got.append(th[inside(th)])
            if sum(len(g) for g in got) >= walkers:
                return np.vstack(got)[:walkers]
    raise FitError("the least-squares solution lies outside the prior (beta > 0, s0 >= 0, "
                   f"C_rr >= {C_RR_MIN:g}): no walker could be started")



def _slip_term(samples: dict, res, rng) -> None:
    """A family term that moves the headline slip (a slip law in the speed: fitlug.explain
    .families) is not in the sampled model: its change g of the slip is drawn beside each
    sample from its Gaussian given the sample's steady slip (their joint covariance from
    the extended fit, res.robust["slip_term"]) and added to the slip. A term with
    "replace" (the slip read off the straight runs, fitlug.explain._straight) replaces the
    slip, and delta_l' with it, by draws from its value and std."""
    term = (getattr(res, "robust", None) or {}).get("slip_term")
    if not term or "slip" not in samples:
        return
    if term.get("replace"):  # the slip read off the straight runs (fitlug.explain._straight)
        draw = term["value"] + term["std"] * rng.standard_normal(np.shape(samples["slip"]))
        if "delta_l_mm" in samples:  # delta_l' = s L / (n - 1) (MODEL.md §2)
            from ..model import delta_l

            lay = res.problem.lay
            samples["delta_l_mm"] = delta_l(draw, float(lay.n_contact), float(lay.L))
        samples["slip"] = draw
        return
    s = np.asarray(samples["slip"], float)
    b = term["cov_with_slip"] / term["slip_var"] if term["slip_var"] > 0 else 0.0
    rest = max(term["var"] - b * term["cov_with_slip"], 0.0)
    g = term["value"] + b * (s - term["steady_slip"]) + np.sqrt(rest) * rng.standard_normal(
        s.shape)
    samples["slip"] = s + g
