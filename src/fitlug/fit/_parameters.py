"""Parameters as objects (the lmfit habit): fix any parameter or element at a value, bound
it, or give it a prior; :func:`fitlug.fit` honours them without recompiling its solver
(:mod:`fitlug.fit._constrained`).

One name per parameter: the model's symbol (MODEL.md), e.g. ``R``, ``D``, ``s0``,
``beta``, ``cx`` (body-marker offsets, one element per body marker), an effect's own
parameter (``runout_a``); the fit.json key of the same number is accepted as an alias
(``R_mm``, ``s0_linear``). The derived ``k`` (stiffness_N_per_mm), ``C_rr``
(rolling_resistance) and ``m`` (the rig's mass) take priors only: a prior on k is a
pseudo-observation of k(beta) = 2 m / (1000 beta n L).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ._names import ALIASES, DERIVED

_KINDS = ("normal", "lognormal", "uniform")


@dataclass(frozen=True)
class Prior:
    """A prior on one parameter: ``Prior.normal(mean, sd)``, ``Prior.lognormal(median,
    sd_log)`` (sd of the natural log) or ``Prior.uniform(lo, hi)`` (a bound: flat inside).

    In the least squares a normal prior is one more residual (x - mean) / sd (a
    pseudo-observation), a log-normal one (ln x - ln median) / sd_log; in the posterior the
    same terms are added to the log density."""

    kind: str
    a: float
    b: float

    def __post_init__(self):
        if self.kind not in _KINDS:
            raise ValueError(f"prior kind must be one of {', '.join(_KINDS)}, got {self.kind!r}")
        a, b = float(self.a), float(self.b)
        if not (math.isfinite(a) and math.isfinite(b)):
            raise ValueError(f"{self.kind} prior: parameters must be finite, got {a}, {b}")
        if self.kind == "uniform" and not a < b:
            raise ValueError(f"uniform prior: lo < hi needed, got {a}, {b}")
        if self.kind != "uniform" and not b > 0:
            raise ValueError(f"{self.kind} prior: the spread must be > 0, got {b}")
        if self.kind == "lognormal" and not a > 0:
            raise ValueError(f"lognormal prior: the median must be > 0, got {a}")

    @classmethod
    def normal(cls, mean: float, sd: float) -> "Prior":
        return cls("normal", mean, sd)

    @classmethod
    def lognormal(cls, median: float, sd_log: float) -> "Prior":
        return cls("lognormal", median, sd_log)

    @classmethod
    def uniform(cls, lo: float, hi: float) -> "Prior":
        return cls("uniform", lo, hi)

    def as_dict(self) -> dict:
        keys = {"normal": ("mean", "sd"), "lognormal": ("median", "sd_log"),
                "uniform": ("lo", "hi")}[self.kind]
        return {"kind": self.kind, keys[0]: float(self.a), keys[1]: float(self.b)}

    def log_density(self, x):
        """Log density up to a constant (jnp or numpy), -inf outside a uniform prior."""
        import jax.numpy as jnp

        if self.kind == "normal":
            return -0.5 * ((x - self.a) / self.b) ** 2
        if self.kind == "lognormal":
            z = (jnp.log(jnp.maximum(x, 1e-300)) - math.log(self.a)) / self.b
            return jnp.where(x > 0, -0.5 * z ** 2 - jnp.log(jnp.maximum(x, 1e-300)), -jnp.inf)
        return jnp.where((x >= self.a) & (x <= self.b), 0.0, -jnp.inf)


class Parameter:
    """One named parameter: its value (start or fitted), which elements vary, bounds and a
    prior. Methods return the parameter, so calls chain: ``params["R"].fix(96.0)``.

    Attributes:
        name: the parameter's one name.
        value: float or array (mm, s, 1, ... as MODEL.md), or None for a derived quantity.
        vary: bool, or a bool array per element.
        min, max: bounds (None: unbounded), applied to every element.
        prior: a :class:`Prior` or None.
        std: the fit's standard error (fitted parameters only), else None.
    """

    def __init__(self, name: str, value=None, *, vary=True, min=None, max=None, prior=None,
                 derived: bool = False, std=None):
        self.name, self.derived = name, derived
        self.value = None if value is None else _num(value)
        if self.value is not None and np.ndim(self.value) and np.ndim(vary) == 0:
            vary = np.full(np.shape(self.value), bool(vary))
        self.vary = vary
        self.min, self.max, self.prior, self.std = min, max, prior, std

    # -- changes ------------------------------------------------------------------------
    def fix(self, value=None) -> "Parameter":
        """Hold the parameter (every element) at `value` (default: its current value)."""
        self._no_derived("fixed")
        if value is not None:
            self.value = _num(value) if np.ndim(self.value) == 0 else \
                np.broadcast_to(_num(value), np.shape(self.value)).astype(float).copy()
        self.vary = False if np.ndim(self.value) == 0 else np.zeros(np.shape(self.value), bool)
        return self

    def free(self) -> "Parameter":
        """Let every element vary again."""
        self._no_derived("freed")
        self.vary = True if np.ndim(self.value) == 0 else np.ones(np.shape(self.value), bool)
        return self

    def bound(self, min: float | None = None, max: float | None = None) -> "Parameter":
        """Keep the fitted value within [min, max] (None: open on that side)."""
        self._no_derived("bounded")
        if min is not None and max is not None and not min < max:
            raise ValueError(f"{self.name}: bounds need min < max, got {min}, {max}")
        self.min, self.max = min, max
        return self

    def set_prior(self, prior: Prior | None) -> "Parameter":
        """Put a :class:`Prior` on the parameter (None removes it); a uniform prior is a
        bound."""
        if prior is not None and not isinstance(prior, Prior):
            raise TypeError(f"{self.name}: prior must be a fitlug.Prior, got "
                            f"{type(prior).__name__}")
        if prior is not None and prior.kind == "uniform":
            if self.derived:
                raise ValueError(f"{self.name} is derived: it takes a normal or log-normal "
                                 "prior, not a uniform one (bound the fitted parameters)")
            self.bound(prior.a, prior.b)
        self.prior = prior
        return self

    def __getitem__(self, i) -> "_Element":
        if self.value is None or np.ndim(self.value) == 0:
            raise IndexError(f"{self.name} is a scalar: it has no elements")
        n = np.size(self.value)
        if not isinstance(i, (int, np.integer)) or not -n <= i < n:
            raise IndexError(f"{self.name} has elements 0..{n - 1}, got {i!r}")
        return _Element(self, int(i) % n)

    # -- reading ------------------------------------------------------------------------
    @property
    def is_fixed(self) -> bool:
        """Whether no element varies."""
        return not np.any(self.vary)

    @property
    def constrained(self) -> bool:
        """Whether anything is held, bounded or prior'd (what fit.json records)."""
        return (not self.derived and not np.all(self.vary)) or self.min is not None \
            or self.max is not None or self.prior is not None

    def as_dict(self) -> dict:
        """The JSON form fit.json records (fixed elements with their values)."""
        out = {}
        if not self.derived and not np.all(self.vary):
            v = np.asarray(self.value, float)
            out["fixed"] = float(v) if np.ndim(v) == 0 else \
                {str(i): float(v.flat[i]) for i in np.flatnonzero(~np.ravel(self.vary))}
        if self.min is not None:
            out["min"] = float(self.min)
        if self.max is not None:
            out["max"] = float(self.max)
        if self.prior is not None:
            out["prior"] = self.prior.as_dict()
        return out

    def __repr__(self) -> str:
        v = "derived" if self.value is None else (
            f"{float(self.value):.6g}" if np.ndim(self.value) == 0
            else f"array{tuple(np.shape(self.value))}")
        bits = [v]
        if not self.derived:
            bits.append("fixed" if self.is_fixed else
                        ("vary" if np.all(self.vary) else f"{int(np.sum(~np.asarray(self.vary)))} "
                                                          "elements fixed"))
        if self.std is not None and np.ndim(self.std) == 0:
            bits.append(f"std={float(self.std):.3g}")
        if self.min is not None or self.max is not None:
            bits.append(f"bounds=[{self.min}, {self.max}]")
        if self.prior is not None:
            bits.append(f"prior={self.prior.kind}({self.prior.a:g}, {self.prior.b:g})")
        return f"<Parameter {self.name}: {', '.join(bits)}>"

    def _no_derived(self, what):
        if self.derived:
            raise ValueError(f"{self.name} is derived from the fitted parameters: it takes a "
                             f"prior, it cannot be {what}")


