"""The Posterior: samples of the slip law and the quantities derived from it, their
fit.json "mcmc" block and their netCDF file.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np

from ..model._physics import C_RR_MIN
from ._mcmc import Chain, autocorr_time
from ._priors import _NONNEG, _POSITIVE


@dataclass
class Posterior:
    """Posterior samples of the slip law and the physical quantities derived from it.

    estimates: name -> Estimate (median, std, 2.5-97.5 % interval) for 'slip',
    'delta_l_mm', 'rolling_resistance', 'k_over_m' and 'stiffness_N_per_mm' (with a mass);
    a quantity the data do not fix is ``Estimate(None, None, reason=...)`` (the reason
    also in `not_identifiable`).
    samples: name -> (draws * walkers,) for those and the sampled parameters.
    """

    estimates: dict
    samples: dict
    chain: Chain
    method: str
    check: dict
    seed: int
    seconds: float
    n_marginalised: int
    settings: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)  # stage -> seconds
    not_identifiable: dict = field(default_factory=dict)  # quantity -> reason
    uncertainty_method: str = "posterior (emcee)"
    temper: dict = field(default_factory=lambda: {"factor": 1.0})
    #: how a replacing slip law was sampled (._reparam): its coordinates, the mode the
    #: walkers started from; empty when theta itself was sampled
    coordinates: dict = field(default_factory=dict)

    def __repr__(self) -> str:
        e = self.estimates.get("slip")
        slip = "n/a" if e is None or e.value is None else f"{e.value:.6g} ± {e.std:.2g}"
        return (f"<Posterior ({self.method}): slip {slip}; sampled {', '.join(self.chain.names)}"
                f"; {self.n_marginalised} marginalised; "
                f"{'converged' if self.converged else 'NOT converged'}>")

    def _repr_html_(self) -> str:
        import html

        rows = "".join(f"<tr><td>{html.escape(k)}</td><td>{e.value:.6g}</td><td>{e.std:.2g}</td>"
                       f"</tr>" for k, e in self.estimates.items()
                       if e is not None and e.value is not None)
        return (f"<div><b>{html.escape(repr(self)[1:-1])}</b><table><tr><th>quantity</th>"
                f"<th>median</th><th>sd</th></tr>{rows}</table></div>")

    @property
    def parameters(self) -> tuple:
        return self.chain.names

    @property
    def converged(self) -> bool:
        return self.chain.converged

    def mcmc_json(self) -> dict:
        """The fit.json "mcmc" block (DATA.md), plus how it was obtained."""
        c = self.chain
        # a replacing slip law is sampled in whitened coordinates of its own (._reparam):
        # the chain's tau and ESS are of those, named z1..zn, not of the parameters
        labels = (list(c.names) if not self.coordinates
                  else [f"z{i + 1} (sampled, whitened)" for i in range(len(c.names))])
        tau = {k: _num(t) for k, t in zip(labels, c.tau)}
        ess = {k: _num(e) for k, e in zip(labels, c.ess)}
        slip_tau = autocorr_time(self.samples["slip"].reshape(c.samples.shape[:2])[..., None])
        kept = c.samples.shape[0]
        return {
            "walkers": int(c.walkers),
            "steps": int(c.steps),
            "burn_in": int(c.discard),
            "autocorr_time": _num(np.max(c.tau)),
            "ess": _num(np.min(c.ess)),
            "acceptance": _num(np.mean(c.acceptance)),
            "converged": bool(c.converged),
            "status": "converged" if c.converged else "not converged",
            "message": c.reason or (f"chain {kept / np.max(c.tau):.0f} tau long after burn-in; "
                                    f"ESS >= {np.min(c.ess):.0f} for every parameter"),
            "parameters": list(c.names),
            "autocorr_time_per_parameter": tau,
            "ess_per_parameter": ess,
            "ess_slip": _num(c.walkers * kept / float(slip_tau[0])),
            "method": self.method,
            "marginalised": (f"{self.n_marginalised} nuisance parameters, flat prior: "
                             "profiled by one Gauss-Newton step with their Jacobian at "
                             "theta"),
            "priors": {**{k: v for k, v in {**_POSITIVE, **_NONNEG}.items()
                          if k in c.names},
                       **({"s0/beta": f"C_rr + F_d/(m g) = s0 / (1000 g beta) >= {C_RR_MIN:g}"}
                          if "s0" in c.names and "beta" in c.names else {}),
                       "other": "flat"},
            "linearity_check": self.check,
            **({"coordinates": self.coordinates} if self.coordinates else {}),
            "tempering": {k: v for k, v in self.temper.items() if k != "cov"},
            "settings": self.settings,
            "seed": int(self.seed),
            "seconds": _num(self.seconds),
            "seconds_by_stage": {k: _num(v) for k, v in self.timings.items()},
        }

    def _groups(self, run_id=None) -> tuple[dict, dict]:
        """({group: {name: (walker, draw) array}}, root attrs) of :meth:`to_inference_data`
        and :meth:`save`."""
        import json

        c = self.chain
        shape = c.samples.shape[:2]  # (draws, walkers)
        post = {k: np.asarray(v).reshape(shape).T for k, v in self.samples.items()}
        attrs = {"inference_library": "emcee", "fitlug_method": self.method,
                 "converged": int(c.converged), "burn_in": int(c.discard),
                 "seed": int(self.seed), "sampled": ",".join(c.names),
                 "not_identifiable": json.dumps(self.not_identifiable),
                 **({"run_id": str(run_id)} if run_id is not None else {})}
        return {"posterior": post, "sample_stats": {"lp": np.asarray(c.log_prob).T}}, attrs

    def to_inference_data(self, run_id=None):
        """The samples as an ArviZ InferenceData, in memory.

        Returns:
            arviz.InferenceData: group ``posterior`` with every sampled parameter (``s0``,
            ``beta``, an effect's slip-law parameters) and derived quantity (``slip``,
            ``delta_l_mm``, ``stiffness_N_per_mm``, ``rolling_resistance``, ``k_over_m``)
            by name, dims (chain = walker, draw); ``sample_stats``: ``lp``. Its attrs say
            how it was made and which quantities the data do not fix (a JSON object
            ``not_identifiable``: name -> reason; their draws are kept, but their
            percentiles only echo the prior).
        """
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            import arviz as az

            groups, attrs = self._groups(run_id)
            return az.from_dict(**groups, attrs=attrs)

    def save(self, path, run_id=None) -> None:
        """Write the samples as a netCDF file (atomically), in the layout ArviZ writes
        :meth:`to_inference_data` in (:func:`fitlug.io.write_samples_netcdf`, without
        importing ArviZ); `run_id` (the fit-lug run that writes the folder) goes into its
        attrs. Read back with arviz.from_netcdf(path).
        """
        from ..io import write_samples_netcdf

        groups, attrs = self._groups(run_id)
        write_samples_netcdf(path, groups, attrs)


def _num(x):
    x = float(x)
    return x if math.isfinite(x) else None
