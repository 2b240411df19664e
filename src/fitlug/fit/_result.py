"""The outcome of a least-squares fit: parameters, uncertainties, derived physics."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import FitError
from ..model import belt_length, steady_slip
from ..model._physics import G
from ..model.effects import CATALOG
# GROSS_MISFIT: chi^2/dof above which a fit that did not converge is far from the data
from ._trust import GROSS_MISFIT

Z95 = 1.959963984540054


@dataclass
class Estimate:
    """A value with its standard error and 95 % interval (normal, or from the posterior)."""

    value: float | None
    std: float | None
    ci95: tuple | None = None
    #: why value is None: the data cannot fix the quantity (not identifiable)
    reason: str | None = None

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


def _no_pull(F) -> bool:
    """Whether no drawbar pull is given: None or zero (a traced pull is a given one)."""
    return F is None or (not isinstance(F, jax.core.Tracer) and not np.any(np.asarray(F)))


def derived(p: dict, lay, mass_kg, drawbar_N: float = 0.0) -> dict:
    """Physical quantities of one parameter set (JAX scalars), see MODEL.md §2.

    With a drawbar pull F_d the steady traction is m C_rr g + F_d, so s0 / (1000 g beta)
    = C_rr + F_d / (m g): C_rr then needs the mass (left out without one); k / m does not
    depend on F_d.
    """
    n, L = lay.n_contact, lay.L
    P = belt_length(p["R"], p["D"])
    crr_plus = p["s0"] / (1000.0 * G * p["beta"])  # C_rr + F_d / (m g)
    out = {
        "slip": steady_slip(p, lay),
        "delta_l_mm": p["s0"] * L / (n - 1),
        "k_over_m": 2.0 / (1000.0 * p["beta"] * n * L),
        "R_mm": p["R"], "D_mm": p["D"], "e_mm": p["e"], "pitch_mm": P / lay.n_belt,
        "s0_linear": p["s0"], "beta": p["beta"],
    }
    if _no_pull(drawbar_N):
        out["rolling_resistance"] = crr_plus
    elif mass_kg is not None:
        out["rolling_resistance"] = crr_plus - drawbar_N / (mass_kg * G)
    if mass_kg is not None:
        out["stiffness_N_per_mm"] = mass_kg * out["k_over_m"]
        # steady traction F0 = m C_rr g + F_d = m s0 / (1000 beta)  (N)
        out["traction_N"] = mass_kg * p["s0"] / (1000.0 * p["beta"])
    return out


@dataclass
class FitResult:
    """Least-squares fit of one recording under a set of effects.

    Attributes:
        problem: the :class:`fitlug.fit.Problem` fitted (recording, rig, layout, weights).
        params: name -> fitted value (float64 arrays; names as :class:`fitlug.Parameters`).
        packing: how the varying parameters pack into `flat` (names, shapes).
        flat: the packed parameter vector (held elements included, at their values).
        cov: covariance of `flat` (packing order; labelled: :meth:`covariance_frame`).
        residuals: weighted residuals (model - data) / sigma, lug x, lug y, body x, body y
            (labelled: :meth:`residuals_frame`).
        chi2, dof: sum of squared residuals (the data's, without priors) and degrees of
            freedom (valid coordinates - varying parameters).
        converged, steps: the solver's outcome.
        quantities: name -> :class:`Estimate` (slip, delta_l_mm, stiffness_N_per_mm,
            rolling_resistance, k_over_m, R_mm, D_mm, e_mm, pitch_mm, s0_linear, beta,
            traction_N), delta-method errors.
        robust: set by fitlug.explain when the misfit stays unexplained (widened errors).
        constraints: the :class:`fitlug.Parameters` of ``fit(..., params=)``, or None.
        held: bool per element of `flat`, True where held (None: nothing held).
        prior_chi2: the priors' pseudo-observations' chi^2 (0 without priors).
    """

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
    # fitted under fitlug.fit(..., params=): the user's Parameters, which packed elements
    # were held (bool per element of flat) and the priors' chi^2 (not in chi2)
    constraints: object = None
    held: np.ndarray | None = None
    prior_chi2: float = 0.0

    @property
    def parameters(self):
        """Every parameter by name (:class:`fitlug.Parameters`): fitted values, standard
        errors, and the held elements, bounds and priors of the fit; pass it back as
        ``fitlug.fit(rec, rig, params=res.parameters)``."""
        from ._parameters import parameters_from_result

        return parameters_from_result(self)

    # -- labelled views (fitlug.fit._labelled) ----------------------------------------
    def covariance_frame(self):
        """Covariance of the fitted parameters, a pandas DataFrame labelled by element
        (``R``, ``v[3]``, ``cx[1]``; held elements: zero rows and columns)."""
        from ._labelled import covariance_frame

        return covariance_frame(self)

    def correlation(self):
        """Correlation matrix of the fitted parameters, labelled (DataFrame)."""
        from ._labelled import correlation_frame

        return correlation_frame(self)

    def residuals_frame(self):
        """Residuals (model - data) per sample and axis, raw (mm) and standardised, as a
        tidy DataFrame: time_s, marker, role, axis, raw_mm, standardised, sigma_mm, used."""
        from ._labelled import residuals_frame

        return residuals_frame(self)

    def residuals_by_marker(self) -> dict:
        """{marker: {'role', 't', 'x', 'y', 'x_std', 'y_std'}}: the residuals as arrays
        (raw in mm, and standardised), per marker in time order."""
        from ._labelled import residual_arrays

        return residual_arrays(self)

    def summary(self, explanation=None, posterior=None) -> str:
        """The text `fit-lug` prints on the terminal for this fit (:func:`fitlug.summary`)."""
        import importlib

        # the report stage formats it (fit.json's fields): imported on call, downstream
        return importlib.import_module("fitlug.report").summary(
            self, explanation=explanation, posterior=posterior)

    def __repr__(self) -> str:
        from ._labelled import short_repr

        return short_repr(self)

    def _repr_html_(self) -> str:
        from ._labelled import html_table

        return html_table(self)

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
        held = 0 if self.held is None else int(np.sum(self.held))
        return len(self.flat) - held + extra

    @property
    def n_data(self) -> int:
        return self.problem.n_valid

    @property
    def slip(self) -> Estimate:
        return self.quantities["slip"]

    def predict(self, times, markers=None, *, extrapolate: bool = False):
        """The fitted model's marker positions at any times, with 1 σ bands.

        Args:
            times: 1-D times, s, inside the recording (the span of its fitted samples).
            markers: a marker name or names (the recording's spelling); None: every
                fitted marker.
            extrapolate: evaluate outside the recording too (speed and acceleration held
                at the edge of the fit: a guess, not a measurement).

        Returns:
            A :class:`fitlug.fit.Prediction`: x, y and their standard errors (delta method
            from this fit's covariance), mm, one row per marker; ``to_dataframe()``.

        Raises:
            ValueError: a time outside the recording (naming its range) without
                ``extrapolate=True``, or an unknown marker (naming the fitted ones).
        """
        from ._predict import predict_positions

        return predict_positions(self, times, markers, extrapolate=extrapolate)

    def slip_at(self, times, *, extrapolate: bool = False):
        """The model's slip s(t) = 1 - v / v_t at any times, with its 1 σ band.

        Args:
            times: 1-D times, s, inside the recording.
            extrapolate: as in :meth:`predict`.

        Returns:
            A :class:`fitlug.fit.Band` (t, value, std; ``ci95``): NaN where the robot is at
            rest (body speed under 5 % of its peak: the slip is undefined there). The
            band is the statistical error of this fit; where the true acceleration jumps
            (the end of a ramp) the speed spline smooths it, a bias of order beta times
            the jump that the band does not include.

        Raises:
            ValueError: a time outside the recording without ``extrapolate=True``.
        """
        from ._predict import slip_at

        return slip_at(self, times, extrapolate=extrapolate)

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


    def effect_identifiability(self, effect_id: str, tol: float = 1e-8) -> dict:
        """Reported parameters of an effect the data cannot fix here: {name: reason}.

        Decided from the Fisher information: for each of the effect's model parameters,
        held or fitted, the information left in its Jacobian column once every other
        fitted parameter has taken its share, |P_perp J_k|^2, against its own |J_k|^2. A
        ratio below `tol` means the data cannot tell it from the others (or it does not
        act at all: zero column): its reported counterparts are not identifiable. Covers
        a parameter held by convention because the geometry makes it degenerate (B of
        body_bounce with one body marker) and a free one at a degenerate geometry.
        """
        from ._covariance import _residuals_jacobian
        from ._residuals import Packing

        eff = CATALOG[effect_id]
        p = {k: jnp.asarray(v, float) for k, v in self.params.items()}
        internal = [k for k in eff.defaults if k in p and np.ndim(p[k]) == 0
                    and k not in eff.fixed_in_fit]
        if not internal:
            return {}
        held = [k for k in internal if k not in self.packing.names]
        pk = Packing.of(p, set(self.packing.names) | set(held))
        fixed = {k: v for k, v in p.items() if k not in pk.names}
        prob = self.problem
        # compiled (eagerly, op by op, this Jacobian cost ~5 s of fit.json's writing on a
        # drive-through's lug_sliding fit: hundreds of one-primitive programs lowered)
        J = np.asarray(_residuals_jacobian(pk.pack(p), fixed, prob.lay, prob.obs, pk)[1])
        sl = pk.slices()
        fitted = np.concatenate([np.arange(sl[k].start, sl[k].stop) for k in pk.names
                                 if k not in held])
        weak = {}
        for k in internal:
            i = sl[k].start
            others = fitted[fitted != i]  # against the fitted parameters only
            jk = J[:, i]
            nk = float(jk @ jk)
            A = J[:, others]
            sc = 1.0 / np.maximum(np.linalg.norm(A, axis=0), 1e-300)
            As = A * sc
            coef, *_ = np.linalg.lstsq(As, jk, rcond=1e-12)
            left = jk - As @ coef
            ratio = float(left @ left) / nk if nk > 0 else 0.0
            if ratio < tol:
                weak[k] = ratio
        if not weak:
            return {}
        base = {k: np.asarray(v, float) for k, v in self.params.items()}
        rep0 = eff.report(base)
        out = {}
        for k, ratio in weak.items():
            h = max(eff.scales.get(k, 1.0), 1e-9 * abs(float(base[k])))
            q = dict(base)
            q[k] = base[k] + h
            rep = eff.report(q)
            for name, v0 in rep0.items():
                v1 = rep.get(name)
                if v0 is None or v1 is None or abs(v1 - v0) > 1e-12 * max(abs(v0), 1e-300):
                    how = ("held by the fit: " if k in held else "")
                    out[name] = (f"{how}the data carry no information on {k} at this "
                                 f"geometry: its effect on the markers is that of other "
                                 f"parameters (information left {ratio:.1e} of its own, "
                                 f"threshold {tol:.0e})")
        return out


@eqx.filter_jit
def _derived_with_jacobian(flat, packing, fixed, lay, mass, pull, has_mass: bool,
                           has_pull: bool):
    """:func:`derived` and its Jacobian in the free vector, in one compiled program (run
    op by op they cost ~20 small compilations, each a persistent-cache read, per fit)."""
    def f(fl):
        return derived(packing.unpack(fl, fixed), lay, mass if has_mass else None,
                       pull if has_pull else 0.0)

    return f(flat), jax.jacfwd(f)(flat)


def _derived_exported(flat, fixed, lay, mass, pull, packing, has_mass: bool, has_pull: bool):
    """:func:`_derived_with_jacobian` with its static arguments last (fitlug._exported)."""
    return _derived_with_jacobian(flat, packing, fixed, lay, mass, pull, has_mass, has_pull)


def compute_quantities(res_params, packing, flat, cov, lay, mass_kg, fixed,
                       drawbar_N: float = 0.0) -> dict:
    """Each derived quantity with its delta-method standard error."""
    fixed = {k: jnp.asarray(v, float) for k, v in fixed.items()}
    # the mass and pull as traced numbers (a campaign's recordings share one program);
    # whether they are given is static
    # on bucketed shapes (fit._buckets: a recording of a new length compiles nothing new)
    from ._buckets import pad

    pb = pad(flat, fixed, lay, {}, packing)
    args = (pb.flat, pb.packing, pb.fixed, pb.lay) if pb else (jnp.asarray(flat, float),
                                                               packing, fixed, lay)
    from .. import _exported  # a module kept on disk: a new process skips its tracing

    vals, jac = _exported.call("derived", _derived_exported,
                               (args[1], mass_kg is not None, bool(drawbar_N)), args[0], args[2],
                               args[3], jnp.asarray(mass_kg or 0.0, float),
                               jnp.asarray(drawbar_N or 0.0, float))
    out = {}
    for k, v in vals.items():
        g = np.asarray(jac[k]) if pb is None else np.asarray(jac[k])[pb.cols]
        with np.errstate(invalid="ignore"):  # k = inf at beta = 0: no error (not identifiable)
            var = float(g @ cov @ g)
        out[k] = Estimate(float(v), float(np.sqrt(max(var, 0.0))))
    from ._identifiable import mark_not_identifiable

    return mark_not_identifiable(out, Estimate)


def not_converged(res: FitResult, steps: int, advice: str) -> FitError:
    """The error of a fit `res` that did not converge after `steps` steps: `advice` (what to
    check), and at a gross misfit that the model is far from the data."""
    gross = np.isfinite(res.chi2) and res.chi2_per_dof > GROSS_MISFIT
    return FitError(f"{res.problem.rec.path or 'recording'}: the least-squares fit did not "
                    f"converge after {steps} steps (chi2/dof = {res.chi2_per_dof:.3g}); "
                    + (f"the model is far from the data: {advice}, or for physics the base "
                       "model cannot bend to (lugs sliding at a high load)" if gross
                       else advice))

