"""The outcome of a least-squares fit: parameters, uncertainties, derived physics."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

from ..model import belt_length, steady_slip
from ..model._physics import G
from ..model.effects import CATALOG

Z95 = 1.959963984540054


@dataclass
class Estimate:
    """A value with its standard error and 95 % interval (normal, or from the posterior)."""

    value: float | None
    std: float | None
    ci95: tuple | None = None

    def __post_init__(self):
        if self.ci95 is None and self.value is not None and self.std is not None:
            self.ci95 = (self.value - Z95 * self.std, self.value + Z95 * self.std)

    def as_dict(self) -> dict | None:
        if self.value is None:
            return None
        return {"value": _f(self.value), "std": _f(self.std),
                "ci95": None if self.ci95 is None else [_f(c) for c in self.ci95]}


def _f(x):
    if x is None:
        return None
    x = float(x)
    return x if np.isfinite(x) else None


def derived(p: dict, lay, mass_kg) -> dict:
    """Physical quantities of one parameter set (JAX scalars), see MODEL.md §2."""
    n, L = lay.n_contact, lay.L
    P = belt_length(p["R"], p["D"])
    out = {
        "slip": steady_slip(p, lay),
        "delta_l_mm": p["s0"] * L / (n - 1),
        "rolling_resistance": p["s0"] / (1000.0 * G * p["beta"]),
        "k_over_m": 2.0 / (1000.0 * p["beta"] * n * L),
        "R_mm": p["R"], "D_mm": p["D"], "e_mm": p["e"], "pitch_mm": P / lay.n_belt,
        "s0_linear": p["s0"], "beta": p["beta"],
    }
    if mass_kg is not None:
        out["stiffness_N_per_mm"] = mass_kg * out["k_over_m"]
    return out


@dataclass
class FitResult:
    """Least-squares fit of one recording under a set of effects."""

    problem: object
    params: dict
    packing: object
    flat: np.ndarray
    cov: np.ndarray  # covariance of the free parameters (packing order)
    residuals: np.ndarray  # weighted, (2 S_l + 2 S_b,)
    chi2: float
    dof: int
    converged: bool
    steps: int
    quantities: dict = field(default_factory=dict)  # name -> Estimate
    # set by fitlug.explain when the verdict is 'unexplained': how the quantities' errors
    # were widened (cluster-robust), see fitlug.explain._robust.robust_result
    robust: dict | None = None

    @property
    def chi2_per_dof(self) -> float:
        return self.chi2 / max(self.dof, 1)

    @property
    def effects(self) -> tuple:
        return self.problem.lay.effects

    @property
    def n_params(self) -> int:
        """Free parameters (discrete choices such as frame_drop's t* included)."""
        extra = sum(CATALOG[e].n_free(self.problem.lay.n_body)
                    - (len(CATALOG[e].defaults) - len(CATALOG[e].fixed_in_fit))
                    for e in self.effects)
        return len(self.flat) + extra

    @property
    def n_data(self) -> int:
        return self.problem.n_valid

    @property
    def slip(self) -> Estimate:
        return self.quantities["slip"]

    def effect_params(self, effect_id: str) -> dict:
        return CATALOG[effect_id].report({k: np.asarray(v) for k, v in self.params.items()})

    def effect_params_std(self, effect_id: str) -> dict:
        """Standard errors of :meth:`effect_params` (delta method through the effect's
        `report`, central differences in its fitted parameters; held ones count as exact)."""
        eff = CATALOG[effect_id]
        base = {k: np.asarray(v, float) for k, v in self.params.items()}
        sl = self.packing.slices()
        free = [k for k in eff.defaults if k in sl]
        idx = [sl[k].start for k in free]
        rep0 = eff.report(base)
        if not free:
            return {k: 0.0 if v is not None else None for k, v in rep0.items()}
        grads = {k: np.zeros(len(free)) for k in rep0}
        for j, name in enumerate(free):
            sd = float(np.sqrt(max(self.cov[idx[j], idx[j]], 0.0)))
            h = max(1e-3 * sd, 1e-9 * max(abs(float(base[name])), eff.scales.get(name, 1.0)))
            outs = []
            for sgn in (1.0, -1.0):
                q = dict(base)
                q[name] = base[name] + sgn * h
                outs.append(eff.report(q))
            for k in rep0:
                a, b = outs[0][k], outs[1][k]
                if a is None or b is None or rep0[k] is None:
                    grads[k] = None
                elif grads[k] is not None:
                    d = a - b
                    if "phi" in k:  # an angle: the short way round
                        d = math.remainder(d, 2 * math.pi)
                    grads[k][j] = d / (2 * h)
        C = self.cov[np.ix_(idx, idx)]
        return {k: (None if g is None else float(np.sqrt(max(g @ C @ g, 0.0))))
                for k, g in grads.items()}


def compute_quantities(res_params, packing, flat, cov, lay, mass_kg, fixed) -> dict:
    """Each derived quantity with its delta-method standard error."""
    def f(fl):
        return derived(packing.unpack(fl, fixed), lay, mass_kg)

    vals = f(jnp.asarray(flat))
    jac = jax.jacfwd(f)(jnp.asarray(flat))
    out = {}
    for k, v in vals.items():
        g = np.asarray(jac[k])
        var = float(g @ cov @ g)
        out[k] = Estimate(float(v), float(np.sqrt(max(var, 0.0))))
    return out
