"""A speed modulation evaluated exactly (not linearised): the base model's kinematics with
v -> v (1 + m) everywhere, m a Fourier series in t or psi (MODEL.md §5, §3's conventions:
X, a, so F and s, and psi all follow the modulated speed), positions from the model's own
stadium path. At tens of hertz the slip's answer to the modulated acceleration,
v_t = v / (1 - s(a)), is not small, and its mean over a cycle moves the slip: the linear
term finds the modulation, this refits it (:func:`refine`).

The modulation's phase is read at the base fit's belt travel psi(t) (the modulation
itself moves psi by ~ eps x period / 2 pi, micrometres: a phase error of 1e-3 rad).
The slip law's term (:mod:`._slip`) is evaluated the same way (:func:`residuals_with`).

:func:`refine` is Levenberg-Marquardt on the exact residuals, written in JAX so that their
Jacobian in the fit's parameters and the term's coefficients is exact: the linear term's
solution can move weakly held parameters far (a speed spline's knots at the edge of the
window, near-degenerate with a cogging at 19 Hz moved by 20 mm/s), where the base model's
Jacobian no longer holds; with it, Gauss-Newton from there stalled at chi2/dof 1.5-6.9
where the exact minimum is at 0.96 (cogging, bench_discovery seed 1001).
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


def residuals_with(res, rates):
    """A function (flat, c) -> weighted residuals (S,) of `res`'s model whose speed v and
    belt rate d psi / dt at the integration nodes (grid and midpoints) are
    `rates(p, v0, a0, c)` -> (v, dpsi) from the base speed v0 and acceleration a0."""
    prob = res.problem
    lay, obs = prob.lay, prob.obs
    grid = np.asarray(lay.grid)
    h = float(lay.h)
    packing = res.packing
    fixed = {q: jnp.asarray(v, float) for q, v in res.params.items() if q not in packing.names}
    G = len(grid)

    def fn(flat, c):  # JAX throughout: refine differentiates it
        p = packing.unpack(jnp.asarray(flat), fixed)
        v0n, a0n, v0m, a0m = speed_basis_values(lay, p["v"])
        v, dpsi = rates(p, jnp.concatenate([v0n, v0m]), jnp.concatenate([a0n, a0m]),
                        jnp.asarray(c, float))
        out = []
        for y in (v, dpsi):  # Simpson on the node grid, then X = psi = 0 at t_ref
            yn, ym = y[:G], y[G:]
            cum = jnp.concatenate([jnp.zeros(1),
                                   jnp.cumsum(h / 6 * (yn[:-1] + 4 * ym + yn[1:]))])
            out.append((cum, yn))
        (X, vX), (P, vP) = out
        t0 = jnp.asarray(lay.t_ref, float)
        Xl = hermite(lay, lay.lug_t, X, vX) - hermite(lay, t0, X, vX)
        Pl = hermite(lay, lay.lug_t, P, vP) - hermite(lay, t0, P, vP)
        Xb = hermite(lay, lay.body_t, X, vX) - hermite(lay, t0, X, vX)
        Pb = hermite(lay, lay.body_t, P, vP) - hermite(lay, t0, P, vP)
        return _weighted(positions(p, lay, Xl, Pl, Xb, Pb), obs)

    fn_jit = jax.jit(fn)

    def exact(flat, c):
        return np.asarray(fn_jit(jnp.asarray(flat, float), jnp.asarray(c, float)))

    exact.jacobian = jax.jit(jax.jacfwd(fn, argnums=(0, 1)))  # (d r / d flat, d r / d c)
    return exact


def nodes(res) -> np.ndarray:
    """The integration nodes of `res`'s model: its grid, then the midpoints."""
    lay = res.problem.lay
    grid = np.asarray(lay.grid)
    return np.r_[grid, grid[:-1] + float(lay.h) / 2]


