"""emcee driven until the chain is long enough to trust, or a step limit is reached.

The stopping rule is emcee's own advice made mechanical: estimate the integrated
autocorrelation time tau of every parameter on the chain after burn-in, and stop once
the kept chain is at least `min_tau_multiple` tau long (below ~50 tau the estimate of
tau itself is biased low) and the effective sample size walkers * kept / tau reaches
`target_ess` for every parameter. Burn-in is 2 tau (walkers start from the least-squares
solution and its covariance, already in the typical set).

The rule looks at the chain only, every CHECK_EVERY steps, and the chain is a function
of the seed: the same seed gives the same samples on a quiet or a busy machine (issue 43:
a 60 s wall budget stopped a busy machine's chain at 218 steps, unconverged, where the
same command alone converged). A chain that reaches `max_steps` unconverged is returned
with converged=False and a reason, never silently. The wall-time guard (`time_budget_s`)
is a safety net, checked at the same points: it is reached only when something is wrong
(a log-probability far slower than it should be), and then a RuntimeWarning says so and
that the result depends on the machine's speed.

Move: differential evolution (emcee's DEMove) instead of the default stretch move. On the
slip law's nearly Gaussian, strongly correlated 2-3 dimensional posteriors it gives
tau ~ 8-11 steps against ~ 30 for the stretch move (measured on correlated Gaussians,
rho = 0.9), so the 50 tau rule is met 3-4 times sooner. emcee's DESnookerMove, often
mixed in, is left out: in emcee <= 3.1.6 its Metropolis factor is wrong (dfm/emcee#531);
measured here it shrinks the std of a 3-D Gaussian by 8 %.

With a Laplace approximation of the target (`proposal`: a replacing slip law's exact
marginal, sampled in the law's own coordinates from its mode, ._reparam) half the steps
are an independence Metropolis move instead: every walker proposes a draw from a Student
t (5 degrees of freedom) of that mean and covariance, accepted with the Metropolis-Hastings
factor. Where the target is nearly that Gaussian (lug_sliding on bench_speed's effect
recording: its chi^2 within 0.3 of the quadratic at 1-sigma draws) the chain forgets its
past in a few steps: tau ~ 2.5 steps against ~ 9 for DEMove alone there, so it stops at
MIN_STEPS. The DEMove half keeps it moving where the approximation is poor (an
independence sampler alone sticks in tails the proposal misses, and tau then says so).
"""

from __future__ import annotations

import math
import sys
import time
import warnings
from dataclasses import dataclass

import numpy as np

from .. import _progress

CHECK_EVERY = 100  # steps between convergence checks (a check costs ~1 ms)
MIN_STEPS = 200
#: ~10 x the steps a converged slip-law chain takes (tau ~ 10: ~600). It bounds a default
#: run's time the same on every machine: a slowly mixing exact chain is reported not
#: converged at this limit, with its reason, rather than run for ten minutes (lug_sliding
#: on a drive-through, sampled in theta with DEMove: tau ~ 240 steps, ~12 000 steps and
#: 558 s CPU; in the law's own coordinates, ._reparam: tau ~ 2.5, 200 steps)
MAX_STEPS = 6_000
#: with a `proposal`: the share of steps that are independence moves, and their t's
#: degrees of freedom
INDEPENDENCE_WEIGHT = 0.5
INDEPENDENCE_DOF = 5.0
#: import emcee without scipy.stats (set by the `fit-lug` executable where nothing else in
#: its process needs it): only emcee's KDEMove, which fitlug does not use, takes
#: scipy.stats's gaussian_kde, and importing scipy.stats for it cost ~0.3 s of a ~4.5 s
#: run of the bundled recording (issue 43). Library callers import emcee whole.
LEAN_IMPORT = False
GUARD_S = 900.0  # the default wall-time guard: reached only when something is wrong
_clock = time.perf_counter  # the guard's clock (tests put a slow one in its place)


def _emcee():
    """The emcee module; under LEAN_IMPORT imported with scipy.stats hidden (its KDEMove
    then has no gaussian_kde), unless either is imported already. scipy.stats imports as
    usual afterwards."""
    if LEAN_IMPORT and "emcee" not in sys.modules and "scipy.stats" not in sys.modules:
        sys.modules["scipy.stats"] = None  # emcee.moves.kde: `except ImportError`
        try:
            import emcee
        finally:
            if "scipy.stats" in sys.modules and sys.modules["scipy.stats"] is None:
                del sys.modules["scipy.stats"]
        return emcee
    import emcee

    return emcee


