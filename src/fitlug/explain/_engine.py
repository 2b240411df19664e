"""One compiled model for every candidate: the base model with ALL catalog effects active.

Compiling the fitter once per effect set costs seconds per candidate; here every
candidate is the same all-effects model (MODEL.md §3: an effect at its identity values
is no effect) with only its own parameters moved away from identity. What differs
between candidates is which parameters are free, so nothing is compiled twice.

The fit is Levenberg-Marquardt with exact residuals of the all-effects model. Its
Jacobian has two blocks: the parameters the starting fit had free, differentiated
exactly (forward mode) under the starting fit's own model, and the added effect
parameters by central differences of the all-effects model. The first block leaves
out the added effects' small change to the base derivatives (order epsilon of the
effect), so convergence is linear instead of quadratic for large effects; the
minimum it converges to is the same, since the residuals are exact. Each step tries
several damping values at once (one batched model evaluation).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from .. import _jaxconfig  # noqa: F401
from ..fit import residuals
from ..fit._lsq import Packing, jacobian
from ..model import CATALOG, param_names

COUPLED = ("s0", "beta", "R", "D", "e", "x_off", "y_off")
CHUNK = 8  # model evaluations per batched call (fixed, so one compilation serves all)
_BASE_STEPS = {"s0": 1e-5, "beta": 1e-9, "R": 1e-4, "D": 1e-4, "e": 1e-4, "x_off": 1e-4,
               "y_off": 1e-4}
_LAMBDAS = np.array([0.0, 1e-6, 1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0])


@partial(jax.jit, static_argnames=("packing",))
def _res_batch(flats, packing, lay, obs):
    return jax.vmap(lambda f: residuals(packing.unpack(f, {}), lay, obs))(flats)


@partial(jax.jit, static_argnames=("packing",))
def _jac_block(flat, fixed, packing, lay, obs):
    return jacobian(flat, fixed, lay, obs, packing)  # structured: same values as jacfwd


@dataclass
class LMResult:
    theta: np.ndarray  # all-effects parameter vector
    r: np.ndarray  # weighted residuals
    chi2: float
    iterations: int
    converged: bool


class Engine:
    """Residuals, Jacobians and fits of any effect set on one recording.

    `res`: the fit explanation starts from (its model and free parameters form the base
    block). Parameter vectors `theta` are in the all-effects packing (`self.names`).
    """

    def __init__(self, res):
        self.res = res
        prob = res.problem
        self.prob_all, p_all = prob.with_effects(tuple(CATALOG), res.params)
        self.lay_all = self.prob_all.lay
        self.obs = prob.obs
        self.packing = Packing.of(p_all, param_names(self.lay_all))
        self.theta0 = np.asarray(self.packing.pack(p_all))
        self.slices = self.packing.slices()
        self.n_body = prob.lay.n_body
        self.n_data = prob.n_valid
        # base block: the starting fit's free parameters under its own model
        self.cur_packing = res.packing
        self.cur_fixed_names = [k for k in res.params if k not in res.packing.names]
        self.cur_idx = np.concatenate([np.arange(self.slices[k].start, self.slices[k].stop)
                                       for k in res.packing.names])
        self.cur_positions = {k: sl.start for k, sl in res.packing.slices().items()
                              if sl.stop - sl.start == 1}
        self.evaluations = 0

    # ---- parameter bookkeeping -------------------------------------------------------
    def index(self, name: str) -> int:
        sl = self.slices[name]
        if sl.stop - sl.start != 1:
            raise ValueError(f"parameter {name!r} is not a scalar")
        return sl.start

    def get(self, theta, name):
        v = theta[self.slices[name]]
        return float(v[0]) if len(v) == 1 else v

    def with_values(self, theta, values: dict) -> np.ndarray:
        th = np.array(theta, float)
        for k, v in values.items():
            th[self.slices[k]] = v
        return th

    def params(self, theta) -> dict:
        """Parameter dict (numpy) of a vector."""
        return {k: np.asarray(theta[sl]).reshape(s)
                for (k, sl), s in zip(self.slices.items(), self.packing.shapes)}

    def free_names(self, effect_id: str) -> list[str]:
        """An effect's parameters fitted here (gauge, discrete and unidentifiable ones held)."""
        cls = CATALOG[effect_id]
        names = [k for k in cls.defaults if k not in cls.fixed_in_fit]
        if effect_id == "body_bounce" and self.n_body < 2:
            names.remove("bounce_B")  # MODEL.md §3: B = 0 with one body marker
        return names

    def n_free(self, effect_id: str) -> int:
        return CATALOG[effect_id].n_free(self.n_body)

    def field(self) -> tuple:
        """((x_min, x_max), (y_min, y_max)) of the valid samples, mm: the field of view."""
        xs, ys = [], []
        for role in ("lug", "body"):
            ok = np.asarray(self.obs[role + "_w"]) > 0
            xs.append(np.asarray(self.obs[role + "_x"])[ok])
            ys.append(np.asarray(self.obs[role + "_y"])[ok])
        x, y = np.concatenate(xs), np.concatenate(ys)
        return (float(x.min()), float(x.max())), (float(y.min()), float(y.max()))

    # ---- evaluation --------------------------------------------------------------------
    def residuals(self, thetas) -> np.ndarray:
        """Weighted residuals of the all-effects model, (B, S) for (B, P) vectors."""
        thetas = np.atleast_2d(np.asarray(thetas, float))
        out = []
        for i in range(0, len(thetas), CHUNK):
            blk = thetas[i:i + CHUNK]
            pad = np.vstack([blk, np.repeat(blk[-1:], CHUNK - len(blk), 0)])
            r = np.asarray(_res_batch(jnp.asarray(pad), self.packing, self.lay_all, self.obs))
            out.append(r[:len(blk)])
            self.evaluations += len(blk)
        return np.vstack(out)

    def base_jacobian(self, theta) -> np.ndarray:
        """Jacobian of the starting model wrt its free parameters at theta, (S, n).

        Exact for the starting model; an added effect that maps the time stamps
        (frame_drop) is applied to the sample times first, since a 10 ms shift changes the
        fine speed-spline columns by tens of percent after the lost frame.
        """
        flat = jnp.asarray(theta[self.cur_idx])
        fixed = {k: jnp.asarray(self.get(theta, k), float) for k in self.cur_fixed_names}
        lay = self.res.problem.lay
        maps = [c for e, c in CATALOG.items()
                if c.time_map is not None and e not in self.res.effects]
        if maps:
            p = {k: jnp.asarray(v) for k, v in self.params(theta).items()}
            lt, bt = lay.lug_t, lay.body_t
            for c in maps:
                lt, bt = c.time_map(p, lt), c.time_map(p, bt)
            lay = lay.with_times(lt, lay.lug_i, bt, lay.body_j)
        return np.asarray(_jac_block(flat, fixed, self.cur_packing, lay, self.obs))

    def step_of(self, name: str) -> float:
        for cls in CATALOG.values():
            if name in cls.scales:
                return 1e-2 * cls.scales[name]
        return _BASE_STEPS.get(name, 1e-6)

    def fd_columns(self, specs, theta) -> np.ndarray:
        """Central-difference columns (S, len(specs)); spec = (settings dict, param name)."""
        if not specs:
            return np.zeros((len(self.obs["lug_w"]) * 2 + len(self.obs["body_w"]) * 2, 0))
        pts, hs = [], []
        for settings, name in specs:
            th = self.with_values(theta, settings)
            h = self.step_of(name)
            i = self.index(name)
            for sgn in (1.0, -1.0):
                t2 = th.copy()
                t2[i] += sgn * h
                pts.append(t2)
            hs.append(h)
        R = self.residuals(np.array(pts))
        return np.stack([(R[2 * k] - R[2 * k + 1]) / (2 * hs[k]) for k in range(len(specs))], 1)

    def jacobian(self, theta, extra: list[str]) -> np.ndarray:
        """[base block | columns of the `extra` scalar parameters] at theta.

        The base block's scalar physics and geometry columns (s0, beta, R, D, e, x_off,
        y_off) are replaced by differences of the all-effects model: an effect such as
        lug_sliding changes them by tens of percent, the spline and offset columns by
        at most the effect's relative size.
        """
        Jb = np.array(self.base_jacobian(theta))
        coupled = [k for k in COUPLED if k in self.cur_packing.names]
        cols = self.fd_columns([({}, k) for k in coupled + list(extra)], theta)
        pos = self.cur_positions
        for i, k in enumerate(coupled):
            Jb[:, pos[k]] = cols[:, i]
        return np.hstack([Jb, cols[:, len(coupled):]])

    # ---- fitting -----------------------------------------------------------------------
    def fit(self, theta0, extra: list[str], *, r0=None, max_iter: int = 30,
            tol: float = 1e-3, give_up=None) -> LMResult:
        """Levenberg-Marquardt over the base block plus the scalar parameters `extra`.

        Stops when an accepted step lowers chi^2 by less than `tol` (+1e-10 chi^2), or
        when a nearly linear step (gain within 10 % of the prediction) gains less than 1,
        or when `give_up(chi2, predicted_decrease)` says the fit cannot win anyway.
        """
        theta = np.array(theta0, float)
        idx = np.r_[self.cur_idx, [self.index(k) for k in extra]].astype(int)
        r = self.residuals(theta)[0] if r0 is None else np.asarray(r0)
        chi2 = float(r @ r)
        converged = False
        it = 0
        lam_scale = 1.0
        stale = True
        for it in range(1, max_iter + 1):
            if stale:
                J = self.jacobian(theta, extra)
                A = J.T @ J
                g = J.T @ r
                d = np.sqrt(np.diag(A))
                d = np.where(d > 0, d, 1.0)
                w, V = np.linalg.eigh(A / np.outer(d, d))
                gs = V.T @ (g / d)
                stale = False
                ok_w = w > 1e-13 * max(w.max(), 1e-300)
                predicted = float(np.sum(gs[ok_w] ** 2 / w[ok_w]))
                if give_up is not None and give_up(chi2, predicted):
                    break
            tol_w = 1e-13 * max(w.max(), 1e-300)
            trials = []
            for lam in _LAMBDAS * lam_scale:
                den = w + lam
                step = -(V @ np.where(den > tol_w, gs / np.where(den > tol_w, den, 1.0), 0.0)) / d
                t2 = theta.copy()
                t2[idx] += step
                trials.append(t2)
            R = self.residuals(np.array(trials))
            c2 = np.einsum("ij,ij->i", R, R)
            c2 = np.where(np.isfinite(c2), c2, np.inf)
            k = int(np.argmin(c2))
            if c2[k] >= chi2:
                lam_scale *= 100.0
                if lam_scale > 1e6:
                    converged = True  # no direction lowers chi^2: at the minimum
                    break
                continue
            gain = chi2 - float(c2[k])
            theta, r, chi2 = trials[k], R[k], float(c2[k])
            stale = True
            lam_scale = max(lam_scale * (0.3 if k <= 2 else 1.0), 1e-3)
            linear = k == 0 and abs(gain - predicted) < 0.1 * predicted
            if gain < tol + 1e-10 * chi2 or (linear and gain < 1.0):
                converged = True
                break
        return LMResult(theta=theta, r=r, chi2=chi2, iterations=it, converged=converged)
