"""The posterior of the slippage: emcee over the slip-law parameters, the rest marginalised.

What is sampled. The data pin the slip law, theta = (s0, beta) (plus the parameters of a
replacing law, e.g. lug_sliding's slide_mu); k/m = 2 / (1000 beta n L), C_rr =
s0 / (1000 g beta), dl' = s0 L / (n - 1) and the steady slip follow per sample. The ~70
other parameters eta (speed spline, marker phases, offsets, geometry, effect params) are
marginalised linearly: around the least-squares optimum r(theta, eta) ~ r(theta, eta_hat)
+ J_eta (eta - eta_hat), and with a flat prior on eta

    -2 log L(theta) = |P r(theta, eta_hat)|^2 + const,   P = I - J_eta J_eta^+ .

Two evaluations of this marginal. 'exact' evaluates the full model at theta with eta moved
by one Gauss-Newton step from eta_hat, eta_hat - M(theta)^+ J_eta(theta)^T r(theta,
eta_hat) with M = J_eta(theta)^T J_eta(theta), and takes chi^2 there: the profile
min_eta chi^2 to second order, where |P r(theta, eta_hat)|^2 is its linear prediction
(that prediction leaves out the curvature of r along the step, which grows with the
recording: a slip-law change shifts the belt phase of every later sample; at 30 000
frames it put the beta axis up to 0.8 off the Gaussian, the step 2e-4). The nuisance
Jacobian is taken at theta, not at the optimum: a cruise-only recording leaves beta
nearly free, and J_eta changes by its own size along it, so a step with J_eta(theta_hat)
lands far off the profile (2026-11-25 and -26: Delta chi^2 134 for a profile of 5.6, k
declared identifiable with a false interval; cruise s0 covered 90 %). J_eta(theta) comes
from a model built once (J_eta is linear in theta to 1e-3 in chi^2 along a whole cruise
ridge): interpolated linearly from its values at d + 1 points, whose products with r
and with each other give b and M (_Marginal._step_model). Two passes of the model per
theta, vmapped over walkers (the linear prediction alone: ~0.9 ms CPU per walker and step
on the reference recording, ~10 s of CPU for a converged chain; so the exact chain is
over the report's time target on its own).
'gaussian' is its Gaussian limit, r linear in theta too: -2 log L = (theta - theta_hat)^T
F (theta - theta_hat), F = J_theta^T P J_theta, which costs microseconds. On the reference
recording the two give the same median (to 1e-5 sigma) and std (to 0.4 %).
method='auto' (default) evaluates the exact marginal at 2-sigma points around the
optimum (principal axes and diagonals) and uses the Gaussian limit only when it agrees
to `LINEARITY_TOL` in delta-chi^2 everywhere there; otherwise it samples the exact
marginal under the time budget. The check's largest discrepancy is reported.

When fitlug.explain leaves a misfit unexplained (res.robust set), the white-noise
likelihood is orders of magnitude too confident: it is stretched to the cluster-robust
covariance of the slip law (see `tempering`), so the posterior is never narrower than the
robust least-squares errors. What the data cannot fix is found from the samples
(`._identify`) and reported, not printed as a number (Posterior.not_identifiable).

Priors (flat otherwise): beta > 0 (k > 0), s0 >= 0 (C_rr >= 0), slide_mu >= 0 (a
positive friction limit F_max). The measurement noise per role is held at the fit's
estimate (from ~10^4 residuals: its own uncertainty changes interval widths by < 1 %).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import _exported, _jaxconfig  # noqa: F401
from .._errors import FitError
from ..model._physics import C_RR_MIN, beta_max
from ..model.effects import CATALOG
from ..fit._chunk_prep import _prepare_jit, block_shared
from ..fit._chunks import BLOCK_ENTRIES, chunk_plan, chunkable, nodes_batch, time_blocks
from ..fit._covariance import inverse_norms
from ..fit._lsq import LARGE_ENTRIES
from ..fit._normal import contract, contract_cross_jit, normal_blocks, normal_equations
from ..fit._residuals import _residuals_from_nodes, jacobian, residuals
from ._identify import not_identifiable
from ._mcmc import Chain, autocorr_time, run_ensemble
from ..fit._result import Estimate, FitResult, derived

LINEARITY_TOL = 0.25  # max |delta chi^2| between exact and Gaussian marginal at 2 sigma
CHECK_SIGMA = 2.0
REPORTED = ("slip", "delta_l_mm", "stiffness_N_per_mm", "rolling_resistance", "k_over_m")
_NONNEG = {"s0": "C_rr >= 0", "slide_mu": "F_max > 0"}
_POSITIVE = {"beta": "k > 0"}


def slip_law_parameters(res: FitResult) -> list[str]:
    """The sampled parameters: s0, beta and the free parameters of any replacing slip law."""
    names = ["s0", "beta"]
    for eid in res.effects:
        if CATALOG[eid].slip is not None:
            names += [k for k in CATALOG[eid].defaults if k in res.packing.names]
    missing = [k for k in names if k not in res.packing.names]
    if missing:
        raise FitError(f"the fit holds {missing} fixed: the slip law cannot be sampled")
    return names


@dataclass
class Posterior:
    """Posterior samples of the slip law and the physical quantities derived from it.

    estimates: name -> Estimate (median, std, 2.5-97.5 % interval) for 'slip',
    'delta_l_mm', 'rolling_resistance', 'k_over_m' and 'stiffness_N_per_mm' (with a mass).
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

    @property
    def parameters(self) -> tuple:
        return self.chain.names

    @property
    def converged(self) -> bool:
        return self.chain.converged

    def mcmc_json(self) -> dict:
        """The fit.json "mcmc" block (DATA.md), plus how it was obtained."""
        c = self.chain
        tau = {k: _num(t) for k, t in zip(c.names, c.tau)}
        ess = {k: _num(e) for k, e in zip(c.names, c.ess)}
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
            "tempering": {k: v for k, v in self.temper.items() if k != "cov"},
            "settings": self.settings,
            "seed": int(self.seed),
            "seconds": _num(self.seconds),
            "seconds_by_stage": {k: _num(v) for k, v in self.timings.items()},
        }

    def save(self, path, run_id=None) -> None:
        """Write the samples as an ArviZ InferenceData netCDF file (atomically); `run_id`
        (the fit-lug run that writes the folder) goes into its attrs.

        posterior group: every sampled and derived quantity, dims (chain=walker, draw);
        sample_stats: lp. Read back with arviz.from_netcdf(path).
        """
        from ..io import atomic_path

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            import arviz as az

            c = self.chain
            shape = c.samples.shape[:2]  # (draws, walkers)
            post = {k: np.asarray(v).reshape(shape).T for k, v in self.samples.items()}
            idata = az.from_dict(
                posterior=post, sample_stats={"lp": c.log_prob.T},
                attrs={"inference_library": "emcee", "fitlug_method": self.method,
                       "converged": int(c.converged), "burn_in": int(c.discard),
                       "seed": int(self.seed),
                       **({"run_id": str(run_id)} if run_id is not None else {})})
            with atomic_path(path, suffix=".nc") as tmp:
                idata.to_netcdf(tmp, engine="h5netcdf")


