"""A speed modulation evaluated exactly (not linearised): the base model's kinematics with
v -> v (1 + m) everywhere, m a Fourier series in t or psi (MODEL.md §5, §3's conventions:
X, a, so F and s, and psi all follow the modulated speed), positions from the model's own
stadium path. At tens of hertz the slip's answer to the modulated acceleration,
v_t = v / (1 - s(a)), is not small, and its mean over a cycle moves the slip: the linear
term finds the modulation, this refits it (:func:`refine`), its frequency with it.

In psi the modulation's phase is read at the model's own belt travel, which the
modulation itself moves (RK4 through the model's grid, as :func:`fitlug.model.integrate`
does a catalog modulation): a 46 Hz cogging of 1.7 % swings the slip by +- 0.1 and the
belt 0.08 mm, a tenth of a radian of the phase. The slip law's term (:mod:`._slip`) is
evaluated like a modulation in t (:func:`residuals_with`).

:func:`refine` is Levenberg-Marquardt on the exact residuals, written in JAX so that their
Jacobian in the fit's parameters and the term's coefficients is exact: the linear term's
solution can move weakly held parameters far (a speed spline's knots at the edge of the
window, near-degenerate with a cogging at 19 Hz moved by 20 mm/s), where the base model's
Jacobian no longer holds; with it, Gauss-Newton from there stalled at chi2/dof 1.5-6.9
where the exact minimum is at 0.96 (cogging, bench_discovery seed 1001). Each start is
first settled in the fit's parameters alone, and the steps carry Transtrum's geodesic
acceleration: a term's second-order effect (the cogging's mean belt rate, quadratic in its
amplitude, against a slip held to 1e-5) is a narrow curved valley that straight steps
crawl along (60 steps from chi2/dof 14 to 1.8; with both, 20 to 0.66). The Jacobian at
the solution is returned for the extended fit's covariance.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ...fit._residuals import _weighted
from ...model import hermite, positions, slip_law
from ...model._model import speed_basis_values

MAX_STEPS = 30
START_SCALES = (1.0, 0.5, 0.25, 0.0)  # 0: the fit itself, never worse than it
LM_LAMBDA0 = 1e-3
LM_TRIES = 6
GEODESIC_H = 0.1  # finite-difference step of the geodesic acceleration, of the step
GEODESIC_ALPHA = 0.75  # the acceleration's largest share of the step (Transtrum's alpha)
SETTLE_STEPS = 4  # steps of the fit's parameters alone from each start
FIXED_POINT_ITERATIONS = 6  # as tests/mechanisms.py's truth; fitlug.model uses 4


def residuals_with(res, rates):
    """A function (flat, c) -> weighted residuals (S,) of `res`'s model whose speed v and
    belt rate d psi / dt at the integration nodes (grid and midpoints) are
    `rates(p, v0, a0, c)` -> (v, dpsi) from the base speed v0 and acceleration a0."""
    lay, obs, params_at = _model_of(res)
    G = lay.grid.shape[0]

    def fn(flat, c):  # JAX throughout: refine differentiates it
        p = params_at(flat)
        v0n, a0n, v0m, a0m = speed_basis_values(lay, p["v"])
        v, dpsi = rates(p, jnp.concatenate([v0n, v0m]), jnp.concatenate([a0n, a0m]),
                        jnp.asarray(c, float))
        # Simpson on the node grid, then X = psi = 0 at t_ref
        X, P = (_simpson(lay, y[:G], y[G:]) for y in (v, dpsi))
        return _at_samples(p, lay, obs, X, v[:G], P, dpsi[:G])

    return _exact_fn(fn)


def _model_of(res):
    """(layout, observations, flat -> the parameters (JAX)) of `res`'s model."""
    packing = res.packing
    fixed = {q: jnp.asarray(v, float) for q, v in res.params.items() if q not in packing.names}
    return res.problem.lay, res.problem.obs, lambda flat: packing.unpack(jnp.asarray(flat),
                                                                         fixed)


def _simpson(lay, yn, ym):
    """Cumulative Simpson integral on the layout's grid of node values yn, midpoints ym
    (0 at the grid's start)."""
    return jnp.concatenate([jnp.zeros(1), jnp.cumsum(lay.h / 6 * (yn[:-1] + 4 * ym
                                                                   + yn[1:]))])


