"""The forward model of MODEL.md §2 with any set of catalog effects (§3), in JAX.

Parameters are a flat dict of float64 arrays (see :func:`param_names`); the static
structure (knots, markers, sample times, active effects) is a :class:`Layout`.

Belt travel psi(t) and body position X(t) are integrated on a fine grid of `substeps`
nodes per frame interval: Simpson's rule when the speed does not depend on psi (base
model, slip-law and image effects), classical RK4 when a speed modulation locked to the
belt is active (lug_ripple, wheel_runout make dpsi/dt depend on psi). Values at the
sample times come from cubic Hermite interpolation with the exact node derivatives, so
the integration error is far below a micrometre.
"""

from __future__ import annotations

import dataclasses
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import _jaxconfig  # noqa: F401  (x64, cache)
from . import _spline
from ._path import belt_length, stadium
from .effects import CATALOG, Ctx
from .effects._lug_memory import LAMBDA_MIN, belt_travel

BASE_SCALARS = ("s0", "beta", "R", "D", "e", "x_off", "y_off")
_FIXED_POINT_ITERATIONS = 4


class Layout(eqx.Module):
    """Static structure of one recording: time grid, spline basis, who is sampled when."""

    grid: jax.Array  # (G,) node times, s
    # the speed basis in banded form (a cubic B-spline has 4 nonzero functions at any t):
    # basis at node g = Bn[g, q] for coefficient jn[g] + q; memory linear in G whatever K
    Bn: jax.Array  # (G, 4) speed basis at nodes
    dBn: jax.Array
    Bm: jax.Array  # (G-1, 4) at interval midpoints
    dBm: jax.Array
    jn: jax.Array  # (G,) first coefficient of each node's band
    jm: jax.Array  # (G-1,)
    lug_t: jax.Array  # (S_l,) sample times of lug markers
    lug_i: jax.Array  # (S_l,) lug marker index
    body_t: jax.Array
    body_j: jax.Array
    # the rig's numbers are 0-d float64 arrays, not static fields (issue 43 item 2): a
    # static field is part of every compiled program's key, so each rig (its lugs on the
    # belt and in contact, its load-bearing length, its frame rate) compiled the fit's,
    # the explanation's and the posterior's programs afresh. Host code reads them with
    # float() / int().
    h: jax.Array  # () node spacing of the integration grid, s
    n_coef: int = eqx.field(static=True)  # K, speed-spline coefficients
    n_lug: int = eqx.field(static=True)
    n_body: int = eqx.field(static=True)
    n_belt: jax.Array  # () N, lugs on the belt
    n_contact: jax.Array  # () n
    L: jax.Array  # () load-bearing length, mm
    # knots of the speed spline and the gauge time are arrays, not static fields: a static
    # field is part of the compiled function's key, and every recording has its own knots
    breaks: jax.Array  # (K - 2,) spline breakpoints, s (metadata: the bases hold them)
    t_ref: jax.Array  # () X(t_ref) = psi(t_ref) = 0
    effects: tuple = eqx.field(static=True)

    def dense_bases(self):
        """(Bn, dBn, Bm, dBm) as dense (G, K) matrices (numpy; small layouts only)."""
        out = []
        for vals, first in ((self.Bn, self.jn), (self.dBn, self.jn), (self.Bm, self.jm),
                            (self.dBm, self.jm)):
            vals, first = np.asarray(vals), np.asarray(first)
            M = np.zeros((vals.shape[0], self.n_coef))
            rows = np.arange(vals.shape[0])
            for q in range(vals.shape[1]):
                M[rows, first + q] += vals[:, q]
            out.append(M)
        return tuple(out)

    def with_effects(self, effects) -> "Layout":
        order = tuple(e for e in CATALOG if e in set(effects))
        # a static field is no pytree leaf, so eqx.tree_at cannot replace it
        return dataclasses.replace(self, effects=order)

    def with_breaks(self, breaks) -> "Layout":
        """The same recording with the speed spline on other breakpoints (same grid)."""
        return dataclasses.replace(self, **_speed_bases(np.asarray(self.grid), float(self.h),
                                                          breaks))

    def with_times(self, lug_t, lug_i, body_t, body_j) -> "Layout":
        """The same model evaluated at other sample times (inside the grid)."""
        a = [jax.device_put(v) if isinstance(v, np.ndarray) else jnp.asarray(v)  # (no compile)
             for v in (lug_t, lug_i, body_t, body_j)]
        return eqx.tree_at(lambda l: (l.lug_t, l.lug_i, l.body_t, l.body_j), self, tuple(a))


