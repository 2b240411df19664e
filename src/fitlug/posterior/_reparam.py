"""The exact marginal of a replacing slip law, sampled in the law's own coordinates.

Why. With a replacing slip law (lug_sliding: s = f(s_lin; mu), s_lin = s0 + beta a) the
data pin the slip the law gives, not (s0, beta, mu) one by one: the steady slip
S(s0; phi) = f(s0; phi) and the slope dS/da = beta f'(s0; phi) at a = 0 are fixed to
~1e-5 of themselves, and along the curve they leave free, s0, beta and mu move together
(correlations 0.99999 at the least-squares solution, the curve bending out of that
straight line within one sigma). emcee's moves are affine invariant: no linear change of
coordinates helps on such a ridge, and its DEMove crept along it (tau ~ 240 steps, ~12 000
steps to converge on bench_speed's effect recording). In u = (S, beta f', phi) the ridge is
straight and the marginal nearly Gaussian (its chi^2 within 0.3 of the quadratic at
random 1-sigma draws there), and emcee mixes as on the linear law's posteriors.

What is sampled is the same distribution: the density in u is the posterior of theta
times |d theta / d u| = 1 / |det d u / d theta| (for lug_sliding 1 / f'(s0)^2), and every
sample is mapped back to theta. The inverse takes s0 from S by Newton's method on the
law (f increasing in s_lin); a point where it does not converge is outside the sampled
region (-inf), like a point outside the prior.

Where the walkers start. The least-squares solution need not be the exact marginal's
mode along such a ridge: on bench_speed's effect recording the marginal's chi^2 is 42.8
lower 6 sigma away along it (mu 6.09 where the fit stopped at 7.69; the simulation's
truth is 6). So the mode of the density in (whitened) u is found first by Newton's method
on finite differences (2 d^2 + 1 points an iteration, in one batch; deterministic), and
the walkers start from the Laplace approximation there.

Where that approximation agrees with the exact density at 2-sigma points around the mode
to LINEARITY_TOL in delta-chi^2 (the test the Gaussian limit passes at the least-squares
solution, now in these coordinates; 0.22 on bench_speed's effect recording, 356 in theta
at the least-squares solution), method='auto' samples it instead of the exact density:
its Gaussian limit in the law's coordinates, with the prior's bounds.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .. import _jaxconfig  # noqa: F401
from ..model import slip_law
from ._priors import _log_prior

NEWTON_ITERATIONS = 60  # the inverse's fixed count (quadratic from s = S: ~6 needed)
MODE_ITERATIONS = 12
FD_STEP = 0.5  # the finite-difference step of the mode's Newton, in whitened units
#: rows per call of the compiled maps: one shape, so one trace and compile each (a new
#: batch size, 1 to 6 400 rows here, cost ~0.5 s of tracing and compiling every time)
ROWS = 128


def has_own_coordinates(res, names) -> bool:
    """A replacing slip law is sampled (a parameter beyond s0 and beta)."""
    return list(names[:2]) == ["s0", "beta"] and len(names) > 2


class SlipCoordinates:
    """theta = (s0, beta, phi...) <-> u = (S(s0; phi), beta S'(s0; phi), phi...), with
    S(s; phi) the slip law at zero acceleration for a linear-law slip s."""

    def __init__(self, res, names):
        lay = res.problem.lay
        base = {k: jnp.asarray(v) for k, v in res.params.items()}
        names = list(names)
        self.names = names

        def law(s, phi):
            p = dict(base)
            p.update({k: phi[i] for i, k in enumerate(names[2:])})
            p["s0"], p["beta"] = s, jnp.zeros_like(s)
            return slip_law(p, lay, jnp.zeros_like(s))

        slope = jax.grad(law, 0)

        def fwd(th):
            s0, beta, phi = th[0], th[1], th[2:]
            return jnp.concatenate([jnp.stack([law(s0, phi), beta * slope(s0, phi)]), phi])

        def inv(u):
            u1, u2, phi = u[0], u[1], u[2:]
            s = jax.lax.fori_loop(0, NEWTON_ITERATIONS,
                                  lambda _, s: s - (law(s, phi) - u1) / slope(s, phi), u1)
            ok = jnp.abs(law(s, phi) - u1) <= 1e-9 * jnp.abs(u1) + 1e-15
            th = jnp.concatenate([jnp.stack([s, u2 / slope(s, phi)]), phi])
            return jnp.where(ok, th, jnp.nan)

        def logdet(th):  # log |det d u / d theta|
            return jnp.linalg.slogdet(jax.jacfwd(fwd)(th))[1]

        self._fwd = jax.jit(fwd)
        self._jac = jax.jit(jax.jacfwd(fwd))
        self._inv = _in_rows(jax.jit(jax.vmap(inv)))
        self._logdet = _in_rows(jax.jit(jax.vmap(logdet)))
        self._prior = _in_rows(jax.jit(lambda th: _log_prior(th, names)))

    def whiten(self, theta_hat, cov):
        """z = L^-1 (u - u_hat), L L^T the Gaussian limit's covariance carried to u."""
        th = jnp.asarray(theta_hat, float)
        self.u_hat = np.asarray(self._fwd(th))
        J = np.asarray(self._jac(th))
        Cu = J @ cov @ J.T
        sd = np.sqrt(np.diag(Cu))  # correlation form: S ~ 0.1 and beta f' ~ 1e-4
        self.L = np.linalg.cholesky(Cu / np.outer(sd, sd)) * sd[:, None]

    def theta(self, z: np.ndarray) -> np.ndarray:
        """theta of (m, d) whitened points (nan where the law cannot be inverted)."""
        u = self.u_hat + np.atleast_2d(z) @ self.L.T
        return self._inv(u)

    def log_prob(self, log_prob_theta):
        """The log density of z, from theta's (vectorised, -inf outside the prior)."""

        def lp(z):
            th = self.theta(z)
            out = np.full(len(th), -np.inf)
            ok = np.all(np.isfinite(th), axis=1)
            if ok.any():
                out[ok] = (np.asarray(log_prob_theta(th[ok]))
                           - self._logdet(th[ok]))
            return np.where(np.isfinite(out), out, -np.inf)

        return lp

    def mode(self, lp) -> tuple:
        """(z at the density's mode, the Laplace covariance there, iterations): Newton's
        method on central differences, backtracking; falls back to (0, I), the
        least-squares solution's Gaussian, where the Hessian is not positive."""
        d = len(self.names)
        z = np.zeros(d)
        f, g, H = _derivatives(lp, z, FD_STEP)
        it = 0
        for it in range(1, MODE_ITERATIONS + 1):
            if not (np.isfinite(f) and np.all(np.isfinite(H))
                    and np.all(np.linalg.eigvalsh(H) > 0)):
                return np.zeros(d), np.eye(d), it
            step = -np.linalg.solve(H, g)
            for _ in range(20):  # backtracking: -2 log p must not rise
                f1 = -2.0 * float(lp((z + step)[None])[0])
                if np.isfinite(f1) and f1 <= f + 1e-9:
                    break
                step = 0.5 * step
            else:
                break
            z = z + step
            f, g, H = _derivatives(lp, z, FD_STEP)
            if np.max(np.abs(step)) < 1e-3:
                break
        w = np.linalg.eigvalsh(H) if np.all(np.isfinite(H)) else np.zeros(d)
        if not np.all(w > 0):
            return z, np.eye(d), it
        C = 2.0 * np.linalg.inv(H)  # H: of -2 log p
        return z, 0.5 * (C + C.T), it

    def linearity_check(self, z0, C, lp, tol: float) -> dict:
        """The exact density against its Laplace approximation at `CHECK_SIGMA` points
        (principal axes and diagonals of C) around the mode z0, as _Marginal's check
        at the least-squares solution: max |delta chi^2|."""
        from ._marginal import CHECK_SIGMA

        d = len(z0)
        w, V = np.linalg.eigh(C)
        root = V * np.sqrt(w)
        dirs = [sgn * e for e in np.eye(d) for sgn in (1, -1)]
        if d > 1:
            dirs += [(2 * np.array(c) - 1) / np.sqrt(d) for c in np.ndindex(*(2,) * d)]
        pts = z0 + CHECK_SIGMA * np.array([root @ u for u in dirs])
        c = -2.0 * np.asarray(lp(np.vstack([z0, pts])))
        exact = c[1:] - c[0]
        diff = exact - CHECK_SIGMA ** 2
        ok = bool(np.all(np.isfinite(diff)))
        return {"sigma": CHECK_SIGMA, "points": int(len(pts)),
                "max_delta_chi2": float(np.max(np.abs(diff))) if ok else None,
                "delta_chi2_exact_range": [float(exact.min()), float(exact.max())] if ok
                else None, "tolerance": tol}

    def gaussian_log_prob(self, z0, C):
        """The Laplace approximation's log density in z, -inf outside the prior (and
        where the law does not invert)."""
        P = np.linalg.inv(C)

        def lp(z):
            z = np.atleast_2d(z)
            th = self.theta(z)
            out = -0.5 * np.einsum("ij,jk,ik->i", z - z0, P, z - z0)
            ok = np.all(np.isfinite(th), axis=1)
            ok[ok] = np.isfinite(self._prior(th[ok]))
            return np.where(ok, out, -np.inf)

        return lp

    def start(self, z0, C, lp, walkers: int, rng) -> np.ndarray:
        """Walkers from N(z0, C) inside the prior (and where the law inverts), with a
        finite density."""
        root = np.linalg.cholesky(C)
        got = []
        for _ in range(8):
            z = z0 + rng.standard_normal((4 * walkers, len(z0))) @ root.T
            th = self.theta(z)
            ok = np.all(np.isfinite(th), axis=1)
            ok[ok] = np.isfinite(self._prior(th[ok]))
            got.append(z[ok])
            if sum(len(x) for x in got) >= walkers:
                break
        z = np.vstack(got)[:walkers]
        if len(z) < walkers:
            return None
        fine = np.isfinite(lp(z))
        return z if fine.all() else None

    def log_jacobian(self, theta: np.ndarray) -> np.ndarray:
        """log |det d u / d theta| per row: a sample's log density in theta is its log
        density in z plus this (up to a constant)."""
        return self._logdet(np.atleast_2d(theta))


def _in_rows(f):
    """f of (m, d) rows, called on blocks of ROWS rows (the last one padded): numpy out."""

    def g(x):
        x = np.atleast_2d(np.asarray(x, float))
        m = len(x)
        pad = np.concatenate([x, np.repeat(x[:1], (-m) % ROWS, 0)])
        return np.concatenate([np.asarray(f(jax.device_put(pad[i:i + ROWS])))
                               for i in range(0, len(pad), ROWS)])[:m]

    return g


def _derivatives(lp, z, h):
    """(-2 log p, its gradient, its Hessian) at z by central differences, one batch."""
    d = len(z)
    E = np.eye(d) * h
    pts = [z]
    for i in range(d):
        pts += [z + E[i], z - E[i]]
    for i in range(d):
        for j in range(i + 1, d):
            pts += [z + E[i] + E[j], z + E[i] - E[j], z - E[i] + E[j], z - E[i] - E[j]]
    c = -2.0 * np.asarray(lp(np.array(pts)))
    f0, g, H, k = c[0], np.zeros(d), np.zeros((d, d)), 1
    for i in range(d):
        g[i] = (c[k] - c[k + 1]) / (2 * h)
        H[i, i] = (c[k] - 2 * f0 + c[k + 1]) / h ** 2
        k += 2
    for i in range(d):
        for j in range(i + 1, d):
            H[i, j] = H[j, i] = (c[k] - c[k + 1] - c[k + 2] + c[k + 3]) / (4 * h * h)
            k += 4
    return f0, g, H