class _Element:
    """One element of an array parameter (a body offset ``cx[1]``)."""

    def __init__(self, param: Parameter, i: int):
        self.param, self.i = param, i

    @property
    def value(self) -> float:
        return float(np.ravel(self.param.value)[self.i])

    def fix(self, value=None) -> Parameter:
        p = self.param
        p.value = np.array(p.value, float)
        if value is not None:
            p.value.flat[self.i] = float(value)
        p.vary = np.array(p.vary, bool)
        p.vary.flat[self.i] = False
        return p

    def free(self) -> Parameter:
        p = self.param
        p.vary = np.array(p.vary, bool)
        p.vary.flat[self.i] = True
        return p


class Parameters(dict):
    """Every parameter of a model by its one name (a dict of :class:`Parameter`); names
    from :data:`ALIASES` (fit.json's keys) are accepted in ``[]``.

    Made by :func:`fitlug.parameters` (start values of a recording) or read from a fit
    (``res.parameters``, fitted values and errors); passed back as
    ``fitlug.fit(rec, rig, params=params)``.
    """

    def __getitem__(self, name: str) -> Parameter:
        key = self.canonical(name)
        return dict.__getitem__(self, key)

    def canonical(self, name: str) -> str:
        """The one name of `name` (an alias resolved). Raises KeyError naming the valid
        names."""
        if not isinstance(name, str):
            raise TypeError(f"parameter names are strings, got {type(name).__name__}")
        key = ALIASES.get(name, name)
        if dict.__contains__(self, key):
            return key
        near = [k for k in self if k.lower() == key.lower()]
        hint = f" (did you mean {near[0]!r}?)" if near else ""
        raise KeyError(f"unknown parameter {name!r}{hint}; valid: {', '.join(self)}"
                       f" (aliases: {', '.join(a for a, k in ALIASES.items() if k in self)})")

    def __contains__(self, name) -> bool:
        return isinstance(name, str) and dict.__contains__(self, ALIASES.get(name, name))

    @property
    def constrained(self) -> dict:
        """{name: Parameter} of those held, bounded or prior'd."""
        return {k: p for k, p in self.items() if p.constrained}

    def as_json(self) -> dict:
        """{name: {fixed, min, max, prior}} of the constrained parameters (fit.json's
        "parameter_constraints")."""
        return {k: p.as_dict() for k, p in self.constrained.items()}

    def copy(self) -> "Parameters":
        out = Parameters()
        for k, p in self.items():
            q = Parameter(k, None if p.value is None else np.array(p.value, float),
                          vary=np.array(p.vary, bool) if np.ndim(p.vary) else p.vary,
                          min=p.min, max=p.max, prior=p.prior, derived=p.derived, std=p.std)
            if p.value is not None and np.ndim(p.value) == 0:
                q.value = float(p.value)
            dict.__setitem__(out, k, q)
        return out

    def __repr__(self) -> str:
        held = self.constrained
        return (f"<Parameters: {len(self)} ({', '.join(list(self)[:12])}"
                f"{', ...' if len(self) > 12 else ''}); constrained: "
                f"{', '.join(held) if held else 'none'}>")

    def _repr_html_(self) -> str:
        rows = "".join(f"<tr><td>{k}</td><td>{repr(p)[len(k) + 13:-1]}</td></tr>"
                       for k, p in self.items())
        return f"<table><tr><th>name</th><th>value, state</th></tr>{rows}</table>"