def _num(x):
    x = float(x)
    return x if math.isfinite(x) else None


# ----- the marginal likelihood ------------------------------------------------------------

@eqx.filter_jit
def _jacobian(flat, fixed, lay, obs, packing):
    return jacobian(flat, fixed, lay, obs, packing)  # structured: same values as jacfwd


def _jacobian_tuple(flat, fixed, lay, obs, packing):
    return (_jacobian(flat, fixed, lay, obs, packing),)


@eqx.filter_jit
def _project_dense(flats, fixed, lay, obs, packing, Jes):
    """(chi^2, J_k^T r) of a batch of parameter vectors: r's |r|^2 (m,) and its products
    with the nuisance Jacobians at the step model's points, Jes (K, N, n_eta) -> (m, K,
    n_eta)."""
    def one(f):
        r = residuals(packing.unpack(f, fixed), lay, obs)
        return jnp.sum(r * r), jnp.einsum("kni,n->ki", Jes, r)

    return jax.vmap(one)(flats)


@eqx.filter_jit
def _project_chunked(flats, pts, rest, fixed, lay, obs, packing, plan):
    """:func:`_project_dense` with each J_k^T r from time chunks (no dense Jacobian); pts
    (K, p): the parameter vectors whose Jacobians are contracted."""
    def res_of(f):
        return residuals(packing.unpack(f, fixed), lay, obs)

    R = jax.vmap(res_of)(flats)  # (m, N)
    B = [normal_equations(pts[k], fixed, lay, obs, packing, plan, v=R, with_A=False)[1]
         for k in range(pts.shape[0])]
    return jnp.sum(R * R, axis=1), jnp.stack(B, axis=1)[:, :, rest]


@eqx.filter_jit
def _chi2_flats(flats, fixed, lay, obs, packing):
    def one(f):
        r = residuals(packing.unpack(f, fixed), lay, obs)
        return jnp.sum(r * r)

    return jax.vmap(one)(flats)


#: node values (4 x grid nodes per theta) the blocked exact chi^2 holds at once: 128 MB;
#: 16 parameter vectors of a 100 000-frame recording (200 000 nodes)
NODE_ENTRIES = 16_000_000


@eqx.filter_jit
def _project_block(flats, nodes, rest, fixed, lay, obs, packing, plan, prep):
    """(chi^2, J_eta^T r) of a batch of parameter vectors on one time block (summed over
    the blocks), from their node values and the block's buffers at one of the step model's
    points (`prep`). One point at a time: the residuals are evaluated again per point,
    but the K points' buffers and contractions held together raised the 100 000-frame
    whole run's peak from 1.74 to 1.90 GiB for 6 % of its time."""
    def res_of(f, nd):
        return _residuals_from_nodes(f, fixed, lay, obs, packing, nd)

    R = jax.vmap(res_of)(flats, nodes)  # (m, N_block)
    _, b = contract(prep, lay, packing, plan, v=R, with_A=False)
    return jnp.sum(R * R, axis=1), b[:, rest]


