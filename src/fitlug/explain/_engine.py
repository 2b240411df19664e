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

Long recordings (the dense Jacobian above CHUNKED_ENTRIES entries, a base model the
chunked normal equations take: :func:`fitlug.fit._chunks.chunkable`) never form the
Jacobian: :meth:`Engine.jacobian` returns a :class:`NormalJacobian`, which holds J^T J
and J^T r accumulated over time chunks of the base block's rows
(:class:`fitlug.fit._rowchunks.RowChunks`) and the difference columns; the fit, the screening
(:mod:`._candidates`), the final polish, the robust errors and the systematics check use
it through J^T J and J^T v only. Same values as the dense path to rounding
(tests/test_scale.py); memory linear in the samples.

Longer than 400 lines because the Engine class alone is ~360 lines (one compiled model
and the state its methods share), and the limits the tests patch (CHUNKED_ENTRIES, STORE,
BATCH_ENTRIES, BLOCK_ENTRIES) must stay in the module of the code that reads them.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from .. import _jaxconfig  # noqa: F401
from ..fit import residuals
from ..fit._chunks import BLOCK_ENTRIES, chunkable, nodes_batch, time_blocks, trim_heap
from ..fit._lsq import LARGE_ENTRIES
from ..fit._residuals import Packing, jacobian
from ..fit._rowchunks import RowChunks
from ..model import CATALOG, param_names
from ._normal import NormalJacobian

COUPLED = ("s0", "beta", "R", "D", "e", "x_off", "y_off")
CHUNK = 8  # model evaluations per batched call (fixed, so one compilation serves all)
_BASE_STEPS = {"s0": 1e-5, "beta": 1e-9, "R": 1e-4, "D": 1e-4, "e": 1e-4, "x_off": 1e-4,
               "y_off": 1e-4}
#: an LM step of the search that gains less (in chi^2) than this, and under a quarter of
#: the step before, ends the fit (:meth:`Engine.fit`)
SETTLED_GAIN = 0.5
_LAMBDAS = np.array([0.0, 1e-6, 1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0])
#: dense Jacobian entries above which the engine works on chunked normal equations
CHUNKED_ENTRIES = LARGE_ENTRIES
#: residual entries per batched model evaluation (the batch shrinks on long recordings,
#: or, where time blocks apply, the samples' part runs in blocks of BLOCK_ENTRIES / CHUNK)
BATCH_ENTRIES = 4_000_000
#: residual entries a batch's output may hold on the blocked path (128 MB)
RESULT_ENTRIES = 16_000_000


def use_chunks(lay, packing, params) -> bool:
    """Whether a problem's Jacobian is handled in time chunks rather than formed."""
    n_res = 2 * (lay.lug_t.shape[0] + lay.body_t.shape[0])
    return (n_res * sum(packing.sizes) > CHUNKED_ENTRIES
            and chunkable(params, lay, packing))


def jacobian_of(flat, fixed, packing, lay, obs):
    """The dense Jacobian (numpy) of a problem, or its :class:`RowChunks` when long."""
    if use_chunks(lay, packing, {**fixed, **packing.unpack(jnp.asarray(flat), {})}):
        return RowChunks(jnp.asarray(flat), fixed, lay, obs, packing)
    return np.asarray(_jac_block(jnp.asarray(flat), fixed, packing, lay, obs))


#: storage of the long recordings' difference columns (the engine's coupled and extra
#: columns F, the screened alternatives' columns C): float32, which halves their memory,
#: the largest share of an explanation's peak on 100 000 frames (9 columns of 2.8 M rows:
#: 200 -> 100 MB). Each difference is computed in float64 and rounded once when stored
#: (2-3e-8 relative: more than the central differences' own error on the base columns,
#: 1e-9 to 1e-11), and every product with them sums in float64 (:func:`tdot`). They only
#: steer the search (its screening and LM steps, each step judged on exact residuals);
#: the final fit's polish and errors use the exact Jacobian. Measured on a 30 000-frame
#: belt-sag recording against float64 storage (benchmarks/results/2026-11-26c): both
#: rounds' screened delta chi^2 of every catalog effect within 7e-5 relative (1e-4 in
#: chi^2), their starts within 4e-5, the sag's LM fit within 4e-6 in chi^2 of 8.4e5.
STORE = np.float32


@partial(jax.jit, static_argnames=("packing",))
def _res_batch(flats, packing, lay, obs):
    return jax.vmap(lambda f: residuals(packing.unpack(f, {}), lay, obs))(flats)