def _num(value):
    v = np.asarray(value, float)
    return float(v) if v.ndim == 0 else v.copy()


def parameters_of(p0: dict, free, *, fixed_in_fit=(), mass_kg=None) -> Parameters:
    """A :class:`Parameters` of parameter dict `p0` (`free`: the names a fit varies by
    default; the others held), plus the derived k and C_rr and the mass m."""
    out = Parameters()
    for k, v in p0.items():
        dict.__setitem__(out, k, Parameter(k, np.asarray(v, float), vary=k in set(free)))
    for k in DERIVED:
        dict.__setitem__(out, k, Parameter(k, None, derived=True))
    dict.__setitem__(out, "m", Parameter("m", None if mass_kg is None else float(mass_kg),
                                         derived=True))
    return out


def parameters_from_result(res) -> Parameters:
    """The :class:`Parameters` of a FitResult: fitted values, their standard errors, and
    the constraints it was fitted under (held, bounds, priors)."""
    spec = res.constraints
    out = parameters_of(res.params, free_names(res.problem.lay),
                        mass_kg=res.problem.rig.mass_kg)
    sd = np.sqrt(np.maximum(np.diag(res.cov), 0.0))
    for k, s in res.packing.slices().items():
        out[k].std = float(sd[s][0]) if np.ndim(res.params[k]) == 0 else sd[s].reshape(
            np.shape(res.params[k]))
        out[k].vary = bool(np.ndim(res.params[k]) == 0) or np.ones(np.shape(res.params[k]), bool)
    for k in res.params:
        if k not in res.packing.names:
            out[k].vary = False if np.ndim(res.params[k]) == 0 else \
                np.zeros(np.shape(res.params[k]), bool)
    if spec is not None:
        for k, p in spec.items():
            if k not in out:
                continue
            q = out[k]
            if not p.derived:
                q.vary = np.array(p.vary, bool) if np.ndim(p.vary) else bool(p.vary)
            q.min, q.max, q.prior = p.min, p.max, p.prior
    for k, key in DERIVED.items():
        e = res.quantities.get(key)
        if e is not None:
            out[k].value, out[k].std = e.value, e.std
    return out


