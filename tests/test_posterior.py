"""The posterior of the slip law: calibrated against known truth, and the sampler itself.

Statistical tests with fixed seeds (emcee's own integration tests are the model): 4
simulated recordings with known slip and rolling resistance, each fitted and sampled; per
recording the posterior std must equal the least-squares one (a nearly linear problem)
and the chain must be converged. The calibration over many recordings (how often the 90 %
and 95 % intervals hold the truth, z and the probability integral transform) is
benchmarks/bench_posterior.py's part (a), over >= 100 recordings: a 16-recording sweep
here took a quarter of this file's time (issue 43, item 6). The ensemble driver is
checked on distributions known in closed form.
"""

import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from fitlug import FitError
from fitlug.fit import fit
from fitlug.posterior import Posterior, sample_posterior
from fitlug.posterior._mcmc import run_ensemble
from fitlug.posterior._marginal import slip_law_parameters
from fitlug.sim import Scenario, rig_of, simulate

# short recordings (300 frames, 6 lug + 2 body markers): ~4 s per fit on 2 cores
SHORT = Scenario(duration_s=3.0, travel_mm=300, rest_s=0.3, ramp_s=0.8, lug_markers=6)
SEEDS = tuple(range(7100, 7104))  # 4 recordings (CI time: each compiles its own)
QUANTITIES = ("slip", "rolling_resistance", "stiffness_N_per_mm")


def _scenario(seed):
    rng = np.random.default_rng(seed)
    return SHORT.replace(slip=float(rng.uniform(0.04, 0.12)),
                         rolling_resistance=float(rng.uniform(0.06, 0.15)))


@pytest.fixture(scope="module")
def runs():
    out = []
    for seed in SEEDS:
        sc = _scenario(seed)
        rec, truth = simulate(sc, seed)
        res = fit(rec, rig_of(sc), noise={"lug": sc.noise_lug_mm, "body": sc.noise_body_mm})
        post = sample_posterior(res, seed=seed)
        out.append((truth, res, post))
        # each recording's knots are static in its layout, so it compiles its own functions:
        # drop them, or a long test session runs out of LLVM code memory
        jax.clear_caches()
    return out


def test_posterior_std_agrees_with_least_squares(runs):
    # nearly linear problem: the marginal posterior std equals the Jacobian error to within
    # the Monte-Carlo error of a std from ESS >= 1000 samples (~2 %)
    for _, res, post in runs:
        for q in QUANTITIES:
            ratio = post.estimates[q].std / res.quantities[q].std
            assert 0.88 < ratio < 1.12, (q, ratio)
        e = post.estimates["slip"]
        assert e.ci95[0] < e.value < e.ci95[1]


def test_chain_diagnostics(runs):
    for _, _, post in runs:
        m = post.mcmc_json()
        json.dumps(m, allow_nan=False)
        for key in ("walkers", "steps", "autocorr_time", "ess", "converged", "acceptance",
                    "method", "seconds"):
            assert key in m, key
        assert m["converged"] is True and m["status"] == "converged"
        assert m["walkers"] == 32
        assert 0.15 < m["acceptance"] < 0.7
        kept = m["steps"] - m["burn_in"]
        assert kept >= 50 * m["autocorr_time"]
        assert m["ess"] >= 1000 and m["ess_slip"] >= 1000
        assert m["method"].startswith("gaussian")
        assert m["linearity_check"]["max_delta_chi2"] < 0.25
        assert m["parameters"] == ["s0", "beta"]
        assert set(post.estimates) == {"slip", "delta_l_mm", "stiffness_N_per_mm",
                                       "rolling_resistance", "k_over_m"}


def test_exact_marginal_agrees_with_its_gaussian_limit(runs):
    _, res, gauss = runs[0]
    # the sampler stops once converged; the wall budget is only a guard (120 s ran out on
    # a machine with load average 14)
    # ESS 200: the means' Monte Carlo error 0.07 sd, the std's 5 % (bounds 0.3 sd, 20 %)
    exact = sample_posterior(res, seed=3, method="exact", target_ess=200,
                             min_tau_multiple=20)
    assert exact.method.startswith("exact")
    assert exact.converged
    for q in ("slip", "stiffness_N_per_mm"):
        g, e = gauss.estimates[q], exact.estimates[q]
        assert abs(e.value - g.value) < 0.3 * g.std, q
        assert 0.8 < e.std / g.std < 1.25, q


