"""The slip's memory: lugs whose tips hold on the ground remember where they touched down
(MODEL.md §2's load sharing, read without its steady-state shortcut).

MODEL.md's law s = 2F/(k n L) is the steady state of a brush of lugs that hold on the
ground: the lug that touched down at belt travel psi_e carries k (S(psi) - S(psi_e)), S the
belt's slip displacement psi - X (dS = s dpsi). Summed over a brush of n lugs spread over
the contact length Lambda, the traction is

    F = (k n / Lambda) * integral_{psi - Lambda}^{psi} (S(psi) - S(psi')) dpsi'

so S(psi) - mean of S over the last Lambda of belt travel = (Lambda / 2) s_qs, where
s_qs = 2F / (k n Lambda) is the law's quasi-static slip (s0 + beta a, or the replacing
slip law). At constant load S rises linearly and s = s_qs: today's model. When the load
changes, the slip follows one contact length late (the lugs that touched down under the
old load still carry it), and the body, a mass on the lugs' shear springs, can surge fore
and aft at sqrt(n k / m) / 2 pi with the belt running steadily: the free speed profile
X(t) then moves S, not psi.

The memory length is lambda * L (L the rig's load-bearing length): lambda = 1 is a brush
whose lugs hold over the whole contact, lambda -> 0 the instantaneous law (identity:
lambda below 0.05 is today's model exactly; the explanation does not search this effect,
a user fits it by name). The belt travel solves the relation on the integration's nodes
(:func:`belt_travel`), a Newton step per node, the history read by belt travel; before
the first node the belt is taken to have run at that node's slip. With a belt-locked
speed modulation (lug_ripple, wheel_runout) the model integrates X and psi together and
the memory is not applied.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ._base import Effect

#: lambda below which the instantaneous law is used: a memory shorter than 5 % of L (6 mm
#: on the reference rig) is the law within the integration's belt steps
LAMBDA_MIN = 0.05
_NEWTON = 3


class LugMemory(Effect):
    """The slip follows the load one contact length late (lugs remember their touch-down)."""

    id = "lug_memory"
    defaults = {"memory_lambda": 0.0}
    scales = {"memory_lambda": 0.2}
    meaning = ("The lugs hold on the ground from touch-down to lift-off, so the slip follows "
               "a change of the load one contact length late, and the body, a mass on the "
               "lugs' shear springs, surges fore and aft on them while the belt runs steadily.")
    searched = False  # fitted by name; see the module docstring
    signature = "x:lug+body:time"

    @classmethod
    def memory(cls, p):
        return p["memory_lambda"]

    @classmethod
    def report(cls, p):
        return {"lambda": float(p["memory_lambda"])}


def belt_travel(X, s_qs, lam_L, h):
    """Belt travel psi at the nodes (psi[0] = 0) for body positions X (mm, X[0] = 0) and
    quasi-static slips s_qs at the nodes, with memory length lam_L (mm, > 0) and node
    spacing h (s). Returns (psi, dpsi/dt) (the rate by second-order differences)."""
    G = X.shape[0]
    Lam = jnp.maximum(lam_L, 1e-9)
    s_start = s_qs[0]
    big = jnp.asarray(jnp.inf, X.dtype)

    def I_at(q, psi_h, I_h, S_h):
        """The running integral of S over belt travel at q (0 at the first node)."""
        i = jnp.clip(jnp.searchsorted(psi_h, q, side="right"), 1, G - 1)
        p0, p1 = psi_h[i - 1], psi_h[i]
        dp = jnp.where(jnp.isfinite(p1), p1 - p0, 0.0)
        w = jnp.clip(jnp.where(dp > 0, (q - p0) / jnp.where(dp > 0, dp, 1.0), 0.0), 0.0, 1.0)
        S0, S1 = S_h[i - 1], jnp.where(jnp.isfinite(p1), S_h[i], S_h[i - 1])
        S_q = S0 + w * (S1 - S0)
        inside = I_h[i - 1] + w * dp * (S0 + S_q) / 2.0
        d = psi_h[0] - q  # before the first node: S = S[0] + s_start (psi - psi[0])
        before = -(S_h[0] * d - s_start * d * d / 2.0)
        S_before = S_h[0] - s_start * d
        early = q < psi_h[0]
        return jnp.where(early, before, inside), jnp.where(early, S_before, S_q)

    psi_h = jnp.full(G, big).at[0].set(0.0)
    I_h = jnp.zeros(G)
    S_h = jnp.zeros(G).at[0].set(-X[0])

    def step(carry, g):
        psi_h, I_h, S_h, rate = carry
        psi_p, S_p, I_p = psi_h[g - 1], S_h[g - 1], I_h[g - 1]
        Xg, target = X[g], Lam / 2.0 * s_qs[g]
        psi = psi_p + h * rate

        for _ in range(_NEWTON):
            S = psi - Xg
            I = I_p + (psi - psi_p) * (S + S_p) / 2.0
            I_lag, S_lag = I_at(psi - Lam, psi_h, I_h, S_h)
            phi = S - (I - I_lag) / Lam - target
            dphi = 1.0 - ((S + S_p) / 2.0 + (psi - psi_p) / 2.0 - S_lag) / Lam
            psi = psi - phi / dphi
        S = psi - Xg
        I = I_p + (psi - psi_p) * (S + S_p) / 2.0
        new_rate = (psi - psi_p) / h
        return (psi_h.at[g].set(psi), I_h.at[g].set(I), S_h.at[g].set(S), new_rate), None

    v0 = (X[1] - X[0]) / h
    rate0 = v0 / (1.0 - s_start)
    (psi_h, _, _, _), _ = jax.lax.scan(step, (psi_h, I_h, S_h, rate0), jnp.arange(1, G))
    psi = psi_h
    mid = (psi[2:] - psi[:-2]) / (2.0 * h)
    first = (-3.0 * psi[0] + 4.0 * psi[1] - psi[2]) / (2.0 * h)
    last = (3.0 * psi[-1] - 4.0 * psi[-2] + psi[-3]) / (2.0 * h)
    return psi, jnp.concatenate([first[None], mid, last[None]])