def parameters(rec, rig=None, *, effects=(), noise=None) -> Parameters:
    """Every parameter of the model of `rec` on `rig` (plus `effects`), at the fit's
    data-derived start, for holding, bounding or putting priors on before
    ``fitlug.fit(rec, rig, params=...)``.

    Args:
        rec: Recording, pandas DataFrame or trajectory file path.
        rig: Rig, dict of its fields, rig.toml path, or None (the reference rig).
        effects: catalog effect ids whose parameters are included.
        noise: as in :func:`fitlug.fit`.

    Returns:
        Parameters: name -> Parameter; the derived k, C_rr and the mass m take priors.

    Raises:
        TypeError, ValueError, InputError: as :func:`fitlug.fit.build_problem`.
    """
    from ._problem import build_problem

    prob = build_problem(rec, rig, effects=effects, noise=noise)
    return parameters_of(prob.p0, free_names(prob.lay), mass_kg=prob.rig.mass_kg)


def free_names(lay) -> list[str]:
    """The parameters a fit of layout `lay` varies by default (all but those its effects
    hold: :func:`fitlug.fit.free_parameters`)."""
    from ..model import param_names
    from ..model.effects import CATALOG

    fixed = {k for e in lay.effects for k in CATALOG[e].fixed_in_fit}
    return [k for k in param_names(lay) if k not in fixed]
