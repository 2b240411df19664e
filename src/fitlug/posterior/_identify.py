"""What the recording cannot pin down, decided from the information the data carry.

A reported quantity q (slip, dl', k, C_rr, k/m) is a function of the sampled slip law
theta (s0, beta, ...). Its interval is honest as long as the data fix it well enough for
the interval to mean what it says. q is declared not identifiable when both:

- its relative posterior std exceeds REL_STD_MAX = 0.25 (the 95 % interval is wider than
  the value itself: the data do not fix its order of magnitude to better than a factor
  ~2.7), and
- it is not a linear function of the slip law over its posterior (R^2 of the samples of q
  regressed on theta below LINEAR_R2 = 0.99): a ratio such as k = 2 m / (1000 beta n L)
  over a beta that may be anywhere from ~0 to a few times its value spans orders of
  magnitude, and its percentiles only echo the flat prior's edge (beta > 0).

A quantity linear in the slip law (s0, dl', the steady slip) keeps its interval whatever
its relative width: a slip consistent with zero is a measurement (an upper limit), not a
failure. The threshold 0.25: at a relative std of beta of 0.25 the 95 % interval of 1/beta
spans a factor ~3 and its delta-method std is off by ~15 %; clean recordings with an
acceleration phase have relative std of beta ~1e-3 to 1e-2, cruise-only ones ~1 or more
(and so does a recording whose drawbar pull neither varies nor is known), so the decision
has orders of magnitude of margin on both sides.

The reason names the sampled parameter the data leave open (the one of largest relative
std) and, for the parameters of the base slip law, what would pin it down.
"""

from __future__ import annotations

import numpy as np

from ..fit._identifiable import REL_STD_MAX  # one threshold for least squares and posterior
from ..fit._result import FitResult
from ._derived import _derived_samples
from ._marginal import slip_law_parameters
from ._tempering import reads_straight_runs, tempered_marginal

LINEAR_R2 = 0.99

_LABEL = {"slip": "the slip", "delta_l_mm": "dl'", "stiffness_N_per_mm": "k",
          "rolling_resistance": "C_rr", "k_over_m": "k/m"}
_MEANING = {  # parameter -> (what it is, what would fix it)
    "beta": ("beta = ds/da, the slope of the slip with acceleration",
             "; an acceleration phase (or a known drawbar pull) would fix it"),
    "s0": ("the steady slip s0", ""),
}


def relative_std(x: np.ndarray) -> float:
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    if len(x) < 3:
        return float("inf")
    med = float(np.median(x))
    sd = float(np.std(x, ddof=1))
    return sd / abs(med) if med != 0 else float("inf")


def linear_r2(y: np.ndarray, theta: np.ndarray) -> float:
    """R^2 of y regressed (least squares, with intercept) on the columns of theta."""
    ok = np.isfinite(y) & np.all(np.isfinite(theta), axis=1)
    y, theta = np.asarray(y, float)[ok], np.asarray(theta, float)[ok]
    if len(y) < theta.shape[1] + 3:
        return 0.0
    sy = float(np.std(y))
    if sy == 0:
        return 1.0
    X = np.column_stack([np.ones(len(y)), (theta - theta.mean(0)) / np.maximum(theta.std(0), 1e-300)])
    coef, *_ = np.linalg.lstsq(X, (y - y.mean()) / sy, rcond=None)
    resid = (y - y.mean()) / sy - X @ coef
    return float(1.0 - np.mean(resid ** 2))


def read_apart(res) -> tuple:
    """The reported quantities `res` reads apart from its slip law, each a measurement of
    its own whose interval stands however wide: the slip and dl' where they are read off
    the straight runs (the posterior's draws of them are that reading's, not the law's:
    the rule for quantities nonlinear in the law does not apply; a light robot's 0.0093
    +- 0.0026 was withheld as "nonlinear in beta")."""
    return ("slip", "delta_l_mm") if reads_straight_runs(res) else ()


def not_identifiable(samples: dict, names, measured=()) -> dict:
    """quantity -> one-sentence reason, for the reported quantities the data cannot tell.

    samples: name -> (m,) draws of the sampled parameters `names` and derived quantities;
    `measured`: quantities never declared (:func:`read_apart`).
    """
    theta = np.column_stack([np.asarray(samples[n], float) for n in names])
    rel = {n: relative_std(samples[n]) for n in names}
    worst = max(names, key=lambda n: rel[n])
    out = {}
    for q, label in _LABEL.items():
        if q not in samples or q in measured:
            continue
        r = relative_std(samples[q])
        if np.isfinite(r) and r <= REL_STD_MAX:
            continue
        r2 = linear_r2(samples[q], theta)
        if np.isfinite(r) and r2 >= LINEAR_R2:
            continue
        lo, hi = np.percentile(np.asarray(samples[worst], float), [2.5, 97.5])
        what, fix = _MEANING.get(worst, (worst, ""))
        out[q] = (f"the data do not fix {what} (relative std {_pct(rel[worst])} > "
                  f"{100 * REL_STD_MAX:.0f} %, 95 %: {lo:.2g} … {hi:.2g}) and {label} "
                  f"depends on it nonlinearly{fix}")
    return out


def _pct(x: float) -> str:
    return f"{100 * x:.0f} %" if np.isfinite(x) else "infinite"


def least_squares_identifiability(res: FitResult, *, seed: int = 0, draws: int = 4000) -> dict:
    """quantity -> reason for a least-squares-only run (no chain): the same decision as the
    posterior's (fitlug.posterior._identify), on draws from the Gaussian limit of the
    marginal of the slip law (tempered like the posterior when the misfit is unexplained)."""
    names = slip_law_parameters(res)
    marg, _ = tempered_marginal(res, names, batch=16)
    rng = np.random.default_rng(seed)
    th = marg.theta_hat + rng.standard_normal((draws, len(names))) @ marg.chol.T
    out = not_identifiable(_derived_samples(res, names, th), names, read_apart(res))
    if reads_straight_runs(res):
        # the slip law's other quantities are as the explanation left them (as
        # sample_posterior does)
        out.update({k: e.reason for k, e in res.quantities.items()
                    if e.value is None and e.reason and k in _LABEL})
    return out