def speed_residuals(res, ctx, coord: str, f: float, n: int):
    """A function (flat, c) -> weighted residuals (S,) of `res`'s model with the speed
    modulation m = sum_k c_k sin(2 pi k f u) + c_{n+k} cos(...), u = t or psi / v_t,cruise."""
    lay = res.problem.lay
    tn = nodes(res)
    vt = float(np.max(np.abs(ctx.vt_nodes)))
    psi_b = np.interp(tn, ctx.grid, ctx.psi_nodes)
    vt_b = np.interp(tn, ctx.grid, ctx.vt_nodes)
    u = tn if coord == "t" else psi_b / vt
    du = np.ones_like(u) if coord == "t" else vt_b / vt
    k = np.arange(1, n + 1)
    ph = 2 * np.pi * f * np.outer(u, k)
    S, C = np.sin(ph), np.cos(ph)
    W = 2 * np.pi * f * k[None, :] * du[:, None]

    S, C, WC, WS = (jnp.asarray(q) for q in (S, C, W * C, W * S))

    def rates(p, v0, a0, c):
        m = S @ c[:n] + C @ c[n:]
        dm = WC @ c[:n] - WS @ c[n:]
        v = v0 * (1 + m)
        a = a0 * (1 + m) + v0 * dm
        return v, v / (1 - slip_law(p, lay, a))

    return residuals_with(res, rates)


def base_residuals(res):
    """The fit's own model as :func:`residuals_with` writes it (no term of its own): for
    refitting terms that are linear in their coefficients (``idx`` empty in :func:`refine`)."""
    lay = res.problem.lay

    def rates(p, v0, a0, c):
        return v0, v0 / (1 - slip_law(p, lay, a0))

    return residuals_with(res, rates)


def refine(proj, ctx, B, c, exact, idx) -> tuple:
    """Gauss-Newton on exact residuals from the linear solution: (flat, c, residuals).

    `exact(flat, c[idx])` gives the residuals of the fit's model with the exact term of
    coefficients c[idx] (a function of :func:`residuals_with`, which carries its exact
    Jacobian); the other columns of B add linearly. Every step recomputes the extended
    model's Jacobian where the parameters now are."""
    others = np.setdiff1d(np.arange(B.shape[1]), idx)
    B0 = B

    def resid(flat, cc):
        return exact(flat, cc[idx]) + B0[:, others] @ cc[others]

    flat0 = np.asarray(ctx.res.flat, float)
    step = proj.solve(ctx.r + B @ c)
    # the start: the linear solution, or a fraction of it where the exact model leaves the
    # linear one (a term near-degenerate with weakly held parameters, a speed spline's
    # knots at the window's edge, moves them far, and the stadium path bends under that)
    best = None
    for scale in START_SCALES:
        r = resid(flat0 - scale * step, scale * c)
        chi2 = float(r[proj.valid] @ r[proj.valid])
        if np.isfinite(chi2) and (best is None or chi2 < best[0]):
            best = (chi2, scale, r)
    chi2, scale, r = best
    flat, c = flat0 - scale * step, scale * c
    v = proj.valid
    lam = LM_LAMBDA0
    for _ in range(MAX_STEPS):
        # the extended model's own Jacobian where the parameters now are, exactly
        Jf, Jc = (np.asarray(q) for q in exact.jacobian(jnp.asarray(flat, float),
                                                       jnp.asarray(c[idx], float)))
        J = Jf[v]
        B = B.copy()
        B[:, idx] = Jc
        A = np.hstack([J, B[v]])
        d = np.sqrt(np.sum(A * A, 0))
        d = np.where(d > 0, d, 1.0)
        As = A / d
        N = As.T @ As
        grad = As.T @ r[v]
        n_p = J.shape[1]
        for _ in range(LM_TRIES):  # Levenberg-Marquardt: a step the model can follow
            step = -np.linalg.solve(N + lam * np.diag(np.diag(N) + 1e-12), grad) / d
            r2 = resid(flat + step[:n_p], c + step[n_p:])
            c2 = float(r2[v] @ r2[v])
            if np.isfinite(c2) and c2 < chi2:
                lam = max(lam / 10, 1e-9)
                break
            lam *= 10
        else:
            break
        gain = chi2 - c2
        flat, c, r, chi2 = flat + step[:n_p], c + step[n_p:], r2, c2
        if gain < 1e-3 * max(chi2, 1.0) ** 0.5:
            break
    return flat, c, r

