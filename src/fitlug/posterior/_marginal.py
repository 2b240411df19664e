"""The marginal likelihood of the slip law, the other parameters marginalised.

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
"""

from __future__ import annotations

import jax
import numpy as np
import jax.numpy as jnp

from .. import _exported, _jaxconfig  # noqa: F401
from ..fit import _buckets
from .._errors import FitError
from ..model.effects import CATALOG
from ..fit._chunk_prep import _prepare_jit, block_shared
from ..fit._chunks import BLOCK_ENTRIES, chunk_plan, chunkable, nodes_batch, time_blocks
from ..fit._covariance import inverse_norms
from ..fit._lsq import LARGE_ENTRIES
from ..fit._normal import contract_cross_jit, normal_blocks
from ..fit._result import FitResult
from ._priors import _NONNEG, _POSITIVE
from ._psd import _psd_solve
from ._projections import (_chi2_block, _chi2_flats_tuple, _jacobian_tuple, _project_block,
                           _project_chunked, _project_dense_tuple)

LINEARITY_TOL = 0.25  # max |delta chi^2| between exact and Gaussian marginal at 2 sigma
CHECK_SIGMA = 2.0
#: node values (4 x grid nodes per theta) the blocked exact chi^2 holds at once: 128 MB;
#: 16 parameter vectors of a 100 000-frame recording (200 000 nodes)
NODE_ENTRIES = 16_000_000
#: where a singular marginal is allowed (``singular_ok``), each parameter of the law gets a
#: std this many times its conditional one (from Att's diagonal), and at least its value
SINGULAR_RIDGE = 1e4


def slip_law_parameters(res: FitResult) -> list[str]:
    """The sampled parameters: s0, beta and the free parameters of any replacing slip law."""
    names = ["s0", "beta"]
    for eid in res.effects:
        if CATALOG[eid].slip is not None:
            names += [k for k in CATALOG[eid].defaults if k in res.packing.names]
    missing = [k for k in names if k not in res.packing.names]
    held = getattr(res, "held", None)
    if held is not None:
        sl = res.packing.slices()
        missing += [k for k in names if k in sl and np.any(np.asarray(held)[sl[k]])]
    if missing:
        raise FitError(f"the fit holds {missing} fixed: the slip law cannot be sampled")
    return names