def test_step_limit_and_wall_guard_stop_and_say_not_converged(runs):
    _, res, _ = runs[1]
    post = sample_posterior(res, seed=0, max_steps=100)  # deterministic: a step limit
    m = post.mcmc_json()
    assert m["converged"] is False and m["status"] == "not converged"
    assert m["message"].startswith("not converged: stopped at 100 steps")
    assert np.isfinite(post.estimates["slip"].value)
    with pytest.warns(RuntimeWarning, match="wall-time guard.*NOT reproducible"):
        post = sample_posterior(res, seed=0, time_budget_s=1e-6)  # the guard: says so
    assert post.mcmc_json()["message"].startswith("not converged: stopped by the wall-time")


def test_seeded_and_reproducible(runs):
    _, res, post = runs[2]
    again = sample_posterior(res, seed=SEEDS[2])
    np.testing.assert_array_equal(again.samples["slip"], post.samples["slip"])
    other = sample_posterior(res, seed=SEEDS[2] + 1)
    assert not np.array_equal(other.samples["slip"], post.samples["slip"])


def test_samples_saved_for_arviz(runs, tmp_path):
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        import arviz as az

    _, _, post = runs[0]
    path = tmp_path / "posterior.nc"
    post.save(path)
    idata = az.from_netcdf(str(path))
    for name in ("slip", "s0", "beta", "stiffness_N_per_mm", "rolling_resistance"):
        v = idata.posterior[name].values
        assert v.shape[0] == 32
        np.testing.assert_allclose(np.sort(v.ravel()), np.sort(post.samples[name]))
    assert "lp" in idata.sample_stats
    assert [p.name for p in tmp_path.iterdir()] == ["posterior.nc"]  # no temporary left


def test_bad_arguments(runs):
    _, res, _ = runs[0]
    with pytest.raises(ValueError, match="method"):
        sample_posterior(res, method="nuts")
    with pytest.raises(ValueError, match="walkers"):
        sample_posterior(res, walkers=7)
    assert isinstance(runs[0][2], Posterior)