def _speed_bases(grid: np.ndarray, h: float, breaks) -> dict:
    """The banded speed basis (and its derivative) at the nodes and interval midpoints."""
    mid = grid[:-1] + h / 2
    br = np.asarray(breaks, dtype=float)
    Bn, jn = _spline.banded(grid, br, 0)
    dBn, _ = _spline.banded(grid, br, 1)
    Bm, jm = _spline.banded(mid, br, 0)
    dBm, _ = _spline.banded(mid, br, 1)
    f = jax.device_put  # (jnp.asarray compiles a small program per new shape)
    return {"Bn": f(Bn), "dBn": f(dBn), "Bm": f(Bm), "dBm": f(dBm), "jn": f(jn), "jm": f(jm),
            "breaks": f(br), "n_coef": _spline.n_coefficients(br)}


def make_layout(*, breaks, t_lo, t_hi, fps, lug_t, lug_i, body_t, body_j, n_lug, n_body,
                n_belt, n_contact=8, L=127.0, effects=(), substeps=2, t_ref=0.0) -> Layout:
    """Build a :class:`Layout`. The grid spans [t_lo, t_hi] (must contain t_ref and every
    sample); X and psi are 0 at t_ref (MODEL.md's t = 0; the first sample's time when a
    recording starts later)."""
    h = 1.0 / (float(fps) * substeps)
    G = int(np.ceil((t_hi - t_lo) / h)) + 1
    grid = t_lo + h * np.arange(G)
    f = lambda a, dt: jax.device_put(np.asarray(a, dt))  # noqa: E731  (as in _speed_bases)
    lay = Layout(grid=f(grid, float), **_speed_bases(grid, h, breaks),
                 t_ref=jnp.asarray(float(t_ref)),
                 lug_t=f(lug_t, float), lug_i=f(lug_i, int),
                 body_t=f(body_t, float), body_j=f(body_j, int), h=f(h, float),
                 n_lug=int(n_lug), n_body=int(n_body), n_belt=f(int(n_belt), float),
                 n_contact=f(int(n_contact), float), L=f(float(L), float), effects=())
    return lay.with_effects(effects)


def param_names(lay: Layout) -> list[str]:
    names = ["v", *BASE_SCALARS, "sigma0", "cx", "cy"]
    for eid in lay.effects:
        names += list(CATALOG[eid].defaults)
    return names


def default_params(lay: Layout) -> dict:
    """Identity values of the layout's effect parameters (base values must be set by caller)."""
    p = {}
    for eid in lay.effects:
        p.update({k: jnp.asarray(v, float) for k, v in CATALOG[eid].defaults.items()})
    return p


def ctx_of(p, lay: Layout) -> Ctx:
    P = belt_length(p["R"], p["D"])
    links = _hook(lay, "link")
    return Ctx(R=p["R"], D=p["D"], e=p["e"], P=P, pitch=P / lay.n_belt,
               link=sum(f(p) for f in links) if links else None)


def _hook(lay, name):
    return [getattr(CATALOG[e], name) for e in lay.effects if getattr(CATALOG[e], name) is not None]


def slip_law(p, lay: Layout, a):
    """Slip s for body acceleration a (mm/s^2): s0 + beta a, or the replacing law."""
    s = p["s0"] + p["beta"] * a
    for f in _hook(lay, "slip"):
        s = f(p, s)
    return s


def steady_slip(p, lay: Layout):
    """s0 under the model's law: the slip at constant speed (MODEL.md §2)."""
    return slip_law(p, lay, jnp.asarray(0.0))


def _rates(p, lay, ctx, v0, a0, psi):
    """(v, dpsi/dt) at given base speed/acceleration and belt travel."""
    mods = _hook(lay, "speed")
    if not mods:
        return v0, v0 / (1.0 - slip_law(p, lay, a0))
    m = jnp.zeros_like(psi)
    dm = jnp.zeros_like(psi)
    for f in mods:
        mi, dmi = f(p, psi, ctx)
        m, dm = m + mi, dm + dmi
    v = v0 * (1.0 + m)
    dpsi = v / (1.0 - slip_law(p, lay, a0 * (1.0 + m)))
    for _ in range(_FIXED_POINT_ITERATIONS):  # a depends on dpsi/dt through m(psi)
        a = a0 * (1.0 + m) + v0 * dm * dpsi
        dpsi = v / (1.0 - slip_law(p, lay, a))
    return v, dpsi


