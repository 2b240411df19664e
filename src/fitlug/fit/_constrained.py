"""The least-squares fit with a :class:`fitlug.fit.Parameters`: held elements, bounds and
priors, one compiled solver for every choice of them.

Mask, don't reshape: the free vector keeps every parameter the fit varies by default,
and the choices travel as arrays (:class:`Cons`) into one compiled program:

- a held element: its step is multiplied by 0 (a zero column of the solver's Jacobian; the
  damping keeps the step's system definite), its value set in the start; its covariance
  row and column are zero;
- a prior: one more residual per element, (x - mean) / sd (normal) or (ln x - ln median)
  / sd_log (log-normal), zero weight where none is set; k and C_rr (derived from beta and
  s0, MODEL.md §2) get one row each. The rows enter the covariance (a normal prior of sd
  s_p on a parameter the data measure to s_d gives 1 / s^2 = 1 / s_d^2 + 1 / s_p^2);
- a bound: one-sided stiff penalties (zero inside, like the slip law's physical range in
  :func:`fitlug.fit._lsq.bound_residuals`) steer the solver, the value is clipped into the
  bound at the end, and the covariance is that of the data and priors alone.

A second fit with another held set, bounds or priors reuses the compiled program (same
shapes); tests/test_library_api.py counts the compilations.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx

from .. import _exported
from .._errors import FitError
from ..model._physics import G
from ._covariance import covariance
from ._lsq import LARGE_ENTRIES, _START_GAIN, _column_scale, bound_residuals
from ._parameters import ALIASES, DERIVED, Parameters, free_names
from ._result import Estimate, FitResult, compute_quantities, not_converged
from ._residuals import Packing, jacobian, residuals
from ._trust import _levenberg_marquardt

_BIG = 1e300


class Cons(NamedTuple):
    """The held elements, bounds and priors of one packing, as arrays (traced)."""

    mask: jax.Array  # (n,) 1 varies, 0 held
    lo: jax.Array  # (n,) bounds (+-1e300: open)
    hi: jax.Array
    bscale: jax.Array  # (n,) a bound's violation in these units costs 1 in the residuals
    mu: jax.Array  # (n,) prior centre (ln median for log-normal)
    isd: jax.Array  # (n,) 1 / prior sd (0: no prior)
    logp: jax.Array  # (n,) 1 for a log-normal prior
    dmu: jax.Array  # (2,) priors of k, C_rr
    disd: jax.Array
    dlog: jax.Array
    mass: jax.Array  # () kg (0: none)
    pull: jax.Array  # () N


def constraints_for(spec: Parameters, p0: dict, packing: Packing, lay, mass_kg,
                    pull_N) -> tuple[dict, Cons]:
    """(start with the held values set, the :class:`Cons` of `spec` on `packing`).

    Raises ValueError for a prior on k without the rig's mass, or a held value outside
    its bounds."""
    p0 = {k: np.array(v, float) for k, v in p0.items()}
    n = int(sum(packing.sizes))
    a = {k: np.zeros(n) for k in ("mu", "isd", "logp")}
    mask, lo, hi = np.ones(n), np.full(n, -_BIG), np.full(n, _BIG)
    sl = packing.slices()
    for name, par in spec.items():
        if par.derived or name not in p0:
            continue
        vary = np.asarray(par.vary, bool)
        if vary.ndim and vary.shape != np.shape(p0[name]):
            if not vary.all():  # elements held on another layout (another knot count)
                raise ValueError(f"params: {name} has {vary.size} elements in the given "
                                 f"Parameters but {np.size(p0[name])} in this model")
            vary = np.ones((), bool)
        held = ~np.broadcast_to(vary, np.shape(p0[name]))
        if np.any(held) and par.value is not None and np.size(par.value) in (1, held.size):
            v = np.broadcast_to(np.asarray(par.value, float), np.shape(p0[name]))
            p0[name] = np.where(held, v, p0[name])
        if name not in sl:
            continue  # held by the model (an effect's gauge): values set, nothing varies
        s = sl[name]
        mask[s] = np.where(np.ravel(held), 0.0, 1.0)
        if par.min is not None:
            lo[s] = par.min
        if par.max is not None:
            hi[s] = par.max
        pr = par.prior
        if pr is not None and pr.kind != "uniform":
            a["mu"][s] = np.log(pr.a) if pr.kind == "lognormal" else pr.a
            a["isd"][s] = 1.0 / pr.b
            a["logp"][s] = float(pr.kind == "lognormal")
    flat0 = np.asarray(packing.pack(p0))
    bad = (mask == 0) & ((flat0 < lo) | (flat0 > hi))
    if np.any(bad):
        raise ValueError(f"a held value lies outside its bounds (element {int(np.argmax(bad))}"
                         " of the packed parameters)")
    d = {k: np.zeros(2) for k in ("dmu", "disd", "dlog")}
    for j, name in enumerate(DERIVED):
        pr = spec[name].prior if name in spec else None
        if pr is None or pr.kind == "uniform":
            continue
        if name == "k" and mass_kg is None:
            raise ValueError("a prior on k needs the rig's mass (Rig(mass_kg=...)): without "
                             "it only k/m is identifiable")
        d["dmu"][j] = np.log(pr.a) if pr.kind == "lognormal" else pr.a
        d["disd"][j] = 1.0 / pr.b
        d["dlog"][j] = float(pr.kind == "lognormal")
    if d["disd"].any() and "beta" in sl and float(np.ravel(p0["beta"])[0]) <= 0:
        # beta = 0 (the default start) is k = inf: start at the prior's k (or C_rr)
        n_L = float(lay.n_contact) * float(lay.L)
        k_mu = np.exp(d["dmu"][0]) if d["dlog"][0] else d["dmu"][0]
        c_mu = np.exp(d["dmu"][1]) if d["dlog"][1] else d["dmu"][1]
        if d["disd"][0] and k_mu > 0:
            p0["beta"] = np.full(np.shape(p0["beta"]), 2.0 * mass_kg / (1000.0 * k_mu * n_L))
        elif c_mu > 0:
            s0 = float(np.ravel(p0["s0"])[0])
            p0["beta"] = np.full(np.shape(p0["beta"]), s0 / (1000.0 * G * c_mu))
        flat0 = np.asarray(packing.pack(p0))
    span = np.where((lo > -_BIG) & (hi < _BIG), hi - lo, 0.0)
    bscale = 1e-6 * np.maximum.reduce([np.abs(flat0), np.abs(np.where(lo > -_BIG, lo, 0)),
                                       np.abs(np.where(hi < _BIG, hi, 0)), span,
                                       np.full(n, 1e-12)])
    f = lambda x: jnp.asarray(x, float)  # noqa: E731
    cons = Cons(f(mask), f(lo), f(hi), f(bscale), f(a["mu"]), f(a["isd"]), f(a["logp"]),
                f(d["dmu"]), f(d["disd"]), f(d["dlog"]), f(mass_kg or 0.0), f(pull_N or 0.0))
    return p0, cons


def _log_or_not(x, logp):
    return jnp.where(logp > 0, jnp.log(jnp.maximum(x, 1e-300)), x)


def prior_rows(flat, fixed, lay, cons: Cons, packing: Packing):
    """(n + 2,) the prior residuals: every packed element, then k and C_rr."""
    own = (_log_or_not(flat, cons.logp) - cons.mu) * cons.isd
    p = packing.unpack(flat, fixed)
    # without a prior on k or C_rr their rows must not put 0 * inf into the Jacobian at
    # beta = 0 (the fit's start): beta enters only where a prior is set (double where)
    beta = jnp.where(jnp.any(cons.disd > 0), jnp.ravel(p["beta"])[0], 1.0)
    beta = jnp.where(jnp.abs(beta) > 1e-12, beta, 1e-12)
    s0 = jnp.ravel(p["s0"])[0]
    k = cons.mass * 2.0 / (1000.0 * beta * lay.n_contact * lay.L)
    crr = s0 / (1000.0 * G * beta) - cons.pull / (jnp.maximum(cons.mass, 1e-300) * G)
    dq = (_log_or_not(jnp.stack([k, crr]), cons.dlog) - cons.dmu) * cons.disd
    return jnp.concatenate([own, dq])


def _bound_rows(flat, cons: Cons):
    return jnp.concatenate([jax.nn.relu(flat - cons.hi) / cons.bscale,
                            jax.nn.relu(cons.lo - flat) / cons.bscale])


@eqx.filter_jit
def _solve(flat0, fixed, lay, obs, cons: Cons, packing: Packing, max_steps: int,
           rtol: float, atol: float):
    def r_data(f):
        return residuals(packing.unpack(f, fixed), lay, obs)

    def extra(f):
        return prior_rows(f, fixed, lay, cons, packing)

    J0 = jnp.concatenate([jacobian(flat0, fixed, lay, obs, packing), jax.jacfwd(extra)(flat0)])
    scale = _column_scale(J0) * _START_GAIN * cons.mask
    atol = atol / _START_GAIN
    slip_range = "s0" in packing.names and "beta" in packing.names

    def fn(z, _):
        f = flat0 + z * scale
        parts = [r_data(f), extra(f), _bound_rows(f, cons)]
        if slip_range:
            parts.append(bound_residuals(packing.unpack(f, fixed)))
        return jnp.concatenate(parts)

    solver = _levenberg_marquardt(rtol, atol, lx.Normal(lx.Cholesky()))
    sol = optx.least_squares(fn, solver, jnp.zeros_like(flat0), max_steps=max_steps,
                             throw=False)
    flat = jnp.clip(flat0 + sol.value * scale, cons.lo, cons.hi)
    J = jacobian(flat, fixed, lay, obs, packing) * cons.mask
    Je = jax.jacfwd(extra)(flat) * cons.mask
    ok = sol.result == optx.RESULTS.successful
    return flat, J, Je, r_data(flat), extra(flat), ok, sol.stats["num_steps"]


def solve(p0: dict, packing: Packing, lay, obs, cons: Cons, *, max_steps: int = 200,
          rtol: float = 1e-8, atol: float = 1e-6):
    """One constrained solve: (params, flat, J (held columns 0), J of the prior rows,
    data residuals, prior residuals, converged, steps)."""
    fixed = {k: jnp.asarray(v, float) for k, v in p0.items() if k not in packing.names}
    flat, J, Je, r, re, ok, steps = _exported.call(
        "lsq_solve_constrained", _solve, (packing, max_steps, rtol, atol),
        packing.pack(p0), fixed, lay, obs, cons)
    flat = np.asarray(flat)
    params = packing.unpack(flat, {k: np.asarray(v) for k, v in fixed.items()})
    return (params, flat, np.asarray(J), np.asarray(Je), np.asarray(r), np.asarray(re),
            bool(ok), int(steps))


def check_spec(spec, names) -> None:
    """Raise TypeError/ValueError when `spec` is no Parameters or names no parameter of
    `names` (the model's) or the derived ones."""
    if not isinstance(spec, Parameters):
        raise TypeError(f"params: expected fitlug.Parameters (fitlug.parameters(rec, rig) or "
                        f"res.parameters), got {type(spec).__name__}")
    valid = set(names) | set(DERIVED) | {"m"}
    unknown = [k for k in spec if k not in valid]
    if unknown:
        raise ValueError(f"params: unknown parameter {unknown[0]!r}; valid: "
                         f"{', '.join(sorted(valid))} (aliases: {', '.join(ALIASES)})")


def fit_constrained(prob, p_start, spec: Parameters, *, free=None, max_steps: int = 300,
                    require_convergence: bool = True, hold_beta_first: bool = True):
    """:func:`fitlug.fit.fit_problem` under `spec`'s held elements, bounds and priors."""
    p0 = dict(prob.p0 if p_start is None else p_start)
    free = free_names(prob.lay) if free is None else list(free)
    check_spec(spec, p0)
    packing = Packing.of(p0, free)
    n_res = 2 * (prob.lay.lug_t.shape[0] + prob.lay.body_t.shape[0])
    if n_res * sum(packing.sizes) > LARGE_ENTRIES:
        raise FitError(f"{prob.rec.path or 'recording'}: params= (held elements, bounds, "
                       "priors) is not yet supported on recordings long enough for the "
                       "chunked solver")
    p0, cons = constraints_for(spec, p0, packing, prob.lay, prob.rig.mass_kg,
                               prob.rig.drawbar_pull_N)
    held_steps = 0
    sl = packing.slices()
    if p_start is None and hold_beta_first and "beta" in sl and float(cons.mask[sl["beta"]][0]):
        # as fit_problem: beta held at first (issue 26), by its mask: the same program
        held = solve(p0, packing, prob.lay, prob.obs,
                     cons._replace(mask=cons.mask.at[sl["beta"]].set(0.0)), max_steps=max_steps)
        if np.all(np.isfinite(held[4])):
            p0 = {**p0, **held[0]}
            held_steps = held[7]
    params, flat, J, Je, r, re, ok, steps = solve(p0, packing, prob.lay, prob.obs, cons,
                                                  max_steps=max_steps)
    cov = covariance(np.vstack([J, Je]))
    fixed = {k: v for k, v in params.items() if k not in packing.names}
    q = compute_quantities(params, packing, flat, cov, prob.lay, prob.rig.mass_kg, fixed,
                           prob.rig.drawbar_pull_N)
    _mass_prior(q, spec)
    held_mask = np.asarray(cons.mask) == 0
    chi2 = float(np.sum(r ** 2))
    res = FitResult(problem=prob, params={k: np.asarray(v) for k, v in params.items()},
                    packing=packing, flat=flat, cov=cov, residuals=r, chi2=chi2,
                    dof=prob.n_valid - int(np.sum(~held_mask)), converged=ok,
                    steps=steps + held_steps, quantities=q, constraints=spec.copy(),
                    held=held_mask, prior_chi2=float(np.sum(re ** 2)))
    if require_convergence and not (ok and np.isfinite(chi2)):
        raise not_converged(res, steps, "check the marker roles, the rig file and the "
                            "parameters' constraints")
    return res


def _mass_prior(q: dict, spec: Parameters) -> None:
    """Widen k's error by the rig mass's own (a normal prior on m: relative errors add in
    quadrature, k = m (k/m))."""
    pr = spec["m"].prior if "m" in spec else None
    e = q.get("stiffness_N_per_mm")
    if pr is None or e is None or pr.kind != "normal" or e.value is None:
        return
    rel = pr.b / pr.a
    q["stiffness_N_per_mm"] = Estimate(e.value, float(np.hypot(e.std, abs(e.value) * rel)))