def test_a_replacing_slip_law_is_sampled_with_its_parameter(monkeypatch):
    # lug_sliding: s = -s_K ln(1 - F/F_max); the steady slip is a nonlinear function of
    # (s0, beta, slide_mu), all three sampled, slide_mu >= 0 by the prior
    sc = SHORT.replace(effects={"lug_sliding": {"slide_mu": 6.0}})
    rec, truth = simulate(sc, 5)
    res = fit(rec, rig_of(sc), effects=("lug_sliding",),
              noise={"lug": sc.noise_lug_mm, "body": sc.noise_body_mm})
    post = sample_posterior(res, seed=0)
    m = post.mcmc_json()
    assert m["parameters"] == ["s0", "beta", "slide_mu"] and m["converged"]
    assert m["linearity_check"]["points"] == 14
    assert np.all(post.samples["slide_mu"] >= 0)
    for q in ("slip", "rolling_resistance", "stiffness_N_per_mm"):
        e = post.estimates[q]
        assert abs(e.value - truth[q]) < 4 * e.std, q
        assert 0.88 < e.std / res.quantities[q].std < 1.12, q
    assert abs(np.median(post.samples["slide_mu"]) - 6.0) < 4 * np.std(post.samples["slide_mu"])
    # the exact marginal: sampled in the law's own coordinates (steady slip, slope,
    # slide_mu) from its mode, where the ridge of (s0, beta, slide_mu) is straight; the
    # same posterior as the Gaussian limit here (the check passes: max 0.06 in chi^2)
    exact = sample_posterior(res, seed=0, method="exact")
    m = exact.mcmc_json()
    assert m["converged"] and m["coordinates"]["mode_iterations"] <= 4
    assert abs(m["coordinates"]["mode_delta_chi2"]) < 1e-3  # the fit is the mode here
    assert m["autocorr_time"] < 5 and m["steps"] <= 300  # ~2.5 and 200; DEMove: ~9, 500
    for q in ("slip", "rolling_resistance", "stiffness_N_per_mm"):
        g, e = post.estimates[q], exact.estimates[q]
        assert abs(e.value - g.value) < 0.2 * g.std, q
        assert 0.9 < e.std / g.std < 1.1, q
    assert np.all(exact.samples["slide_mu"] >= 0)
    # where the check fails at the least-squares solution (made to here) but passes at the
    # mode in the law's coordinates, 'auto' samples the Gaussian limit there
    from fitlug.posterior._marginal import _Marginal

    real = _Marginal.linearity_check

    def failing(self):
        return {**real(self), "max_delta_chi2": 100.0}

    monkeypatch.setattr(_Marginal, "linearity_check", failing)
    near = sample_posterior(res, seed=0)
    m = near.mcmc_json()
    assert m["method"].startswith("gaussian") and "own coordinates" in m["method"]
    assert m["coordinates"]["linearity_check_at_mode"]["max_delta_chi2"] < 0.25
    assert m["converged"]
    for q in ("slip", "rolling_resistance", "stiffness_N_per_mm"):
        g, e = exact.estimates[q], near.estimates[q]
        assert abs(e.value - g.value) < 0.2 * g.std, q
        assert 0.9 < e.std / g.std < 1.1, q
    monkeypatch.undo()
    # the change of coordinates keeps the density of theta: a Gaussian in theta, sampled
    # in u (where it is not Gaussian: the Jacobian 1 / f'(s0)^2 carries it), comes back
    from fitlug.posterior._reparam import SlipCoordinates

    mu = np.array([res.params["s0"], res.params["beta"], res.params["slide_mu"]], float)
    sd = np.array([0.01, 2e-6, 1.0])  # wide enough that f'(s0) varies by ~20 %
    corr = np.array([[1.0, 0.5, -0.6], [0.5, 1.0, -0.3], [-0.6, -0.3, 1.0]])
    cov = corr * np.outer(sd, sd)
    prec = np.linalg.inv(cov)

    def lp_theta(th):
        z = th - mu
        return -0.5 * np.einsum("ij,jk,ik->i", z, prec, z)

    coords = SlipCoordinates(res, ["s0", "beta", "slide_mu"])
    coords.whiten(mu, cov)
    lp = coords.log_prob(lp_theta)
    z0, Cz, _ = coords.mode(lp)
    p0 = coords.start(z0, Cz, lp, 32, np.random.default_rng(1))
    ch = run_ensemble(lp, p0, names=("s0", "beta", "slide_mu"), seed=2, proposal=(z0, Cz))
    assert ch.converged
    th = coords.theta(ch.flat())
    assert np.all(np.abs(th.mean(0) - mu) < 5 * sd / np.sqrt(ch.ess.min()))
    assert np.all(np.abs(th.std(0) / sd - 1) < 0.08)
    np.testing.assert_allclose(np.corrcoef(th.T), corr, atol=0.06)


def test_sampled_parameters_follow_the_slip_law():
    class Res:
        effects = ("lug_sliding",)
        packing = type("P", (), {"names": ("v", "s0", "beta", "R", "slide_mu")})

    assert slip_law_parameters(Res) == ["s0", "beta", "slide_mu"]
    Res.packing.names = ("v", "s0", "R")
    with pytest.raises(FitError, match="beta"):
        slip_law_parameters(Res)


# ----- the ensemble driver on distributions known in closed form ---------------------------

def _jax_log_prob(f):
    g = jax.jit(jax.vmap(f))
    return lambda x: np.asarray(g(jnp.asarray(x)))