@dataclass
class Chain:
    """The kept part of an ensemble run and its diagnostics.

    samples: (draws, walkers, ndim) after burn-in; log_prob: (draws, walkers).
    tau, ess: per parameter (steps, samples); acceptance: per walker, over the whole run.
    """

    names: tuple
    samples: np.ndarray
    log_prob: np.ndarray
    tau: np.ndarray
    ess: np.ndarray
    acceptance: np.ndarray
    steps: int  # total steps run (burn-in included)
    discard: int
    converged: bool
    reason: str
    seconds: float

    @property
    def walkers(self) -> int:
        return self.samples.shape[1]

    def flat(self) -> np.ndarray:
        """(draws * walkers, ndim), draws-major like emcee's get_chain(flat=True)."""
        return self.samples.reshape(-1, self.samples.shape[-1])


def autocorr_time(chain: np.ndarray) -> np.ndarray:
    """Integrated autocorrelation time per parameter of a (steps, walkers, ndim) chain.

    emcee's estimator (Sokal's window, c = 5), without its length check: the caller
    applies the min_tau_multiple rule itself. Returns inf for a constant parameter.
    """
    emcee = _emcee()

    n = chain.shape[0]
    if n < 4:
        return np.full(chain.shape[-1], np.inf)
    with np.errstate(invalid="ignore", divide="ignore"):
        tau = emcee.autocorr.integrated_time(chain, tol=0, quiet=True)
    return np.where(np.isfinite(tau) & (tau > 0), np.maximum(tau, 1.0), np.inf)