@partial(jax.jit, static_argnames=("packing",))
def _res_from_nodes(flats, nodes, packing, lay, obs):
    """:func:`_res_batch` of the samples of `lay` (a time block) from the node values."""
    from ..fit._residuals import _residuals_from_nodes

    return jax.vmap(lambda f, *nd: _residuals_from_nodes(f, {}, lay, obs, packing, nd))(
        flats, *nodes)


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
        self.prob_all, p_all = prob.with_effects(
            tuple(e for e in CATALOG if CATALOG[e].searched or e in res.effects), res.params)
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
        n_res = 2 * (self.obs["lug_w"].shape[0] + self.obs["body_w"].shape[0])
        self.n_res = n_res
        self.batch = int(max(1, min(CHUNK, BATCH_ENTRIES // max(n_res, 1))))
        self.blocks = None
        if self.batch < CHUNK:
            # long recordings: the batch stays CHUNK wide (the integration's sequential
            # scan over the grid costs about as much for one lane as for eight) as long as
            # its residual vectors stay under RESULT_ENTRIES; the samples' part of the
            # model, whose temporaries grow with the samples, runs by time blocks
            blocks = time_blocks(self.lay_all, self.obs, max_rows=BLOCK_ENTRIES // CHUNK,
                                 plans=False)
            if blocks is not None:
                self.blocks = blocks
                self.batch = int(max(1, min(CHUNK, RESULT_ENTRIES // max(n_res, 1))))
        self.chunked = use_chunks(prob.lay, res.packing, res.params)
        # the all-effects packing's entries that the starting model lacks (the catalog's
        # effects it does not hold): at their identity values the all-effects model IS the
        # starting model, whose analytic columns are then exact
        self.other_idx = np.concatenate(
            [np.arange(sl.start, sl.stop) for k, sl in self.slices.items()
             if k not in res.params] or [np.zeros(0, int)]).astype(int)

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
        out = np.empty((len(thetas), self.n_res))  # written in place: no stacked copy
        B = self.lanes
        for i in range(0, len(thetas), B):
            blk = thetas[i:i + B]
            pad = np.vstack([blk, np.repeat(blk[-1:], B - len(blk), 0)])
            if self.blocks is None:
                out[i:i + len(blk)] = np.asarray(_res_batch(
                    jnp.asarray(pad), self.packing, self.lay_all, self.obs))[:len(blk)]
            else:
                self._blocked_residuals(jnp.asarray(pad), out[i:i + len(blk)])
            self.evaluations += len(blk)
        return out

    def _blocked_residuals(self, pad, out) -> None:
        """:func:`_res_batch` on a long recording, written into `out` (its first rows):
        one integration for the batch, the samples by time blocks."""
        trim_heap()
        nodes = nodes_batch(pad, {}, self.lay_all, self.packing)
        n = out.shape[0]
        for lay_k, obs_k, rows_k in zip(self.blocks.lays, self.blocks.obss, self.blocks.rows):
            rk = np.asarray(_res_from_nodes(pad, nodes, self.packing, lay_k, obs_k))
            real = rows_k >= 0
            out[:, rows_k[real]] = rk[:n, real]

    def chi2_best(self, thetas) -> tuple:
        """(chi^2 of each vector (inf where not finite), index of the lowest, its residuals),
        one batch of residual vectors in memory at a time."""
        c2 = np.empty(len(thetas))
        k, best = 0, None
        B = self.batch
        for i in range(0, len(thetas), B):
            R = self.residuals(thetas[i:i + B])
            c = np.einsum("ij,ij->i", R, R)
            c2[i:i + len(R)] = np.where(np.isfinite(c), c, np.inf)
            j = i + int(np.argmin(c2[i:i + len(R)]))
            if best is None or c2[j] < c2[k]:
                k, best = j, R[j - i].copy()
        return c2, k, best

    def base_jacobian(self, theta) -> np.ndarray:
        """Jacobian of the starting model wrt its free parameters at theta, (S, n).

        Exact for the starting model; an added effect that maps the time stamps
        (frame_drop) is applied to the sample times first, since a 10 ms shift changes the
        fine speed-spline columns by tens of percent after the lost frame.
        """
        flat, fixed, lay = self._base_problem(theta)
        return np.asarray(_jac_block(flat, fixed, self.cur_packing, lay, self.obs))

    def base_chunks(self, theta) -> RowChunks:
        """:meth:`base_jacobian` as time chunks of rows (long recordings)."""
        flat, fixed, lay = self._base_problem(theta)
        return RowChunks(flat, fixed, lay, self.obs, self.cur_packing)

    def _base_problem(self, theta):
        flat = self._tangent_law(np.asarray(theta[self.cur_idx], float), theta)
        flat = jnp.asarray(flat)
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
        return flat, fixed, lay

    def _tangent_law(self, flat, theta):
        """The starting model's linear slip law put on the tangent of an added lug_sliding
        at the steady state (s0 -> S, beta -> B = beta / (1 - z0), z0 = mu s0): its
        columns of the speed spline (and of everything whose change moves the slip
        through the acceleration) then carry the slope ds/da the all-effects model has
        there. Left at the law's own s0 and beta they are 1 - z0 of it, a factor 4 at
        F0/F_max = 0.75, and the fit crawls (issue 32). s0 and beta's own columns are the
        all-effects model's differences anyway (COUPLED)."""
        if "lug_sliding" in self.res.effects or "slide_mu" not in self.slices:
            return flat
        mu = self.get(theta, "slide_mu")
        pos = self.cur_positions
        if mu == 0 or "s0" not in pos or "beta" not in pos:
            return flat
        s0, beta = flat[pos["s0"]], flat[pos["beta"]]
        z = mu * s0
        if not 0 < z < 1:
            return flat
        out = flat.copy()
        out[pos["s0"]] = -np.log1p(-z) / mu
        out[pos["beta"]] = beta / (1.0 - z)
        return out

    @property
    def lanes(self) -> int:
        """Parameter vectors per batched model evaluation. A long recording's blocks write
        residuals and differences into the caller's arrays block by block, so its batch
        keeps CHUNK lanes whatever the results' cap (RESULT_ENTRIES) makes of self.batch,
        which caps the residual vectors held at once elsewhere."""
        return CHUNK if self.blocks is not None else self.batch

    def effects_active(self, theta) -> bool:
        """Whether theta moves any effect the starting model lacks off its identity."""
        i = self.other_idx
        return bool(np.any(np.asarray(theta)[i] != self.theta0[i]))

    def step_of(self, name: str) -> float:
        for cls in CATALOG.values():
            if name in cls.scales:
                return 1e-2 * cls.scales[name]
        return _BASE_STEPS.get(name, 1e-6)

    def fd_columns(self, specs, theta, dtype=np.float64) -> np.ndarray:
        """Central-difference columns (S, len(specs)); spec = (settings dict, param name).

        dtype: the columns' storage (:data:`STORE`: float32 on long recordings; each
        difference is computed in float64 and rounded once when stored)."""
        n_res = len(self.obs["lug_w"]) * 2 + len(self.obs["body_w"]) * 2
        if not specs:
            return np.zeros((n_res, 0), dtype)
        out = np.empty((n_res, len(specs)), dtype)
        per = max(1, self.lanes // 2)  # columns per batched evaluation
        for j0 in range(0, len(specs), per):
            pts, hs = [], []
            for settings, name in specs[j0:j0 + per]:
                th = self.with_values(theta, settings)
                h = self.step_of(name)
                i = self.index(name)
                for sgn in (1.0, -1.0):
                    t2 = th.copy()
                    t2[i] += sgn * h
                    pts.append(t2)
                hs.append(h)
            if self.blocks is not None:
                # long recordings: the differences written block by block, never the
                # batch's (2 per, S) residual vectors (180 MB at 100 000 frames)
                self._blocked_differences(np.array(pts), hs, out[:, j0:j0 + len(hs)])
                continue
            R = self.residuals(np.array(pts))
            for k in range(len(hs)):
                out[:, j0 + k] = (R[2 * k] - R[2 * k + 1]) / (2 * hs[k])
        return out

    def _blocked_differences(self, pts, hs, out) -> None:
        """Central differences (R(+h) - R(-h)) / 2h of the pairs of vectors `pts` (one
        batch) into the columns of `out`, one time block at a time."""
        pad = jnp.asarray(np.vstack([pts, np.repeat(pts[-1:], CHUNK - len(pts), 0)]))
        trim_heap()
        nodes = nodes_batch(pad, {}, self.lay_all, self.packing)
        h2 = 2.0 * np.asarray(hs, float)
        for lay_k, obs_k, rows_k in zip(self.blocks.lays, self.blocks.obss, self.blocks.rows):
            rk = np.asarray(_res_from_nodes(pad, nodes, self.packing, lay_k, obs_k))
            real = rows_k >= 0
            d = (rk[0:2 * len(hs):2] - rk[1:2 * len(hs):2])[:, real] / h2[:, None]
            out[rows_k[real], :] = d.T
        self.evaluations += len(pts)

    def jacobian(self, theta, extra: list[str], r=None):
        """[base block | columns of the `extra` scalar parameters] at theta.

        The base block's scalar physics and geometry columns (s0, beta, R, D, e, x_off,
        y_off) are replaced by differences of the all-effects model: an effect such as
        lug_sliding changes them by tens of percent, the spline and offset columns by
        at most the effect's relative size.

        Where theta holds every effect the starting model lacks at its identity value
        (the first round's screening), the all-effects model is the starting model and its
        analytic columns stay (no differences: on a long recording 7 columns of S doubles,
        160 MB at 100 000 frames).

        Long recordings (self.chunked): a :class:`NormalJacobian` (J^T J, J^T r with `r`
        the residuals at theta, computed when not given), never the dense matrix.
        """
        coupled = [k for k in COUPLED if k in self.cur_packing.names] \
            if self.effects_active(theta) else []
        if self.chunked:
            F = self.fd_columns([({}, k) for k in coupled + list(extra)], theta, STORE)
            if r is None:
                r = self.residuals(theta)[0]
            return NormalJacobian(self.base_chunks(theta), F,
                                  [self.cur_positions[k] for k in coupled], np.asarray(r))
        Jb = np.array(self.base_jacobian(theta))
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
        or when a step gains less than SETTLED_GAIN and under a quarter of the step
        before (the steps converging geometrically: what is left is under a third of the
        last gain, < 0.2 in chi^2, nothing to the search's criterion on Delta BIC; the
        final fit polishes the chosen model anyway), or when `give_up(chi2,
        predicted_decrease)` says the fit cannot win anyway.

        The second-to-last rule matters on long recordings: there the Gauss-Newton model
        of the phase-like parameters (slip, slip law) overestimates the curvature (along
        the first step of a belt sag's fit at 100 000 frames, chi^2's curvature is 0.86
        of J^T J's), each step gains ~1.25 times its prediction and the steps converge
        linearly (~0.1 per step): 8 steps at 100 000 frames against 3 at 30 000, the last
        two for a gain of 0.2 (benchmarks/results/2026-11-26).
        """
        theta = np.array(theta0, float)
        idx = np.r_[self.cur_idx, [self.index(k) for k in extra]].astype(int)
        r = self.residuals(theta)[0] if r0 is None else np.asarray(r0)
        chi2 = float(r @ r)
        converged = False
        it = 0
        lam_scale = 1.0
        stale = True
        prev_gain = np.inf
        for it in range(1, max_iter + 1):
            if stale:
                if self.chunked:
                    # only J^T J and J^T r are needed: the chunks and the difference
                    # columns (tens of doubles per residual) go before the next step's
                    A, g = self.jacobian(theta, extra, r).normal()
                else:
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
            c2, k, r_k = self.chi2_best(np.array(trials))
            if c2[k] >= chi2:
                lam_scale *= 100.0
                if lam_scale > 1e6:
                    converged = True  # no direction lowers chi^2: at the minimum
                    break
                continue
            gain = chi2 - float(c2[k])
            theta, r, chi2 = trials[k], r_k, float(c2[k])
            stale = True
            lam_scale = max(lam_scale * (0.3 if k <= 2 else 1.0), 1e-3)
            linear = k == 0 and abs(gain - predicted) < 0.1 * predicted
            settled = gain < SETTLED_GAIN and gain < 0.25 * prev_gain
            if gain < tol + 1e-10 * chi2 or (linear and gain < 1.0) or settled:
                converged = True
                break
            prev_gain = gain
        return LMResult(theta=theta, r=r, chi2=chi2, iterations=it, converged=converged)


def _alternative_columns(engine, NJ, theta, alts, per_pass: int = 4):
    """(alternative, its settings vector, columns C, J^T C) for each alternative; J^T C of
    a few alternatives' columns per pass over the time chunks."""
    group = []

    def flush():
        JtC = NJ.Jt([g[2] for g in group])  # no stacked copy of the group's columns
        k = 0
        for alt, th, C in group:
            yield alt, th, C, JtC[:, k:k + C.shape[1]]
            k += C.shape[1]

    for alt in alts:
        th = engine.with_values(theta, alt.settings)
        group.append((alt, th, engine.fd_columns(alt.columns, th, STORE)))
        if sum(g[2].shape[1] for g in group) >= per_pass:
            yield from flush()
            group = []
    if group:
        yield from flush()