def test_driver_recovers_a_correlated_gaussian():
    mu = np.array([0.07716, -3.0, 1e-4])
    sd = np.array([2e-6, 0.5, 3e-8])
    corr = np.array([[1.0, 0.8, -0.5], [0.8, 1.0, -0.3], [-0.5, -0.3, 1.0]])
    cov = corr * np.outer(sd, sd)
    prec = jnp.asarray(np.linalg.inv(cov))

    def lp(x):
        z = x - mu
        return -0.5 * z @ prec @ z

    rng = np.random.default_rng(11)
    p0 = rng.multivariate_normal(mu, cov, 32)
    ch = run_ensemble(_jax_log_prob(lp), p0, names=("a", "b", "c"), seed=5, time_budget_s=60)
    assert ch.converged and ch.reason == ""
    assert np.all(ch.samples.shape[0] >= 50 * ch.tau) and np.all(ch.ess >= 1000)
    x = ch.flat()
    ess = ch.ess
    assert np.all(np.abs(x.mean(0) - mu) < 5 * sd / np.sqrt(ess))
    assert np.all(np.abs(x.std(0) / sd - 1) < 0.08)
    np.testing.assert_allclose(np.corrcoef(x.T), corr, atol=0.06)
    # nearly independent draws: every 2 tau-th step of every walker
    thin = ch.samples[::int(math.ceil(2 * ch.tau.max()))].reshape(-1, 3)
    for k in range(3):
        assert stats.kstest((thin[:, k] - mu[k]) / sd[k], "norm").pvalue > 1e-3
    assert 0.15 < ch.acceptance.mean() < 0.7
    # with independence moves from a Laplace approximation (here a wider, shifted one):
    # the same distribution, from a chain that forgets its past in a few steps
    ch = run_ensemble(_jax_log_prob(lp), p0, names=("a", "b", "c"), seed=5,
                      proposal=(mu + 0.3 * sd, 1.5 * cov))
    assert ch.converged and np.all(ch.tau < 5)
    x = ch.flat()
    assert np.all(np.abs(x.mean(0) - mu) < 5 * sd / np.sqrt(ch.ess))
    assert np.all(np.abs(x.std(0) / sd - 1) < 0.08)
    np.testing.assert_allclose(np.corrcoef(x.T), corr, atol=0.06)
    thin = ch.samples[::int(math.ceil(2 * ch.tau.max()))].reshape(-1, 3)
    for k in range(3):
        assert stats.kstest((thin[:, k] - mu[k]) / sd[k], "norm").pvalue > 1e-3


def test_driver_respects_a_truncating_prior(capsys):
    # N(0.5, 1) truncated to x > 0, like the prior beta > 0 on a poorly measured beta
    def lp(x):
        return jnp.where(x[0] > 0, -0.5 * (x[0] - 0.5) ** 2, -jnp.inf)

    rng = np.random.default_rng(2)
    p0 = np.abs(rng.normal(0.5, 1.0, (32, 1))) + 1e-3
    ch = run_ensemble(_jax_log_prob(lp), p0, names=("x",), seed=1, time_budget_s=60,
                      progress=True)
    assert capsys.readouterr().err == ""  # the progress bar is silent off a terminal
    x = ch.flat()[:, 0]
    assert x.min() > 0
    tn = stats.truncnorm(-0.5, np.inf, loc=0.5, scale=1.0)
    assert abs(x.mean() - tn.mean()) < 5 * tn.std() / np.sqrt(ch.ess[0])
    thin = ch.samples[::int(math.ceil(2 * ch.tau.max()))].ravel()
    assert stats.kstest(thin, tn.cdf).pvalue > 1e-3
    # independence moves from the untruncated Gaussian: proposals below 0 are refused
    ch = run_ensemble(_jax_log_prob(lp), p0, names=("x",), seed=1,
                      proposal=(np.array([0.5]), np.eye(1)))
    x = ch.flat()[:, 0]
    assert x.min() > 0 and ch.converged
    assert abs(x.mean() - tn.mean()) < 5 * tn.std() / np.sqrt(ch.ess[0])
    thin = ch.samples[::int(math.ceil(2 * ch.tau.max()))].ravel()
    assert stats.kstest(thin, tn.cdf).pvalue > 1e-3


def _gauss_2d(x):
    x = np.atleast_2d(x)
    return -0.5 * (x[:, 0] ** 2 + ((x[:, 1] - 0.9 * x[:, 0]) / 0.3) ** 2)


def test_chain_is_the_same_on_a_busy_machine(monkeypatch):
    """Issue 43: the stopping rule reads the chain, not the clock. A clock 50 s further on
    at every read (a machine 100x slower) leaves the samples bit for bit the same."""
    import fitlug.posterior._mcmc as mcmc

    p0 = np.random.default_rng(3).normal(0, 0.3, (16, 2))
    quiet = run_ensemble(_gauss_2d, p0, names=("a", "b"), seed=4, target_ess=300)
    ticks = iter(range(0, 10 ** 9, 50))
    monkeypatch.setattr(mcmc, "_clock", lambda: float(next(ticks)))
    busy = run_ensemble(_gauss_2d, p0, names=("a", "b"), seed=4, target_ess=300)
    assert quiet.converged and busy.converged
    assert busy.steps == quiet.steps
    np.testing.assert_array_equal(busy.samples, quiet.samples)
    # the guard is reached only when something is wrong, and then says so loudly
    ticks = iter(range(0, 10 ** 9, 1000))
    with pytest.warns(RuntimeWarning, match="wall-time guard of 900 s"):
        stuck = run_ensemble(_gauss_2d, p0, names=("a", "b"), seed=4, target_ess=300)
    assert not stuck.converged and "wall-time guard" in stuck.reason
    assert stuck.steps == mcmc.CHECK_EVERY