def band_dot(vals, first, c):
    """Rows of a banded basis times coefficients c: sum_q vals[:, q] c[first + q]."""
    idx = first[:, None] + jnp.arange(vals.shape[1])[None, :]
    return jnp.sum(vals * c[idx], axis=1)


def speed_basis_values(lay: Layout, c):
    """Base speed and acceleration at the nodes and at the midpoints: (v0n, a0n, v0m, a0m)."""
    return (band_dot(lay.Bn, lay.jn, c), band_dot(lay.dBn, lay.jn, c),
            band_dot(lay.Bm, lay.jm, c), band_dot(lay.dBm, lay.jm, c))


def integrate(p, lay: Layout):
    """Node values (X, psi, dX/dt, dpsi/dt), each (G,), with X = psi = 0 at lay.t_ref."""
    ctx = ctx_of(p, lay)
    c = p["v"]
    v0n, a0n, v0m, a0m = speed_basis_values(lay, c)
    h = lay.h
    if not _hook(lay, "speed"):
        vn, dpn = _rates(p, lay, ctx, v0n, a0n, None)
        vm, dpm = _rates(p, lay, ctx, v0m, a0m, None)
        cum = lambda fn, fm: jnp.concatenate(  # noqa: E731  Simpson, cumulative
            [jnp.zeros(1), jnp.cumsum(h / 6.0 * (fn[:-1] + 4.0 * fm + fn[1:]))])
        X, psi = cum(vn, vm), cum(dpn, dpm)
        mem = _hook(lay, "memory")
        if mem:  # the slip's memory (lug_memory): psi from the brush's relation
            lam = sum(f(p) for f in mem)
            on = lam > LAMBDA_MIN
            psi_m, dp_m = belt_travel(X, slip_law(p, lay, a0n),
                                      jnp.where(on, lam, 1.0) * lay.L, h)
            psi, dpn = jnp.where(on, psi_m, psi), jnp.where(on, dp_m, dpn)
    else:
        def step(state, k):
            X0, s0 = state
            f = lambda vv, aa, ss: _rates(p, lay, ctx, vv, aa, ss)  # noqa: E731
            k1 = f(v0n[k], a0n[k], s0)
            k2 = f(v0m[k], a0m[k], s0 + h / 2 * k1[1])
            k3 = f(v0m[k], a0m[k], s0 + h / 2 * k2[1])
            k4 = f(v0n[k + 1], a0n[k + 1], s0 + h * k3[1])
            X1 = X0 + h / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
            s1 = s0 + h / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
            return (X1, s1), (X1, s1)

        _, (Xs, Ps) = jax.lax.scan(step, (jnp.zeros(()), jnp.zeros(())),
                                   jnp.arange(lay.grid.shape[0] - 1))
        X = jnp.concatenate([jnp.zeros(1), Xs])
        psi = jnp.concatenate([jnp.zeros(1), Ps])
        vn, dpn = _rates(p, lay, ctx, v0n, a0n, psi)
    t0 = jnp.asarray(lay.t_ref, float)
    X0 = hermite(lay, t0, X, vn)
    psi0 = hermite(lay, t0, psi, dpn)
    return X - X0, psi - psi0, vn, dpn


def hermite(lay: Layout, t, y, dy):
    """Cubic Hermite interpolation of node values y (derivatives dy) at times t."""
    G = lay.grid.shape[0]
    u = (t - lay.grid[0]) / lay.h
    i = jnp.clip(jnp.floor(u).astype(int), 0, G - 2)
    tau = u - i
    t2, t3 = tau * tau, tau * tau * tau
    return ((2 * t3 - 3 * t2 + 1) * y[i] + (t3 - 2 * t2 + tau) * lay.h * dy[i]
            + (-2 * t3 + 3 * t2) * y[i + 1] + (t3 - t2) * lay.h * dy[i + 1])


def _true_times(p, lay, t):
    for f in _hook(lay, "time_map"):
        t = f(p, t)
    return t


#: parameters that reach the positions only through X and psi at the sample times
KINEMATIC = ("v", "s0", "beta")