def _at_samples(p, lay, obs, X, vX, P, vP):
    """Weighted residuals of the model's positions with node values X, psi (rates vX, vP)
    Hermite-interpolated at the sample times, both 0 at t_ref."""
    t0 = jnp.asarray(lay.t_ref, float)
    Xl = hermite(lay, lay.lug_t, X, vX) - hermite(lay, t0, X, vX)
    Pl = hermite(lay, lay.lug_t, P, vP) - hermite(lay, t0, P, vP)
    Xb = hermite(lay, lay.body_t, X, vX) - hermite(lay, t0, X, vX)
    Pb = hermite(lay, lay.body_t, P, vP) - hermite(lay, t0, P, vP)
    return _weighted(positions(p, lay, Xl, Pl, Xb, Pb), obs)


def _exact_fn(fn):
    """`fn` (flat, c) -> residuals (JAX) as :func:`refine` takes it: numpy in and out,
    jit-compiled, with `.jacobian` (d r / d flat, d r / d c) by forward differentiation."""
    fn_jit = jax.jit(fn)

    def exact(flat, c):
        return np.asarray(fn_jit(jnp.asarray(flat, float), jnp.asarray(c, float)))

    exact.jacobian = jax.jit(jax.jacfwd(fn, argnums=(0, 1)))
    return exact


def nodes(res) -> np.ndarray:
    """The integration nodes of `res`'s model: its grid, then the midpoints."""
    lay = res.problem.lay
    grid = np.asarray(lay.grid)
    return np.r_[grid, grid[:-1] + float(lay.h) / 2]


def speed_residuals(res, ctx, coord: str, f: float, n: int):
    """A function (flat, c) -> weighted residuals (S,) of `res`'s model with the speed
    modulation m = sum_k c_k sin(2 pi k f' u) + c_{n+k} cos(...), f' = f (1 + c_{2n}):
    the frequency is refitted with the coefficients (``n_free`` = 1, the last entry of c,
    not a column of the linear term).

    u = t (a fixed frequency), or u = psi / v_t,cruise with psi the model's own belt travel
    (:func:`_psi_residuals`): locked to the drive, the modulation's phase follows the belt
    as the modulation itself moves it (46 Hz cogging with 1.7 % of speed: the slip answers
    the modulated acceleration by +- 0.1, the belt runs 0.08 mm ahead and behind, a tenth
    of a radian of the phase; read at the base fit's belt travel the refit held chi^2/dof
    at 10 and the slip 80 sigma off)."""
    tn = nodes(res)
    vt = float(np.max(np.abs(ctx.vt_nodes)))
    k = np.arange(1, n + 1)
    if coord == "t":
        u0 = 0.5 * (float(np.min(tn)) + float(np.max(tn)))
    else:
        u_b = np.interp(tn, ctx.grid, ctx.psi_nodes) / vt
        u0 = 0.5 * (float(np.min(u_b)) + float(np.max(u_b)))
    # the phase about the window's middle, so that a change of frequency does not swing
    # the phase of the whole cycle (a parameter near-degenerate with the coefficients)
    turn = jnp.asarray(2 * np.pi * f * k * u0)
    w0 = jnp.asarray(2 * np.pi * f * k)

    def m_of(u, c):
        """(m, dm/du) at coordinate values u (any shape) for coefficients c."""
        g = 1.0 + c[2 * n]
        ph = (u[..., None] - u0) * (w0 * g) + turn
        S, C = jnp.sin(ph), jnp.cos(ph)
        return S @ c[:n] + C @ c[n:2 * n], (C * (w0 * g)) @ c[:n] - (S * (w0 * g)) @ c[n:2 * n]

    if coord == "t":
        lay = res.problem.lay
        tn_j = jnp.asarray(tn)

        def rates(p, v0, a0, c):
            m, dm = m_of(tn_j, c)
            v = v0 * (1 + m)
            a = a0 * (1 + m) + v0 * dm
            return v, v / (1 - slip_law(p, lay, a))

        exact = residuals_with(res, rates)
    else:
        exact = _psi_residuals(res, lambda psi, c: m_of(psi / vt, c), vt)
    exact.n_free = 1
    exact.free_frequency = lambda free: f * (1.0 + (float(free[0]) if len(free) else 0.0))
    # the cycles at coordinate u (the phase the shape's cycle fraction is read in)
    exact.cycles = lambda uu, free: (exact.free_frequency(free) * (np.asarray(uu) - u0)
                                     + f * u0)
    return exact


