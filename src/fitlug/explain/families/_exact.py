"""A speed modulation evaluated exactly (not linearised): the base model's kinematics with
v -> v (1 + m) everywhere, m a Fourier series in t or psi (MODEL.md §5, §3's conventions:
X, a, so F and s, and psi all follow the modulated speed), positions from the model's own
stadium path. At tens of hertz the slip's answer to the modulated acceleration,
v_t = v / (1 - s(a)), is not small, and its mean over a cycle moves the slip: the linear
term finds the modulation, this refits it (:func:`refine`).

The modulation's phase is read at the base fit's belt travel psi(t) (the modulation
itself moves psi by ~ eps x period / 2 pi, micrometres: a phase error of 1e-3 rad).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ...fit._residuals import _weighted
from ...model import hermite, positions, slip_law
from ...model._model import speed_basis_values
from ._solve import _pinv

MAX_STEPS = 5


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

    def fn(flat, c):
        p = packing.unpack(jnp.asarray(flat), fixed)
        v0n, a0n, v0m, a0m = (np.asarray(q) for q in speed_basis_values(lay, p["v"]))
        v, dpsi = rates(p, np.r_[v0n, v0m], np.r_[a0n, a0m], np.asarray(c))
        out = []
        for y in (v, dpsi):  # Simpson on the node grid, then X = psi = 0 at t_ref
            yn, ym = y[:G], y[G:]
            cum = np.r_[0.0, np.cumsum(h / 6 * (yn[:-1] + 4 * ym + yn[1:]))]
            out.append((jnp.asarray(cum), jnp.asarray(yn)))
        (X, vX), (P, vP) = out
        t0 = jnp.asarray(lay.t_ref, float)
        Xl = hermite(lay, lay.lug_t, X, vX) - hermite(lay, t0, X, vX)
        Pl = hermite(lay, lay.lug_t, P, vP) - hermite(lay, t0, P, vP)
        Xb = hermite(lay, lay.body_t, X, vX) - hermite(lay, t0, X, vX)
        Pb = hermite(lay, lay.body_t, P, vP) - hermite(lay, t0, P, vP)
        return np.asarray(_weighted(positions(p, lay, Xl, Pl, Xb, Pb), obs))

    return fn


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

    def rates(p, v0, a0, c):
        m = S @ c[:n] + C @ c[n:]
        dm = (W * C) @ c[:n] - (W * S) @ c[n:]
        v = v0 * (1 + m)
        a = a0 * (1 + m) + v0 * dm
        s = np.asarray(slip_law(p, lay, jnp.asarray(a)))
        return v, v / (1 - s)

    return residuals_with(res, rates)


def refine(proj, ctx, B, c, exact, idx) -> tuple:
    """Gauss-Newton on exact residuals from the linear solution: (flat, c, residuals).

    `exact(flat, c[idx])` gives the residuals of the fit's model with the exact term of
    coefficients c[idx]; the other columns of B add linearly. The Jacobian is the fit's
    J and the linear columns B (approximate: convergence is linear, the minimum exact)."""
    others = np.setdiff1d(np.arange(B.shape[1]), idx)

    def resid(flat, cc):
        return exact(flat, cc[idx]) + B[:, others] @ cc[others]

    flat = np.asarray(ctx.res.flat, float) - proj.solve(ctx.r + B @ c)
    r = resid(flat, c)
    chi2 = float(r[proj.valid] @ r[proj.valid])
    for _ in range(MAX_STEPS):
        pr = proj.with_residuals(r)
        G, g, _ = pr._normal(B)
        dc = -_pinv(G) @ g
        dth = -pr.solve(r + B @ dc)
        for scale in (1.0, 0.5, 0.25):
            r2 = resid(flat + scale * dth, c + scale * dc)
            c2 = float(r2[proj.valid] @ r2[proj.valid])
            if np.isfinite(c2) and c2 < chi2:
                break
        else:
            break
        gain = chi2 - c2
        flat, c, r, chi2 = flat + scale * dth, c + scale * dc, r2, c2
        if gain < 1e-3 * max(chi2, 1.0) ** 0.5:
            break
    return flat, c, r