def sampled_kinematics(p: dict, lay: Layout):
    """X and psi at the (true) times of the lug and of the body samples: (Xl, psil, Xb, psib).

    The first stage of :func:`predict`. Every sample's position depends on the motion only
    through its own X and psi, which the fit's structured Jacobian uses."""
    return sampled_from_nodes(p, lay, integrate(p, lay))


def sampled_from_nodes(p: dict, lay: Layout, nodes):
    """:func:`sampled_kinematics` from the node values `nodes` = :func:`integrate`'s
    (X, psi, dX/dt, dpsi/dt): the samples' part, local in time (the long recordings'
    explanation integrates once and evaluates the samples by time blocks)."""
    X, psi, vn, dpn = nodes
    tl, tb = _true_times(p, lay, lay.lug_t), _true_times(p, lay, lay.body_t)
    Xl, psil = hermite(lay, tl, X, vn), hermite(lay, tl, psi, dpn)
    lags = _hook(lay, "lug_lag")
    if lags:  # a marker below the pitch line trails its pitch-line point (lug_shear)
        ctx = ctx_of(p, lay)
        sig = p["sigma0"][lay.lug_i] + psil
        psil = psil - sum(f(p, sig, psil, Xl, tl, nodes, lay.grid, ctx) for f in lags)
    return Xl, psil, hermite(lay, tb, X, vn), hermite(lay, tb, psi, dpn)


def predict(p: dict, lay: Layout):
    """Model positions at the layout's samples: (lug_x, lug_y, body_x, body_y), mm."""
    return predict_from_nodes(p, lay, integrate(p, lay))


def predict_from_nodes(p: dict, lay: Layout, nodes):
    """:func:`predict` from :func:`integrate`'s node values `nodes` (a long recording's
    passes integrate once over the whole grid and evaluate the samples by time blocks)."""
    return positions(p, lay, *sampled_from_nodes(p, lay, nodes))


def positions(p: dict, lay: Layout, Xl, psil, Xb, psib):
    """The second stage of :func:`predict`: positions from the sampled X and psi (and every
    parameter except the kinematic ones, :data:`KINEMATIC`, which it does not read)."""
    ctx = ctx_of(p, lay)
    top, bottom = _hook(lay, "top_dy"), _hook(lay, "bottom_dy")
    top_dy = (lambda xi: sum(f(p, xi, ctx) for f in top)) if top else None
    bottom_dy = (lambda u: sum(f(p, u, ctx) for f in bottom)) if bottom else None
    px, py, _ = stadium(p["sigma0"][lay.lug_i] + psil, ctx, top_dy, bottom_dy)
    lx = Xl + p["x_off"] + px
    ly = p["y_off"] + py

    cx = p["cx"][lay.body_j]
    bx = Xb + cx
    by = p["cy"][lay.body_j]
    for f in _hook(lay, "body_dy"):
        by = by + f(p, psib, cx, ctx)

    image = sorted((CATALOG[e] for e in lay.effects if CATALOG[e].image is not None),
                   key=lambda c: c.order)
    for eff in image:
        lx, ly = eff.image(p, lx, ly, True)
        bx, by = eff.image(p, bx, by, False)
    return lx, ly, bx, by


def kinematics(p: dict, lay: Layout, t, nodes=None):
    """Body position X, speed v, belt travel psi, belt speed v_t and slip s at times t
    (`nodes`: :func:`integrate`'s values when the caller has them already)."""
    X, psi, vn, dpn = integrate(p, lay) if nodes is None else nodes
    t = jnp.asarray(t, float)
    v = hermite(lay, t, vn, jnp.gradient(vn, lay.h))
    dp = hermite(lay, t, dpn, jnp.gradient(dpn, lay.h))
    return {"X": hermite(lay, t, X, vn), "v": v, "psi": hermite(lay, t, psi, dpn), "v_t": dp,
            "s": 1.0 - v / jnp.where(dp == 0, 1.0, dp)}


def segments(p: dict, lay: Layout):
    """Path segment (0 bottom, 1 rear arc, 2 top, 3 front arc) of every lug sample."""
    ctx = ctx_of(p, lay)
    X, psi, vn, dpn = integrate(p, lay)
    psil = hermite(lay, _true_times(p, lay, lay.lug_t), psi, dpn)
    return stadium(p["sigma0"][lay.lug_i] + psil, ctx)[2]