def _psi_residuals(res, m_of, vt: float):
    """(flat, c) -> weighted residuals of `res`'s model with v -> v (1 + m(psi)), psi the
    model's own belt travel from t_ref: integrated by RK4 on the model's grid as
    :func:`fitlug.model.integrate` integrates a catalog speed modulation in psi, the
    acceleration (so the slip) through dm/dt = dm/dpsi dpsi/dt by fixed-point iteration.
    `m_of(psi, c)` -> (m, dm/du) with u = psi / vt. The belt travel from the grid's start
    to t_ref is the unmodulated model's, so that the phase stays anchored at t_ref when the
    fit's slip moves."""
    lay, obs, params_at = _model_of(res)
    G = lay.grid.shape[0]
    h = float(lay.h)

    def fn(flat, c):
        p = params_at(flat)
        c = jnp.asarray(c, float)
        v0n, a0n, v0m, a0m = speed_basis_values(lay, p["v"])
        d0n = v0n / (1 - slip_law(p, lay, a0n))
        P0 = _simpson(lay, d0n, v0m / (1 - slip_law(p, lay, a0m)))
        # psi at the grid's start, from t_ref
        start = -hermite(lay, jnp.asarray(lay.t_ref, float), P0, d0n)

        def rate(v0, a0, psi):
            m, dm_du = m_of(psi, c)
            dm = dm_du / vt  # d m / d psi
            v = v0 * (1 + m)
            dpsi = v / (1 - slip_law(p, lay, a0 * (1 + m)))
            for _ in range(FIXED_POINT_ITERATIONS):  # a depends on dpsi/dt through m(psi)
                dpsi = v / (1 - slip_law(p, lay, a0 * (1 + m) + v0 * dm * dpsi))
            return v, dpsi

        def step(state, kk):
            x0, s0 = state
            k1 = rate(v0n[kk], a0n[kk], s0)
            k2 = rate(v0m[kk], a0m[kk], s0 + h / 2 * k1[1])
            k3 = rate(v0m[kk], a0m[kk], s0 + h / 2 * k2[1])
            k4 = rate(v0n[kk + 1], a0n[kk + 1], s0 + h * k3[1])
            x1 = x0 + h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
            s1 = s0 + h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
            return (x1, s1), (x1, s1)

        _, (Xs, Ps) = jax.lax.scan(step, (jnp.zeros(()), start), jnp.arange(G - 1))
        X = jnp.concatenate([jnp.zeros(1), Xs])
        P = jnp.concatenate([start[None], Ps])
        vX, vP = rate(v0n, a0n, P)
        return _at_samples(p, lay, obs, X, vX, P, vP)

    return _exact_fn(fn)


def base_residuals(res):
    """The fit's own model as :func:`residuals_with` writes it (no term of its own): for
    refitting terms that are linear in their coefficients (``idx`` empty in :func:`refine`)."""
    lay = res.problem.lay

    def rates(p, v0, a0, c):
        return v0, v0 / (1 - slip_law(p, lay, a0))

    return residuals_with(res, rates)