def run_ensemble(log_prob, p0: np.ndarray, *, names, seed: int = 0,
                 time_budget_s: float = GUARD_S, min_tau_multiple: float = 50.0,
                 target_ess: float = 1000.0, max_steps: int = MAX_STEPS,
                 progress: bool = False, proposal=None) -> Chain:
    """Run emcee's affine-invariant ensemble from `p0` until converged or `max_steps`.

    log_prob: vectorised, (m, ndim) -> (m,) (emcee's vectorize=True); -inf outside the
    prior. p0: (walkers, ndim) starting positions, all with finite log_prob.
    max_steps: the deterministic limit (then converged=False and the reason).
    time_budget_s: wall-clock guard in seconds, checked with the convergence every
    CHECK_EVERY steps; reaching it warns (RuntimeWarning): the chain then depends on the
    machine's speed. progress: a tqdm bar on stderr (only on a terminal). Each check is
    noted to fitlug.progress (steps, ESS and tau so far: the command line's lines).
    proposal: (mean, cov) of a Laplace approximation of the target, or None: then half
    the steps are an independence Metropolis move from a Student t (INDEPENDENCE_DOF) of
    that mean and covariance, the other half DEMove (see the module docstring).
    Raises ValueError if p0 has a non-finite log-probability or too few walkers.
    """
    emcee = _emcee()

    p0 = np.asarray(p0, float)
    walkers, ndim = p0.shape
    if walkers < 2 * ndim or walkers % 2:
        raise ValueError(f"walkers must be even and >= 2 * ndim = {2 * ndim}; got {walkers}")
    if int(max_steps) < 1:
        raise ValueError(f"max_steps must be >= 1, not {max_steps}")
    lp0 = np.asarray(log_prob(p0))
    if not np.all(np.isfinite(lp0)):
        raise ValueError(f"{int(np.sum(~np.isfinite(lp0)))} of {walkers} starting positions "
                         "have a non-finite log-probability")
    rng = np.random.default_rng(seed)
    moves = emcee.moves.DEMove()
    if proposal is not None:
        moves = [(moves, 1.0 - INDEPENDENCE_WEIGHT),
                 (_independence_move(*proposal), INDEPENDENCE_WEIGHT)]
    sampler = emcee.EnsembleSampler(walkers, ndim, log_prob, vectorize=True, moves=moves)
    state = emcee.State(p0, log_prob=lp0,
                        random_state=np.random.RandomState(rng.integers(2 ** 31)).get_state())
    bar = _progress_bar(progress)
    t0 = _clock()
    wall0 = time.perf_counter()
    converged, reason = False, ""
    tau = np.full(ndim, np.inf)
    discard = 0
    try:
        while True:
            block = int(min(CHECK_EVERY, max_steps - sampler.iteration))
            for state in sampler.sample(state, iterations=block,
                                        skip_initial_state_check=True):
                bar.update(1)
            n = sampler.iteration
            chain = sampler.get_chain()
            tau_all = autocorr_time(chain)
            discard = _burn_in(tau_all, n)
            tau = autocorr_time(chain[discard:])
            kept = n - discard
            ess = walkers * kept / tau
            long_enough = bool(np.all(kept >= min_tau_multiple * tau))
            bar.set_postfix_str(f"tau={np.max(tau):.1f} ESS={np.min(ess):.0f}")
            done = n >= MIN_STEPS and long_enough and np.all(ess >= target_ess)
            _progress.note("sampling", f"{n} steps, ESS {np.min(ess):.0f} (target "
                           f"{target_ess:g}), chain {kept / np.max(tau):.0f} tau long "
                           f"(needs {min_tau_multiple:g})" + (", converged" if done else ""),
                           last=bool(done or n >= max_steps))
            if done:
                converged = True
                break
            state_of = (f"the chain {kept / np.max(tau):.1f} tau long (needs "
                        f"{min_tau_multiple:g}) and ESS {np.min(ess):.0f} (target "
                        f"{target_ess:g})")
            if n >= max_steps:
                reason = f"not converged: stopped at {max_steps} steps with {state_of}"
                break
            if _clock() - t0 > time_budget_s:
                reason = (f"not converged: stopped by the wall-time guard of "
                          f"{time_budget_s:g} s at {n} steps with {state_of}; this chain "
                          "depends on the machine's speed")
                warnings.warn(f"the sampler reached its wall-time guard of {time_budget_s:g} "
                              f"s after {n} steps, long before its step limit ({max_steps}): "
                              "something is wrong (a log-probability far slower than "
                              "expected, or a starved machine); its result is NOT "
                              "reproducible and not converged", RuntimeWarning, stacklevel=2)
                break
    finally:
        bar.close()
    chain = sampler.get_chain()
    lp = sampler.get_log_prob()
    n = sampler.iteration
    kept = n - discard
    return Chain(names=tuple(names), samples=chain[discard:], log_prob=lp[discard:],
                 tau=tau, ess=walkers * kept / tau,
                 acceptance=np.asarray(sampler.acceptance_fraction), steps=int(n),
                 discard=int(discard), converged=converged, reason=reason,
                 seconds=time.perf_counter() - wall0)


def _independence_move(mean, cov, dof: float = None):
    """emcee's MHMove proposing every walker independently of where it is, from a
    multivariate Student t g (mean, cov, `dof` degrees of freedom: tails heavier than the
    Gaussian it approximates), with the Metropolis-Hastings factor g(x) / g(x')."""
    emcee = _emcee()

    dof = INDEPENDENCE_DOF if dof is None else dof
    mean = np.asarray(mean, float)
    L = np.linalg.cholesky(np.asarray(cov, float))
    d = len(mean)

    def log_g(x):
        y = np.linalg.solve(L, (np.atleast_2d(x) - mean).T).T
        return -0.5 * (dof + d) * np.log1p(np.sum(y * y, axis=1) / dof)

    def propose(coords, random):
        n = len(coords)
        y = random.standard_normal((n, d)) * np.sqrt(dof / random.chisquare(dof, n))[:, None]
        q = mean + y @ L.T
        return q, log_g(coords) - log_g(q)  # ln g(x) - ln g(x'), x' proposed

    return emcee.moves.MHMove(propose)


def _burn_in(tau: np.ndarray, n: int) -> int:
    t = float(np.max(tau))
    if not math.isfinite(t):
        return n // 2
    return int(min(math.ceil(2.0 * t), n // 2))


def _progress_bar(progress: bool):
    from tqdm.auto import tqdm

    on = bool(progress) and sys.stderr.isatty()
    return tqdm(desc="posterior", unit="step", file=sys.stderr, disable=not on, leave=True,
                dynamic_ncols=True)