def integrated_basis_rows(lay: Layout, t, chunk: int = 4096):
    """Rows of d X(t) / d c with X(grid[0]) = 0 for the samples t, by time chunks (numpy).

    The same Simpson cumulation and Hermite interpolation as :func:`integrate` (base
    model), without the dense (G, K) matrices: yields (sample indices, dense rows
    (len, K)) per chunk of node intervals, memory chunk x K."""
    grid = np.asarray(lay.grid)
    h, G, K = float(lay.h), grid.shape[0], lay.n_coef
    Bn, jn = np.asarray(lay.Bn), np.asarray(lay.jn)
    Bm, jm = np.asarray(lay.Bm), np.asarray(lay.jm)
    t = np.asarray(t, float)
    u = (t - grid[0]) / h
    i = np.clip(np.floor(u).astype(np.int64), 0, G - 2)
    tau = (u - i)[:, None]
    w = ((2 * tau ** 3 - 3 * tau ** 2 + 1), (tau ** 3 - 2 * tau ** 2 + tau) * h,
         (-2 * tau ** 3 + 3 * tau ** 2), (tau ** 3 - tau ** 2) * h)
    carry = np.zeros(K)
    for c0 in range(0, G - 1, chunk):
        c1 = min(c0 + chunk, G - 1)
        n = c1 - c0
        inc = np.zeros((n, K))
        vn = np.zeros((n + 1, K))
        r = np.arange(n)
        for q in range(Bn.shape[1]):
            np.add.at(inc, (r, jn[c0:c1] + q), h / 6 * Bn[c0:c1, q])
            np.add.at(inc, (r, jm[c0:c1] + q), 4 * h / 6 * Bm[c0:c1, q])
            np.add.at(inc, (r, jn[c0 + 1:c1 + 1] + q), h / 6 * Bn[c0 + 1:c1 + 1, q])
            np.add.at(vn, (np.arange(n + 1), jn[c0:c1 + 1] + q), Bn[c0:c1 + 1, q])
        Inode = carry + np.vstack([np.zeros((1, K)), np.cumsum(inc, 0)])
        sel = np.flatnonzero((i >= c0) & (i < c1))
        if len(sel):
            li = i[sel] - c0
            rows = (w[0][sel] * Inode[li] + w[1][sel] * vn[li] + w[2][sel] * Inode[li + 1]
                    + w[3][sel] * vn[li + 1])
            yield sel, rows
        carry = Inode[-1]


def second_differences(K: int) -> np.ndarray:
    """(K - 2, K): the second differences of K spline coefficients (a curvature penalty)."""
    D2 = np.zeros((max(K - 2, 0), K))
    i = np.arange(K - 2)
    D2[i, i], D2[i, i + 1], D2[i, i + 2] = 1.0, -2.0, 1.0
    return D2


def fit_body_speed(lay: Layout, t, j, x, w, smooth: float | None = None):
    """Speed-spline coefficients and body offsets cx minimising
    sum w^2 (x - X(t) - cx_j)^2 (X(t_ref) = 0, base model with zero slip), plus
    sum (second difference of the coefficients / smooth)^2 when `smooth` (mm/s) is given:
    normal equations accumulated by time chunks, memory independent of the recording's
    length."""
    K, nb = lay.n_coef, lay.n_body
    t, j, x, w = (np.asarray(a) for a in (t, j, x, w))
    ref = np.zeros(K)
    for _, rows in integrated_basis_rows(lay, np.asarray([float(lay.t_ref)])):
        ref = rows[0]
    A = np.zeros((K + nb, K + nb))
    b = np.zeros(K + nb)
    for sel, rows in integrated_basis_rows(lay, t):
        M = np.zeros((len(sel), K + nb))
        M[:, :K] = rows - ref
        M[np.arange(len(sel)), K + j[sel]] = 1.0
        M *= w[sel, None]
        A += M.T @ M
        b += M.T @ (x[sel] * w[sel])
    if smooth is not None and K > 2:
        D2 = second_differences(K)
        A[:K, :K] += D2.T @ D2 / smooth ** 2
    d = np.sqrt(np.maximum(np.diag(A), 0.0))
    s = np.where(d > 0, 1.0 / np.where(d > 0, d, 1.0), 1.0)
    sol = np.linalg.lstsq(A * np.outer(s, s), b * s, rcond=None)[0] * s
    return sol[:K], sol[K:]