@eqx.filter_jit
def _chi2_block(flats, nodes, fixed, lay, obs, packing):
    """chi^2 of a batch of parameter vectors on one time block, from their node values."""
    def one(f, nd):
        r = _residuals_from_nodes(f, fixed, lay, obs, packing, nd)
        return jnp.sum(r * r)

    return jax.vmap(one)(flats, nodes)


class _Marginal:
    """The linearised marginal of theta for one FitResult: Gaussian limit and exact."""

    def __init__(self, res: FitResult, names: list[str], batch: int):
        prob = res.problem
        self.names = names
        sl = res.packing.slices()
        self.idx = np.array([sl[k].start for k in names])
        self.theta_hat = np.asarray(res.flat)[self.idx]
        self.batch = batch
        self._args = (jnp.asarray(res.flat), jnp.asarray(self.idx),
                      {k: jnp.asarray(v) for k, v in res.params.items()
                       if k not in res.packing.names}, prob.lay, prob.obs, res.packing)
        self._plan = self._blocks = self._shared = None
        n_res = 2 * (prob.lay.lug_t.shape[0] + prob.lay.body_t.shape[0])
        if (n_res * len(res.flat) > LARGE_ENTRIES
                and chunkable(res.params, prob.lay, res.packing)):
            # long recordings: everything below needs J only through J^T J (and J_eta^T r
            # in exact_chi2), accumulated in time chunks; no dense (N x p) Jacobian
            self._plan = chunk_plan(prob.lay)
            self._blocks = time_blocks(prob.lay, prob.obs)  # None: one block
            # exact_chi2 holds a batch's residual vectors and their model temporaries: at
            # most LARGE_ENTRIES residuals per call, BLOCK_ENTRIES per time block
            rows = n_res if self._blocks is None else len(self._blocks.rows[0])
            cap = LARGE_ENTRIES if self._blocks is None else BLOCK_ENTRIES
            self.batch = max(1, min(batch, cap // max(rows, 1)))
            JtJ = normal_blocks(self._args[0], self._args[2], *self._args[3:],
                                self._plan, self._blocks)[0]  # bounded buffers
            if self._blocks is not None:  # what exact_chi2's blocks share, once
                self._shared = block_shared(self._args[0], self._args[2], prob.lay,
                                            res.packing, self._blocks.plans)
        else:
            # through a module exported to disk: a new process skips its tracing
            (J,) = _exported.call("posterior_jacobian", _jacobian_tuple, (res.packing,),
                                  self._args[0], self._args[2], prob.lay, prob.obs)
            J = np.asarray(J)
            JtJ = None
        n_par = len(res.flat)
        rest = np.setdiff1d(np.arange(n_par), self.idx)
        self._rest = rest
        self.n_marginalised = len(rest)
        if JtJ is None:
            Je, Jt = J[:, rest], J[:, self.idx]
            Aee, Aet, Att = Je.T @ Je, Je.T @ Jt, Jt.T @ Jt
        else:
            Aee, Aet, Att = (JtJ[np.ix_(rest, rest)], JtJ[np.ix_(rest, self.idx)],
                             JtJ[np.ix_(self.idx, self.idx)])
        # projection onto span(J_eta)^perp through the normal equations, with the same
        # column scaling and eigenvalue cut as the least-squares covariance (an SVD of the
        # tall J costs ~100x more); F = J_t^T P J_t, the Schur complement of J^T J
        # a column 1e-12 of the largest or less does not act (a speed coefficient whose
        # support holds no sample: 1e-31 of the others): zero, not scaled up to a direction
        # of variance 1e62 that the exact marginal's step would move by 1e30
        n = np.sqrt(np.maximum(np.diag(Aee), 0.0))
        s = inverse_norms(np.where(n > 1e-12 * n.max(initial=0.0), n, 0.0))
        M = Aee * np.outer(s, s)
        w, V = np.linalg.eigh(M)
        inv = np.where(w > 1e-12 * w.max(), 1.0 / np.where(w > 0, w, 1.0), 0.0)
        self.Minv = (V * inv) @ V.T * np.outer(s, s)  # (J_eta^T J_eta)^+
        self._Aee, self._s = Aee, s  # the step model's C_00 and its scaling
        F = Att - Aet.T @ (self.Minv @ Aet)
        self.F = 0.5 * (F + F.T)
        # s0 ~ 1e-6 and beta ~ 1e-8 in std: invert the correlation form
        d = 1.0 / np.sqrt(np.maximum(np.diag(self.F), 1e-300))
        Fs = self.F * np.outer(d, d)
        w = np.linalg.eigvalsh(Fs)
        if not np.all(np.isfinite(w)) or not np.all(w > 1e-10 * max(w.max(), 1e-300)):
            raise FitError(f"the data do not constrain the slip law ({', '.join(names)}): "
                           "its marginal information matrix is singular")
        self.cov = np.linalg.inv(Fs) * np.outer(d, d)
        self.cov = 0.5 * (self.cov + self.cov.T)
        self.chol = np.linalg.cholesky(self.cov)
        self._Je = None if JtJ is not None else jnp.asarray(Je)
        self._sd0 = np.sqrt(np.diag(self.cov))  # the Gaussian limit's, before any widening
        self._step = None  # the nuisance step's model in theta (_step_model), when needed
        self.chi2_hat = None
        self.stretch = None  # A: the likelihood is evaluated at theta_hat + A (theta - theta_hat)

    def widened(self, S: np.ndarray) -> None:
        """Stretch the likelihood so that its Gaussian limit has covariance S.

        L_w(theta) = L(theta_hat + A (theta - theta_hat)) with A^T F A = S^-1
        (A = F^-1/2 S^-1/2): the likelihood's shape is kept, its information becomes S^-1.
        For S = c cov this is the tempered likelihood L^(1/c) in the Gaussian limit.
        """
        d = np.sqrt(np.diag(self.cov))
        Fs = self.F * np.outer(d, d)  # correlation form: s0 ~ 1e-6 and beta ~ 1e-8
        Ss = S / np.outer(d, d)
        w1, V1 = np.linalg.eigh(Fs)
        w2, V2 = np.linalg.eigh(0.5 * (Ss + Ss.T))
        As = (V1 / np.sqrt(w1)) @ V1.T @ (V2 / np.sqrt(w2)) @ V2.T
        self.stretch = As * np.outer(d, 1.0 / d)
        self.F = np.linalg.inv(0.5 * (S + S.T))
        self.F = 0.5 * (self.F + self.F.T)
        self.cov = 0.5 * (S + S.T)
        self.chol = np.linalg.cholesky(self.cov)

    def map_theta(self, thetas: np.ndarray) -> np.ndarray:
        """Where the (stretched) likelihood is evaluated for these theta."""
        if self.stretch is None:
            return thetas
        return self.theta_hat + (np.atleast_2d(thetas) - self.theta_hat) @ self.stretch.T

    def exact_chi2(self, thetas: np.ndarray) -> np.ndarray:
        """The marginal chi^2 of (m, d) thetas: chi^2 at theta with the nuisance parameters
        moved by one Gauss-Newton step from eta_hat, eta = eta_hat - M(theta)^+ b(theta)
        with b = J_eta(theta)^T r(theta, eta_hat) and M = J_eta(theta)^T J_eta(theta)
        (the profile over eta to second order; the lower of that and chi^2 at eta_hat).

        J_eta(theta), the nuisance Jacobian at theta, not at theta_hat: on a recording that
        leaves a direction of theta nearly free (a cruise: beta), J_eta changes by its own
        size along it (beta scales how the speed profile's acceleration moves the slip),
        and a step with J_eta(theta_hat) lands far off the profile (cruise seed 37078 at
        beta -> 0: 134 instead of 5.6 in chi^2; at 3 sigma along beta 1.2e4). J_eta is
        linear in theta there to 1e-3 in chi^2, so it is interpolated linearly from its
        values J_k at theta_hat and theta_hat + h_i e_i (:meth:`_step_model`): b from the
        J_k^T r, M from the cross products J_a^T J_b. Two passes over the recording in
        fixed-size vmapped batches, whose first contracts r with the d + 1 J_k."""
        thetas = np.atleast_2d(thetas)
        m, b = len(thetas), self.batch
        pad = np.concatenate([thetas, np.repeat(thetas[-1:], (-m) % b, 0)])
        flats = np.repeat(np.asarray(self._args[0])[None, :], len(pad), 0)
        flats[:, self.idx] = pad  # (theta, eta_hat)
        st = self._step_model()
        c0, B = self._projections(flats)  # |r|^2 (m,), J_k^T r (m, d + 1, n_eta)
        u = (pad - self.theta_hat) / st["h"]  # (m, d)
        w = np.concatenate([1.0 - u.sum(axis=1, keepdims=True), u], axis=1)  # (m, d + 1)
        bt = np.einsum("mk,mkn->mn", w, B)  # J_eta(theta)^T r
        M = np.einsum("mab,abij->mij", w[:, :, None] * w[:, None, :], st["C"])
        s = self._s
        Ms = M * np.outer(s, s)
        lam, V = np.linalg.eigh(0.5 * (Ms + np.swapaxes(Ms, 1, 2)))
        top = lam.max(axis=1, keepdims=True)
        inv = np.where(lam > 1e-12 * top, 1.0 / np.where(lam > 0, lam, 1.0), 0.0)
        y = inv * np.einsum("mkj,mk->mj", V, s * bt)  # V^T s b, scaled by the inverse
        step = s * np.einsum("mij,mj->mi", V, y)
        flats[:, self._rest] -= step
        c1 = self._chi2_of_flats(flats)
        return np.minimum(c0, c1)[:m]

    def _step_model(self) -> dict:
        """The nuisance Jacobian's dependence on theta, built on first use.

        Points theta_hat and theta_hat + h_i e_i (h_i a quarter of theta_i's Gaussian std,
        at most half its distance from a zero bound) and their nuisance Jacobians J_k:
        J_eta(theta_hat + h u) = sum_k w_k J_k with w = (1 - sum u, u), so that
        J_eta^T J_eta = sum_ab w_a w_b C_ab with C_ab = J_a^T J_b (exact for a J_eta
        linear in theta). Returns {"h", "C" (d + 1, d + 1, n_eta, n_eta)}."""
        if self._step is not None:
            return self._step
        d = len(self.idx)
        h = 0.25 * self._sd0
        for i, k in enumerate(self.names):
            if (k in _NONNEG or k in _POSITIVE) and self.theta_hat[i] > 0:
                h[i] = min(h[i], 0.5 * self.theta_hat[i])
        h = np.where(h > 0, h, 1e-12)
        base = np.asarray(self._args[0])
        pts = [base]
        for i in range(d):
            f = base.copy()
            f[self.idx[i]] += h[i]
            pts.append(f)
        self._pts = np.array(pts)
        a, rest = self._args, self._rest
        K = d + 1
        pairs = [(i, j) for i in range(K) for j in range(i, K) if j > 0]
        C = np.zeros((K, K, len(rest), len(rest)))
        C[0, 0] = self._Aee  # the optimum's, from __init__
        if self._plan is None:  # dense: the points' nuisance Jacobians, kept
            Jn = [np.asarray(self._Je)]
            for f in pts[1:]:
                (J,) = _exported.call("posterior_jacobian", _jacobian_tuple, (a[5],),
                                      jnp.asarray(f), a[2], a[3], a[4])
                Jn.append(np.asarray(J)[:, rest])
            self._Jes = jnp.stack(Jn)
            for i, j in pairs:
                C[i, j] = Jn[i].T @ Jn[j]
        else:
            ix = np.ix_(rest, rest)
            if self._blocks is None:
                parts = [(a[3], a[4], self._plan, [None] * K)]
            else:  # what each point's blocks share, kept for _projections
                self._shared_pts = [self._shared] + [
                    block_shared(f, a[2], a[3], a[5], self._blocks.plans) for f in pts[1:]]
                bl = self._blocks
                parts = [(bl.lays[k], bl.obss[k], bl.plans[k],
                          [sh[k] for sh in self._shared_pts]) for k in range(len(bl.lays))]
            for lay_k, ob_k, plan_k, sh_k in parts:
                preps = [_prepare_jit(jnp.asarray(f), a[2], lay_k, ob_k, a[5], plan_k, sh)
                         for f, sh in zip(pts, sh_k)]
                for i, j in pairs:
                    C[i, j] += np.asarray(contract_cross_jit(
                        preps[i], preps[j], lay_k, a[5], plan_k))[ix]
                del preps
        for i in range(K):
            for j in range(i):
                C[i, j] = C[j, i].T
        self._step = {"h": h, "C": C}
        return self._step

    def _node_group(self) -> int:
        """Vectors whose node values one pass over the blocks holds at once (NODE_ENTRIES
        doubles), a multiple of the batch."""
        G, b = int(self._args[3].grid.shape[0]), self.batch
        return max(b, (NODE_ENTRIES // (4 * G)) // b * b)

    def _projections(self, flats: np.ndarray) -> tuple:
        """(|r|^2 (m,), J_k^T r (m, d + 1, n_eta)) for whole parameter vectors (m a
        multiple of the batch), J_k the nuisance Jacobian at the step model's points."""
        b = self.batch
        a = self._args
        rest = jnp.asarray(self._rest)
        K = len(self._pts)
        if self._plan is not None and self._blocks is not None:
            # the vectors' node values once over the whole grid, then block by block: the
            # block's buffers at each point once, its residuals for every vector in
            # batches (time linear in the recording, memory one block's)
            bl = self._blocks
            group = self._node_group()
            cs, bs = [], []
            for g0 in range(0, len(flats), group):
                fg = jnp.asarray(flats[g0:g0 + group])
                nodes = nodes_batch(fg, a[2], a[3], a[5])
                c2 = np.zeros(len(fg))
                bb = np.zeros((len(fg), K, len(self._rest)))
                for k, (lay_k, ob_k, plan_k) in enumerate(zip(bl.lays, bl.obss, bl.plans)):
                    for j in range(K):
                        prep = _prepare_jit(jnp.asarray(self._pts[j]), a[2], lay_k, ob_k,
                                            a[5], plan_k, self._shared_pts[j][k])
                        for i in range(0, len(fg), b):
                            nd = tuple(x[i:i + b] for x in nodes)
                            ck, bk = _project_block(fg[i:i + b], nd, rest, a[2], lay_k,
                                                    ob_k, a[5], plan_k, prep)
                            bb[i:i + b, j] += np.asarray(bk)
                            if j == 0:
                                c2[i:i + b] += np.asarray(ck)
                        del prep
                cs.append(c2)
                bs.append(bb)
            return np.concatenate(cs), np.concatenate(bs)
        if self._plan is not None:
            pts = jnp.asarray(self._pts)
            out = [_project_chunked(jnp.asarray(flats[i:i + b]), pts, rest, a[2], a[3], a[4],
                                    a[5], self._plan) for i in range(0, len(flats), b)]
        else:
            out = [_project_dense(jnp.asarray(flats[i:i + b]), a[2], a[3], a[4], a[5],
                                  self._Jes) for i in range(0, len(flats), b)]
        return (np.concatenate([np.asarray(o[0]) for o in out]),
                np.concatenate([np.asarray(o[1]) for o in out]))

    def _chi2_of_flats(self, flats: np.ndarray) -> np.ndarray:
        """chi^2 of whole parameter vectors (m, p), m a multiple of the batch."""
        b = self.batch
        a = self._args
        if self._blocks is not None:
            bl = self._blocks
            group = self._node_group()
            out = []
            for g0 in range(0, len(flats), group):
                fg = jnp.asarray(flats[g0:g0 + group])
                nodes = nodes_batch(fg, a[2], a[3], a[5])
                c2 = np.zeros(len(fg))
                for lay_k, ob_k in zip(bl.lays, bl.obss):
                    for i in range(0, len(fg), b):
                        nd = tuple(x[i:i + b] for x in nodes)
                        c2[i:i + b] += np.asarray(_chi2_block(fg[i:i + b], nd, a[2], lay_k,
                                                              ob_k, a[5]))
                out.append(c2)
            return np.concatenate(out)
        return np.concatenate([np.asarray(_chi2_flats(jnp.asarray(flats[i:i + b]), a[2], a[3],
                                                      a[4], a[5]))
                               for i in range(0, len(flats), b)])

    def check_points(self) -> np.ndarray:
        """theta_hat + CHECK_SIGMA sigma along the principal axes and the diagonals."""
        d = len(self.names)
        w, V = np.linalg.eigh(self.cov)
        root = V * np.sqrt(w)
        dirs = [sgn * e for e in np.eye(d) for sgn in (1, -1)]
        if d > 1:
            dirs += [(2 * np.array(c) - 1) / np.sqrt(d) for c in np.ndindex(*(2,) * d)]
        return self.theta_hat + CHECK_SIGMA * np.array([root @ u for u in dirs])

    def linearity_check(self) -> dict:
        pts = self.check_points()
        chi = self.exact_chi2(self.map_theta(np.vstack([self.theta_hat, pts])))
        self.chi2_hat = float(chi[0])
        exact = chi[1:] - chi[0]
        z = pts - self.theta_hat
        gauss = np.einsum("ij,jk,ik->i", z, self.F, z)
        diff = exact - gauss
        return {"sigma": CHECK_SIGMA, "points": int(len(pts)),
                "max_delta_chi2": float(np.max(np.abs(diff))),
                "delta_chi2_gaussian": float(np.median(gauss)),
                "delta_chi2_exact_range": [float(exact.min()), float(exact.max())],
                "tolerance": LINEARITY_TOL}


def _log_prior(th, names):
    ok = jnp.ones(th.shape[:-1], bool)
    for i, k in enumerate(names):
        if k in _POSITIVE:
            ok &= th[..., i] > 0
        elif k in _NONNEG:
            ok &= th[..., i] >= 0
    if "s0" in names and "beta" in names:
        s0, beta = th[..., names.index("s0")], th[..., names.index("beta")]
        ok &= beta <= beta_max(s0)
    return jnp.where(ok, 0.0, -jnp.inf)


def _gaussian_log_prob(marg: _Marginal):
    th0, F, names = jnp.asarray(marg.theta_hat), jnp.asarray(marg.F), marg.names

    def one(th):
        z = th - th0
        return -0.5 * z @ F @ z + _log_prior(th, names)

    f = jax.jit(jax.vmap(one))
    return lambda x: np.asarray(f(x))


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


# ----- honest errors when the misfit is unexplained -------------------------------------

TEMPERED = ("slip", "delta_l_mm", "rolling_resistance", "k_over_m")


def tempering(res: FitResult, marg: "_Marginal | None" = None) -> dict:
    """How the likelihood of `res` is widened: {"factor": 1.0} when it is not.

    Only when fitlug.explain left a misfit unexplained and widened the least-squares errors
    to robust ones (res.robust: by marker, in time; each quantity the largest of them and
    of least squares, see fitlug.explain._robust). Then the posterior is made consistent
    with them: of the candidate covariances of the slip law (each robust one, and their
    sum), each scaled up until every reported quantity (slip, dl', C_rr, k/m) is at least
    as wide as its robust least-squares error (delta method), and each rescaled per
    parameter first so that a quantity of one parameter alone (slip, k/m) gets exactly its
    target, the tightest is used (least sum over the quantities of log(variance /
    target)). The likelihood is stretched to that covariance (_Marginal.widened): its
    shape and the priors are kept. No small-sample t factor is
    put on top: the largest of three variance estimates already covers the few clusters
    (bench_coverage's out-of-catalog rows: with t_{G-1} factors on top, the posterior
    intervals held the truth in 150 of 150 recordings).
    Returns {"factor" (slip variance over the white-noise one), "cov", "method",
    "clusters", "extra_scale", "note"}.
    """
    info = getattr(res, "robust", None)
    if not info or info.get("cov") is None:
        return {"factor": 1.0}
    sens = info.get("speed_sensitivity") or {}
    shifted = bool(sens.get("shift")) and not sens.get("headline")  # headline: the free fit
    if info.get("method") == "least squares" and not shifted:
        return {"factor": 1.0}
    if marg is None:
        marg = _Marginal(res, slip_law_parameters(res), batch=16)
    sl = res.packing.slices()
    idx = [sl[k].start for k in marg.names]
    grads = _derived_gradients(res, marg.names, marg.theta_hat)
    g = grads["slip"]
    cands = info.get("covs") or {info["method"]: (info["cov"], info.get("clusters"))}
    blocks = {name: (0.5 * (C + C.T)[np.ix_(idx, idx)], G)
              for name, (C, G) in cands.items() if C is not None}
    if len(blocks) > 1:  # their sum: at least as wide as each in every direction
        blocks["sum of the robust covariances"] = (sum(b[0] for b in blocks.values()), None)
    # each reported quantity's target variance: its robust least-squares one
    target = {}
    for q in TEMPERED:
        want = info["robust_std"].get(q)
        if q in grads and want and math.isfinite(want):
            target[q] = want ** 2
    for name, (S, G) in list(blocks.items()):  # each rescaled per parameter, so that a
        # quantity of one parameter alone (slip: s0; k/m: beta) gets exactly its target
        d = np.ones(len(idx))
        for q, want2 in target.items():
            nz = np.flatnonzero(np.abs(grads[q]) > 1e-12 * np.max(np.abs(grads[q])))
            have = float(grads[q] @ S @ grads[q])
            if len(nz) == 1 and have > 0:
                d[nz[0]] = max(d[nz[0]], math.sqrt(want2 / have))
        if np.any(d > 1.0):
            blocks[name + ", rescaled per parameter"] = (S * np.outer(d, d), G)
    best = None  # the tightest candidate: least total excess over the targets
    for name, (S, G) in blocks.items():
        extra = 1.0  # so that no reported quantity is narrower than its target
        for q, want2 in target.items():
            have = float(grads[q] @ S @ grads[q])
            if have > 0:
                extra = max(extra, want2 / have)
        excess = sum(math.log(max(float(grads[q] @ S @ grads[q]) * extra, 1e-300) / want2)
                     for q, want2 in target.items())
        if best is None or excess < best[0]:
            best = (excess, name, S * extra, G, extra)
    _, method, S, G, extra = best
    naive = float(g @ marg.cov @ g)
    factor = float(g @ S @ g) / naive if naive > 0 else float("inf")
    note = (f"{G} clusters" if G else "the robust covariances added" if "sum" in method
            else "its own covariance")
    if extra > 1.0 + 1e-9:
        note += f", errors x {math.sqrt(extra):.3f} so that no quantity is narrower than its own"
    if shifted:
        note += ("; the robust errors carry the speed-profile sensitivity (the shift of "
                 "each quantity when the speed spline is freed)")
    return {"factor": factor, "cov": S, "method": method, "clusters": G,
            "extra_scale": float(extra), "note": note}


def tempered_marginal(res: FitResult, names, batch: int) -> tuple:
    """(the marginal of `names`, its tempering): the likelihood the posterior samples,
    stretched to the robust covariance when the misfit is unexplained (see `tempering`;
    the returned dict without its "cov")."""
    marg = _Marginal(res, names, batch=batch)
    temper = tempering(res, marg)
    if temper.get("cov") is not None:
        marg.widened(temper.pop("cov"))
    return marg, temper


def _derived_gradients(res: FitResult, names, theta_hat) -> dict:
    """d quantity / d theta at theta_hat for the reported quantities."""
    prob = res.problem
    base = {k: jnp.asarray(v) for k, v in res.params.items()}

    def f(th):
        p = dict(base)
        for i, k in enumerate(names):
            p[k] = th[i]
        q = derived(p, prob.lay, prob.rig.mass_kg)
        return {k: q[k] for k in REPORTED if k in q}

    jac = jax.jacfwd(f)(jnp.asarray(theta_hat, float))
    return {k: np.asarray(v, float) for k, v in jac.items()}


# ----- the verb ---------------------------------------------------------------------------

def sample_posterior(res: FitResult, *, seed: int = 0, progress: bool = False,
                     time_budget_s: float = 60.0, walkers: int = 32,
                     min_tau_multiple: float = 50.0, target_ess: float = 1000.0,
                     method: str = "auto") -> Posterior:
    """Sample the posterior of the slip law of a least-squares fit; see the module docstring.

    res: a converged FitResult. seed: everything random (walker starts, emcee moves).
    progress: a tqdm bar on stderr (only on a terminal). time_budget_s: wall-clock limit of
    the chain (then converged=False and the reason in mcmc_json()). method: 'auto',
    'gaussian' or 'exact'.
    Raises ValueError for bad arguments, FitError when the slip law is not identifiable.
    """
    import time

    if method not in ("auto", "gaussian", "exact"):
        raise ValueError(f"method must be 'auto', 'gaussian' or 'exact', not {method!r}")
    if walkers < 4 or walkers % 2:
        raise ValueError(f"walkers must be an even number >= 4, not {walkers}")
    if not (time_budget_s > 0 and min_tau_multiple > 0 and target_ess > 0):
        raise ValueError("time_budget_s, min_tau_multiple and target_ess must be positive")
    t0 = time.perf_counter()
    names = slip_law_parameters(res)
    marg, temper = tempered_marginal(res, names, batch=walkers // 2)
    check = marg.linearity_check()
    use = method
    if method == "auto":
        use = "gaussian" if check["max_delta_chi2"] <= LINEARITY_TOL else "exact"
    log_prob = _gaussian_log_prob(marg) if use == "gaussian" else _exact_log_prob(marg)
    t1 = time.perf_counter()

    rng = np.random.default_rng(seed)
    p0 = _start(marg, walkers, rng)
    # the chain keeps at least half the budget, however long the set-up took (compiles
    # on a loaded machine): a chain starved to a few steps would report its start spread
    budget = max(time_budget_s - (time.perf_counter() - t0), 0.5 * time_budget_s)
    chain = run_ensemble(log_prob, p0, names=names, seed=int(rng.integers(2 ** 31)),
                         time_budget_s=budget, min_tau_multiple=min_tau_multiple,
                         target_ess=target_ess, progress=progress)
    t2 = time.perf_counter()
    samples = _derived_samples(res, names, chain.flat())
    estimates = {k: _estimate(samples[k]) for k in REPORTED if k in samples}
    unident = not_identifiable(samples, names)
    t3 = time.perf_counter()
    desc = {"gaussian": "emcee on the Gaussian limit of the linearly marginalised likelihood",
            "exact": "emcee on the exact-model, linearly marginalised likelihood"}[use]
    how = "posterior (emcee)"
    headline = (getattr(res, "robust", None) or {}).get("headline")
    if headline:  # a nuisance taken out, a free speed profile: the fit is another model's
        how += "; " + res.robust["uncertainty_method"]
        if temper["factor"] > 1.01:  # an error 0.5 % wider or more
            how += (f"; likelihood stretched (slip error x {math.sqrt(temper['factor']):.3g}) "
                    "to carry the nuisance's own uncertainty")
    elif temper["factor"] > 1.0:
        how += (f", likelihood tempered (stretched) to the {temper['method']} covariance "
                f"({temper['note']}; slip error x {math.sqrt(temper['factor']):.3g} the "
                "white-noise one): " + ("tracker systematics carried" if "nuisance" in
                                        temper["method"] else "unexplained misfit"))
    return Posterior(estimates=estimates, samples=samples, chain=chain,
                     method=f"{use}: {desc}", check=check, seed=seed,
                     not_identifiable=unident, uncertainty_method=how, temper=temper,
                     seconds=time.perf_counter() - t0, n_marginalised=marg.n_marginalised,
                     settings={"time_budget_s": time_budget_s, "min_tau_multiple":
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

    def inside(th):
        return np.isfinite(np.asarray(_log_prior(jnp.asarray(th), names)))

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


def _derived_samples(res: FitResult, names, flat_samples: np.ndarray) -> dict:
    prob = res.problem
    base = {k: jnp.asarray(v) for k, v in res.params.items()}
    mass = prob.rig.mass_kg

    @jax.jit
    @jax.vmap
    def one(th):
        p = dict(base)
        for i, k in enumerate(names):
            p[k] = th[i]
        q = derived(p, prob.lay, mass, prob.rig.drawbar_pull_N)
        return {k: q[k] for k in REPORTED if k in q}

    out = {k: np.asarray(v) for k, v in one(jnp.asarray(flat_samples)).items()}
    out.update({k: np.asarray(flat_samples[:, i]) for i, k in enumerate(names)})
    return out


def _estimate(x: np.ndarray) -> Estimate:
    lo, med, hi = np.percentile(x, [2.5, 50.0, 97.5])
    return Estimate(float(med), float(np.std(x, ddof=1)), (float(lo), float(hi)))


def least_squares_identifiability(res: FitResult, *, seed: int = 0, draws: int = 4000) -> dict:
    """quantity -> reason for a least-squares-only run (no chain): the same decision as the
    posterior's (fitlug.posterior._identify), on draws from the Gaussian limit of the
    marginal of the slip law (tempered like the posterior when the misfit is unexplained)."""
    names = slip_law_parameters(res)
    marg, _ = tempered_marginal(res, names, batch=16)
    rng = np.random.default_rng(seed)
    th = marg.theta_hat + rng.standard_normal((draws, len(names))) @ marg.chol.T
    return not_identifiable(_derived_samples(res, names, th), names)
