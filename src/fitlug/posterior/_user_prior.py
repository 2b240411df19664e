"""The user's priors (:class:`fitlug.Prior` through :class:`fitlug.Parameters`) on the
sampled slip law: on s0, beta and a replacing law's own parameters directly, on the
derived k = 2 m / (1000 beta n L) and C_rr = s0 / (1000 g beta) - F_d / (m g) through
them. They add to the posterior's own (:mod:`._priors`); the least squares took the same
priors as pseudo-observations (:mod:`fitlug.fit._constrained`)."""

from __future__ import annotations

import numpy as np

from ..fit._parameters import ALIASES, DERIVED, Parameters, Prior
from ..model._physics import G


def as_priors(prior) -> dict:
    """{name: Prior} from a Parameters, a dict name -> Prior, or None ({}).

    Raises TypeError for anything else or a value that is no Prior."""
    if prior is None:
        return {}
    if isinstance(prior, Parameters):
        return {k: p.prior for k, p in prior.items() if p.prior is not None}
    if isinstance(prior, dict):
        out = {}
        for k, v in prior.items():
            if not isinstance(v, Prior):
                raise TypeError(f"prior[{k!r}] must be a fitlug.Prior, got {type(v).__name__}")
            out[ALIASES.get(k, k)] = v
        return out
    raise TypeError(f"prior must be fitlug.Parameters or {{name: fitlug.Prior}}, got "
                    f"{type(prior).__name__}")


def user_log_prior(priors: dict, names: list, res):
    """log prior(theta) of the (walkers, d) array theta over `names` (numpy), or None when
    no prior acts on the sampled parameters.

    A prior on a nuisance parameter (neither sampled nor derived from the sampled ones)
    acts through the least squares only. Raises ValueError for a prior on k without the
    rig's mass."""
    if not priors:
        return None
    lay, rig = res.problem.lay, res.problem.rig
    terms = []
    for k, pr in priors.items():
        if k in names:
            i = names.index(k)
            terms.append((pr, lambda th, i=i: th[:, i]))
        elif k in DERIVED or k == "m":
            if k == "m":
                continue  # the mass widens k's error in the least squares only
            si, bi = names.index("s0"), names.index("beta")
            if k == "k":
                if rig.mass_kg is None:
                    raise ValueError("a prior on k needs the rig's mass")
                f = (lambda th: 2.0 * rig.mass_kg / (1000.0 * th[:, bi] * float(lay.n_contact)
                                                     * float(lay.L)))
            else:
                pull = rig.drawbar_pull_N or 0.0
                m = rig.mass_kg or 1.0
                f = (lambda th: th[:, si] / (1000.0 * G * th[:, bi]) - pull / (m * G))
            terms.append((pr, f))
    if not terms:
        return None

    def log_prior(th):
        th = np.atleast_2d(np.asarray(th, float))
        out = np.zeros(len(th))
        with np.errstate(all="ignore"):
            for pr, f in terms:
                out = out + np.asarray(pr.log_density(f(th)))
        return np.where(np.isnan(out), -np.inf, out)

    return log_prior


def mass_prior(samples: dict, priors: dict, rng) -> None:
    """A normal prior on the rig's mass m: k = m (k/m) with m drawn from it per sample
    (relative sd, independent of the chain), so k's band carries the mass's error."""
    pr = priors.get("m")
    k = samples.get("stiffness_N_per_mm")
    if pr is None or pr.kind != "normal" or k is None:
        return
    samples["stiffness_N_per_mm"] = k * rng.normal(1.0, pr.b / pr.a, np.shape(k))