class _Marginal:
    """The linearised marginal of theta for one FitResult: Gaussian limit and exact."""

    def __init__(self, res: FitResult, names: list[str], batch: int, singular_ok: bool = False):
        prob = res.problem
        self.names = names
        sl = res.packing.slices()
        self.idx = np.array([sl[k].start for k in names])
        self.theta_hat = np.asarray(res.flat)[self.idx]
        self.batch = batch
        self._args = (jax.device_put(np.asarray(res.flat, float)), None,
                      {k: jnp.asarray(v) for k, v in res.params.items()
                       if k not in res.packing.names}, prob.lay, prob.obs, res.packing)
        self._plan = self._blocks = self._shared = None
        cols = np.arange(len(res.flat))  # where each parameter sits in self._args[0]
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
            # on bucketed shapes (fit._buckets: a recording of a new length compiles
            # nothing new): the passes below carry the padding's rows and columns, which
            # are exact zeros, and the solves use the real columns only
            pb = _buckets.pad(self._args[0], self._args[2], prob.lay, prob.obs, res.packing)
            if pb is not None:
                self._args = (pb.flat, None, pb.fixed, pb.lay, pb.obs, pb.packing)
                cols = pb.cols
            # through a module exported to disk: a new process skips its tracing
            a = self._args
            (J,) = _exported.call("posterior_jacobian", _jacobian_tuple, (a[5],),
                                  a[0], a[2], a[3], a[4])
            J = np.asarray(J)
            JtJ = None
        n_par = len(res.flat)
        rest = np.setdiff1d(np.arange(n_par), self.idx)
        held = getattr(res, "held", None)
        if held is not None:  # held by fitlug.Parameters: at their values, not marginalised
            rest = rest[~np.asarray(held, bool)[rest]]
        self.n_marginalised = len(rest)
        # _rest: the marginalised columns (of the padded vector where padded); _jrest: the
        # columns the compiled passes carry (the padding's too, for shapes that do not
        # depend on the recording); _live: where _rest sits in _jrest
        self.idx, rest = cols[self.idx], cols[rest]
        self._rest = rest
        self._jrest = np.setdiff1d(np.arange(len(np.asarray(self._args[0]))), self.idx)
        if held is not None:
            self._jrest = rest
        self._live = np.searchsorted(self._jrest, rest)
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
        Fs, d, ok = _scaled(self.F)
        self.singular = not ok
        if self.singular and singular_ok:
            # a model that does not describe the path (the slip read off the straight
            # runs), its nuisance so nearly degenerate that F is rounding (an engine crawler
            # whose tips slide, h 0.71: -4e14 on beta). Its law is not identifiable
            # (explain._robust) nor its slip the headline: each parameter is left
            # uncorrelated, std SINGULAR_RIDGE x its conditional one, at least its size
            var = np.maximum(SINGULAR_RIDGE ** 2 / np.maximum(np.diag(Att), 1e-300),
                             self.theta_hat ** 2)
            self.F = np.diag(1.0 / var)
            Fs, d, ok = _scaled(self.F)
        if not ok:
            raise FitError(f"the data do not constrain the slip law ({', '.join(names)}): "
                           "its marginal information matrix is singular")
        self.cov = np.linalg.inv(Fs) * np.outer(d, d)
        self.cov = 0.5 * (self.cov + self.cov.T)
        self.chol = np.linalg.cholesky(self.cov)
        self._Je = None if JtJ is not None else jax.device_put(np.asarray(J)[:, self._jrest])
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
        step = s * _psd_solve(0.5 * (Ms + np.swapaxes(Ms, 1, 2)), s * bt)
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
                                      jax.device_put(f), a[2], a[3], a[4])
                Jn.append(np.asarray(J)[:, self._jrest])
            self._Jes = jax.device_put(np.stack(Jn))  # numpy: no program to load
            Jn = [J[:, self._live] for J in Jn]
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
        rest = jax.device_put(np.asarray(self._jrest))  # == _rest but on the dense path
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
            pts = jax.device_put(self._pts)
            out = [_project_chunked(jax.device_put(flats[i:i + b]), pts, rest, a[2], a[3], a[4],
                                    a[5], self._plan) for i in range(0, len(flats), b)]
        else:
            out = [_exported.call("posterior_project", _project_dense_tuple, (a[5],),
                                  jax.device_put(flats[i:i + b]), a[2], a[3], a[4], self._Jes)
                   for i in range(0, len(flats), b)]
        return (np.concatenate([np.asarray(o[0]) for o in out]),
                np.concatenate([np.asarray(o[1])[:, :, self._live] for o in out]))

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
        return np.concatenate([np.asarray(_exported.call(
            "posterior_chi2", _chi2_flats_tuple, (a[5],), jax.device_put(flats[i:i + b]), a[2],
            a[3], a[4])[0]) for i in range(0, len(flats), b)])

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


def _scaled(F):
    """(F in correlation form, the scaling d, whether it is positive definite): s0 ~ 1e-6
    and beta ~ 1e-8 in std, so the check and the inverse are made on d F d."""
    diag = np.diag(F)
    if not np.all(np.isfinite(diag)) or not np.all(diag > 0):
        return None, None, False
    d = 1.0 / np.sqrt(diag)
    Fs = F * np.outer(d, d)
    w = np.linalg.eigvalsh(Fs)
    return Fs, d, bool(np.all(np.isfinite(w)) and np.all(w > 1e-10 * max(w.max(), 1e-300)))