def test_driver_refuses_a_bad_start():
    lp = _jax_log_prob(lambda x: jnp.where(x[0] > 0, 0.0, -jnp.inf))
    with pytest.raises(ValueError, match="non-finite"):
        run_ensemble(lp, -np.ones((8, 1)), names=("x",))
    with pytest.raises(ValueError, match="walkers"):
        run_ensemble(lp, np.ones((3, 2)), names=("x", "y"))


def test_exact_marginal_is_the_profile_over_the_nuisance_on_a_cruise():
    """A cruise-only recording leaves beta nearly free, and the nuisance Jacobian changes by
    its own size along it (beta scales how the speed profile's acceleration moves the slip).
    The exact marginal must follow the profile min_eta chi^2 there, found here by an
    independent Gauss-Newton per point: with the Jacobian at the optimum, one
    Gauss-Newton step gave 134 for a profile of 5.6 at beta -> 0 and declared k identifiable
    with a false interval (bench_coverage's cruise row, seed 37078); the linear prediction
    gave the Gaussian, 65 at beta_max for a profile of 2.3."""
    from fitlug.model._physics import beta_max
    from fitlug.posterior._marginal import _Marginal

    from cruise import cruise_recording
    from nuisance_profile import profile_chi2

    rec, rig, truth = cruise_recording(0.11699287025363395, 0.07402002714064823, 37078)
    res = fit(rec, rig)
    names = slip_law_parameters(res)
    marg = _Marginal(res, names, batch=16)
    i0, ib = names.index("s0"), names.index("beta")
    C, th0 = marg.cov, marg.theta_hat
    top = beta_max(th0[i0])
    betas = np.array([0.02, 0.3, 0.6, 1.0]) * top
    th = np.repeat(th0[None], len(betas), 0)
    th[:, ib] = betas  # along the ridge: s0 at its Gaussian conditional mean
    th[:, i0] = th0[i0] + (betas - th0[ib]) * C[i0, ib] / C[ib, ib]
    th = np.vstack([th, marg.check_points()[:2]])  # and 2 sigma along the first axis
    exact = marg.exact_chi2(np.vstack([th0, th]))
    exact = exact[1:] - exact[0]
    prof = np.array([profile_chi2(res, names, t) for t in th]) - profile_chi2(res, names, th0)
    gauss = np.einsum("ij,jk,ik->i", th - th0, marg.F, th - th0)
    assert gauss[3] > 10 * prof[3]  # far from Gaussian: the test means something
    assert prof[0] > 2.0  # and the profile rises towards beta -> 0
    assert np.all(np.abs(exact - prof) <= 0.05 + 0.03 * np.abs(prof)), (exact, prof)
    jax.clear_caches()


def test_lean_emcee_import_leaves_scipy_stats_importable_and_the_chain_unchanged():
    """posterior._mcmc.LEAN_IMPORT (the executable's): emcee imported without scipy.stats,
    which a later import still gets whole; the same seed gives the same chain as emcee
    imported whole (a fresh interpreter each, emcee not yet imported)."""
    import subprocess
    import sys

    code = """
import sys, numpy as np
from fitlug.posterior import _mcmc
_mcmc.LEAN_IMPORT = {lean}
chain = _mcmc.run_ensemble(lambda x: -0.5 * np.sum(x ** 2, axis=1),
                           np.random.default_rng(0).normal(size=(8, 2)) * 0.1,
                           names=["a", "b"], seed=3, max_steps=300)
stats_before = "scipy.stats" in sys.modules and sys.modules["scipy.stats"] is not None
from scipy.stats import theilslopes, norm
assert norm.cdf(0.0) == 0.5 and theilslopes([0.0, 1.0, 2.0])[0] == 1.0
print(repr(float(chain.samples.sum())), stats_before)
"""
    out = {}
    for lean in (True, False):
        run = subprocess.run([sys.executable, "-c", code.format(lean=lean)],
                             capture_output=True, text=True, timeout=300)
        assert run.returncode == 0, run.stderr
        out[lean] = run.stdout.split()
    assert out[True][1] == "False"  # scipy.stats was not imported for emcee
    assert out[True][0] == out[False][0]  # the same chain, bit for bit