def refine(proj, ctx, B, c, exact, idx) -> tuple:
    """Gauss-Newton on exact residuals from the linear solution: (flat, c, residuals, free,
    (J, B)), the last the extended model's Jacobian at the solution (the fit's parameters;
    the terms' coefficients and `free`), for the covariance.

    `exact(flat, c[idx] + free)` gives the residuals of the fit's model with the exact term
    of coefficients c[idx] and `exact.n_free` (0 unless set) further parameters of its own
    (a speed modulation's frequency), started at 0 and returned as `free`; a function of
    :func:`residuals_with`, which carries its exact Jacobian. The other columns of B add
    linearly. Every step recomputes the extended model's Jacobian where the parameters now
    are."""
    others = np.setdiff1d(np.arange(B.shape[1]), idx)
    B0 = B
    n_free = int(getattr(exact, "n_free", 0))
    m = len(idx)
    v = proj.valid

    def resid(flat, cc, free):
        return exact(flat, np.r_[cc[idx], free]) + B0[:, others] @ cc[others]

    last = {}  # the Jacobian last computed, by its point

    def jacobian(flat, c, free):
        """(J, B): d r / d flat and the columns of the terms' coefficients and `free`."""
        at = np.r_[flat, c, free]
        if "at" in last and np.array_equal(last["at"], at):
            return last["jac"]
        Jf, Jc = (np.asarray(q) for q in exact.jacobian(
            jnp.asarray(flat, float), jnp.asarray(np.r_[c[idx], free], float)))
        Bx = B0.copy()
        Bx[:, idx] = Jc[:, :m]
        last.update(at=at, jac=(Jf, np.hstack([Bx, Jc[:, m:]])))
        return last["jac"]

    def lm_step(flat, c, free, r, chi2, lam, fit_only=False):
        """One Levenberg-Marquardt step from residuals r with the extended model's own
        Jacobian where the parameters are (`fit_only`: the fit's parameters alone, the term
        held); None when no step lowers chi^2."""
        Jf, Bx = jacobian(flat, c, free)
        A = Jf[v] if fit_only else np.hstack([Jf[v], Bx[v]])
        d = np.sqrt(np.sum(A * A, 0))
        d = np.where(d > 0, d, 1.0)
        As = A / d
        N = As.T @ As
        grad = As.T @ r[v]
        n_p, n_c = Jf.shape[1], B0.shape[1]

        def moved(step):
            step = np.r_[step, np.zeros(n_c + n_free)] if fit_only else step
            return flat + step[:n_p], c + step[n_p:n_p + n_c], free + step[n_p + n_c:]

        for _ in range(LM_TRIES):  # a step the model can follow
            M = N + lam * np.diag(np.diag(N) + 1e-12)
            step = -np.linalg.solve(M, grad) / d
            # geodesic acceleration (Transtrum & Sethna 2012): the step bent along the
            # curve of the valley; the second directional derivative of the residuals by
            # a finite difference. A term's second-order effect (the mean belt rate of a
            # cogging's slip answer, quadratic in its amplitude) makes a narrow parabolic
            # valley with the slip, along which straight steps crawl
            rh = resid(*moved(GEODESIC_H * step))
            r_vv = 2.0 / GEODESIC_H * ((rh[v] - r[v]) / GEODESIC_H - A @ step)
            acc = -np.linalg.solve(M, As.T @ r_vv) / d
            if np.all(np.isfinite(acc)) and \
                    2 * np.linalg.norm(acc * d) <= GEODESIC_ALPHA * np.linalg.norm(step * d):
                step = step + 0.5 * acc
            new = moved(step)
            r2 = resid(*new)
            c2 = float(r2[v] @ r2[v])
            if np.isfinite(c2) and c2 < chi2:
                return new, r2, c2, max(lam / 10, 1e-9)
            lam *= 10
        return None

    flat0 = np.asarray(ctx.res.flat, float)
    free = np.zeros(n_free)
    step = proj.solve(ctx.r + B @ c)
    # the start: the linear solution, or a fraction of it where the exact model leaves the
    # linear one (a term near-degenerate with weakly held parameters, a speed spline's
    # knots at the window's edge, moves them far, and the stadium path bends under that);
    # each settled first by a few steps of the fit's parameters alone, the term held: what
    # the term does at second order (a 46 Hz cogging's slip answer runs the belt 0.6 %
    # faster on average, 4 mm over the window) is the fit's to take up (the slip), and
    # unsettled the linear solution read chi^2/dof 3767 where it leads to 1
    best = None
    for scale in START_SCALES:
        x = (flat0 - scale * step, scale * c, free)
        r = resid(*x)
        chi2 = float(r[v] @ r[v])
        lam = LM_LAMBDA0
        for _ in range(SETTLE_STEPS if scale > 0 else 0):
            out = lm_step(*x, r, chi2, lam, fit_only=True)
            if out is None:
                break
            gain = chi2 - out[2]
            x, r, chi2, lam = out
            if gain < 1e-3 * chi2:
                break
        if np.isfinite(chi2) and (best is None or chi2 < best[0]):
            best = (chi2, x, r)
    chi2, (flat, c, free), r = best
    lam = LM_LAMBDA0
    for _ in range(MAX_STEPS):
        out = lm_step(flat, c, free, r, chi2, lam)
        if out is None:
            break
        gain = chi2 - out[2]
        (flat, c, free), r, chi2, lam = out
        if gain < 1e-3 * max(chi2, 1.0) ** 0.5:
            break
    return flat, c, r, free, jacobian(flat, c, free)
