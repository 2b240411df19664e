"""Where the lug marker sits on the lug (MODEL.md §2, "Where the marker sits on the lug").

A lug that touches down at the front of the bottom run holds its tip on the ground while
the belt moves on under it, so the lug shears: after belt travel u on the run its shear is
d = integral of s dpsi over that travel. A marker at height fraction h of the lug (0 tip,
1 pitch line) trails its pitch-line point along the belt by (1 - h) d. After lift-off at
the run's rear end the shear relaxes, d -> d_L exp(-dt / tau).

Exactly, with no approximation in the slip's history: the model's X and psi start at 0
together and dpsi - dX = s dpsi, so S = psi - X is the running integral of s dpsi, and the
shear of a lug that entered the run at belt travel psi_e is S(now) - S(psi_e). S and the
time are read as functions of psi from the integration's nodes (psi is monotonic while the
belt runs forward; linear interpolation between nodes 0.5 mm of belt apart at 100 fps,
an error of 1e-5 mm at the reference rig's slip changes). Before the grid's first node S and
t are continued at the first node's slip and belt speed (a lug already on the ground when
the recording starts); where the robot stands still there, at the steady slip s0 (the
lug touched down under the law's slip at rest, and has not relaxed since).
"""

from __future__ import annotations

import jax.numpy as jnp

from ._base import Ctx, Effect

#: belt speed (mm/s) below which a robot is taken to stand still (times since lift-off)
_V_REST = 1e-3


def _at_psi(q, psi_n, fs):
    """Functions of belt travel at q: each (f_n, slope0) of `fs` is f_n at the nodes psi_n
    (non-decreasing), linear between them, continued with slope0 (df/dpsi) before the
    first node. One search serves them all."""
    G = psi_n.shape[0]
    i = jnp.clip(jnp.searchsorted(psi_n, q, side="right"), 1, G - 1)
    p0, p1 = psi_n[i - 1], psi_n[i]
    dp = p1 - p0
    w = jnp.where(dp > 0, (q - p0) / jnp.where(dp > 0, dp, 1.0), 0.0)
    w = jnp.clip(w, 0.0, 1.0)
    return [jnp.where(q < psi_n[0], f_n[0] + slope0 * (q - psi_n[0]),
                      f_n[i - 1] + w * (f_n[i] - f_n[i - 1])) for f_n, slope0 in fs]


class LugShear(Effect):
    """Markers on the lug below the pitch line: the lug's shear under traction and its
    spring-back after lift-off (MODEL.md §2's h and tau)."""

    id = "lug_shear"
    defaults = {"shear_h": 1.0, "shear_tau": 0.05}
    scales = {"shear_h": 0.2, "shear_tau": 0.02}
    meaning = ("The lug markers sit on the lugs below the belt's pitch line (near the tips): "
               "a lug's tip holds on the ground while the lug shears under the traction, so "
               "the marker stands nearly still in contact and springs back as the lug lifts "
               "off at the rear of the contact patch.")
    signature = "x:lug:bottom+rear"

    @classmethod
    def lug_lag(cls, p, sigma, psi, X, t, nodes, grid, ctx: Ctx):
        """Lag (mm, along the belt against its motion) of lug samples at belt coordinate
        sigma = sigma0 + psi, body position X and time t, from the integration's nodes
        (X_n, psi_n, v_n, dpsi_n) on `grid`."""
        Xn, psin, vn, dpn = nodes
        P, D = ctx.P, ctx.D
        u = jnp.mod(sigma, P)
        psi_e = psi - u  # belt travel when this lug touched down at the run's front
        psi_l = psi_e + D  # ... and when it lifted off at the rear
        Sn = psin - Xn
        v0 = jnp.maximum(dpn[0], _V_REST)
        # the slip at the first node, or the steady slip where the robot stands still
        s_start = jnp.where(dpn[0] > _V_REST, 1.0 - vn[0] / v0, p["s0"])
        (S_e,) = _at_psi(psi_e, psin, [(Sn, s_start)])
        S_now = psi - X
        on_run = u < D
        S_l, t_l = _at_psi(jnp.minimum(psi_l, psi), psin, [(Sn, s_start), (grid, 1.0 / v0)])
        tau = jnp.abs(p["shear_tau"])
        dt = jnp.maximum(t - t_l, 0.0)
        decay = jnp.exp(-dt / jnp.maximum(tau, 1e-6))
        d = jnp.where(on_run, S_now - S_e, (S_l - S_e) * decay)
        return (1.0 - p["shear_h"]) * d

    @classmethod
    def report(cls, p):
        return {"h": float(p["shear_h"]), "tau_s": abs(float(p["shear_tau"]))}
