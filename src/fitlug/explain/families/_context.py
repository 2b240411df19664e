"""What every family needs of a fit, row by row of its residual vector.

The families are linear extensions of a converged fit (:mod:`._solve`): each adds columns
B (d weighted residual / d coefficient) next to the fit's own Jacobian J. This module
gathers, for the residual vector of a :class:`fitlug.fit.FitResult` (order [lug_x, lug_y,
body_x, body_y]), where and when each row was taken in the natural coordinates of
MODEL.md §5: time t (and the frame), acceleration a, belt travel psi, the lug's place on
the stadium u (and on the top run, xi), the observed image point q,
its ground position x, the body's X and the body marker's offset c_x, and the derivatives
of the weighted residual by X and psi (for speed modulations).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from ...fit._residuals import _weighted
from ...model import integrate, positions, sampled_kinematics
from ...model._model import ctx_of
from ...model._path import stadium


@dataclass
class Context:
    """Row-wise coordinates of one fit's residual vector (S,) and its Jacobian."""

    res: object  # the FitResult
    r: np.ndarray  # weighted residuals (S,)
    J: np.ndarray  # weighted Jacobian (S, k), packing order of res
    w: np.ndarray  # 1 / sigma per row (0 where invalid)
    valid: np.ndarray  # bool (S,)
    t: np.ndarray  # s
    role: np.ndarray  # 0 lug, 1 body
    axis: np.ndarray  # 0 x, 1 y
    segment: np.ndarray  # 0 bottom, 1 rear arc, 2 top, 3 front arc, 4 body
    marker: np.ndarray  # index into markers (the recording's)
    xi: np.ndarray  # place along the top run, 0 (rear wheel) .. 1 (front wheel); nan off it
    u: np.ndarray  # lug rows: belt coordinate on the stadium, sigma mod P (nan for the body)
    qx: np.ndarray  # the model's point (image position in the ground frame, mm): x
    qy: np.ndarray  # and y (both for the x and the y row of a sample)
    frame: np.ndarray  # index of the sample's time stamp among the recording's, in time order
    x_ground: np.ndarray  # ground x of the sample (lug: its model x; body: X + x_off)
    X: np.ndarray  # body reference position at t, mm
    cx: np.ndarray  # body marker's x offset (0 for lugs)
    a: np.ndarray  # body acceleration at t, mm/s^2
    dr_dX: np.ndarray  # d weighted residual / d X(t)
    dr_dpsi: np.ndarray  # d weighted residual / d psi(t)
    grid: np.ndarray  # integration nodes, s
    v_nodes: np.ndarray  # body speed at the nodes, mm/s
    vt_nodes: np.ndarray  # belt speed at the nodes, mm/s
    psi_nodes: np.ndarray
    t_ref: float
    D: float
    R: float
    pitch: float
    x_off: float
    n_body: int
    markers: tuple

    @property
    def n(self) -> int:
        return int(self.valid.sum())

    def cumulative(self, values: np.ndarray, speed: np.ndarray) -> np.ndarray:
        """int_{t_ref}^t speed * values dt' at every row's t (values, speed: on the nodes;
        values may be (G, m) for m columns at once): trapezoids on the node grid."""
        f = speed[:, None] * values.reshape(len(self.grid), -1)
        h = np.diff(self.grid)[:, None]
        cum = np.vstack([np.zeros((1, f.shape[1])), np.cumsum(0.5 * h * (f[1:] + f[:-1]), 0)])
        at_ref = np.array([np.interp(self.t_ref, self.grid, c) for c in cum.T])
        return np.stack([np.interp(self.t, self.grid, c) for c in cum.T], 1) - at_ref


@jax.jit
def _kinematics(p, lay, obs):
    """The model's kinematics at the samples, their residual derivatives by X and psi, the
    lug rows' stadium segment and the node integration, as one compiled program (op by op
    it was ~200 small programs for every new shape: ~5 s CPU on a fresh process)."""
    Xl, psil, Xb, psib = sampled_kinematics(p, lay)
    n_l, n_b = lay.lug_t.shape[0], lay.body_t.shape[0]

    def stage2(a, b, c, d):
        return _weighted(positions(p, lay, a, b, c, d), obs)

    prim = (Xl, psil, Xb, psib)
    ol, ob, zl, zb = jnp.ones(n_l), jnp.ones(n_b), jnp.zeros(n_l), jnp.zeros(n_b)
    _, dr_dX = jax.jvp(stage2, prim, (ol, zl, ob, zb))
    _, dr_dpsi = jax.jvp(stage2, prim, (zl, ol, zb, ob))
    ctx = ctx_of(p, lay)
    u = p["sigma0"][lay.lug_i] + psil
    px, _, seg_l = stadium(u, ctx)
    return {"Xl": Xl, "psil": psil, "Xb": Xb, "dr_dX": dr_dX, "dr_dpsi": dr_dpsi,
            "R": ctx.R, "D": ctx.D, "P": ctx.P, "u": u, "px": px, "seg_l": seg_l,
            "nodes": integrate(p, lay), "m": positions(p, lay, Xl, psil, Xb, psib)}


def context(res, J: np.ndarray) -> Context:
    """The :class:`Context` of FitResult `res` with its dense weighted Jacobian `J`."""
    prob = res.problem
    lay, obs = prob.lay, prob.obs
    p = {k: jnp.asarray(v, float) for k, v in res.params.items()}
    k = jax.device_get(_kinematics(p, lay, obs))
    n_l, n_b = lay.lug_t.shape[0], lay.body_t.shape[0]
    dr_dX, dr_dpsi = k["dr_dX"], k["dr_dpsi"]
    R, D, P = float(k["R"]), float(k["D"]), float(k["P"])
    u = np.asarray(k["u"])
    px = k["px"]
    um = np.mod(u, P)
    seg_l = np.asarray(k["seg_l"])
    xi_l = np.where(seg_l == 2, (um - D - np.pi * R) / D, np.nan)
    lug_xg = np.asarray(k["Xl"]) + float(p["x_off"]) + np.asarray(px)
    cx_b = np.asarray(p["cx"])[np.asarray(lay.body_j)]
    X_b = np.asarray(k["Xb"])
    X_l = np.asarray(k["Xl"])
    X_n, psi_n, v_n, vt_n = (np.asarray(q) for q in k["nodes"])
    grid = np.asarray(lay.grid)
    a_n = np.gradient(v_n, grid)
    tl, tb = np.asarray(lay.lug_t), np.asarray(lay.body_t)
    t = np.concatenate([tl, tl, tb, tb])
    w = np.concatenate([np.asarray(obs["lug_w"])] * 2 + [np.asarray(obs["body_w"])] * 2)
    # the model's points, not the observed ones: a warp evaluated at the data would hold
    # the residuals themselves (q_obs = q_model - r / w)
    mlx, mly, mbx, mby = (np.asarray(q) for q in k["m"])
    qx = np.concatenate([mlx, mlx, mbx, mbx])
    qy = np.concatenate([mly, mly, mby, mby])
    _, frame = np.unique(np.round(t * 1e7), return_inverse=True)
    lug_marker = np.asarray(prob.lug_ids)[np.asarray(lay.lug_i)]
    body_marker = np.asarray(prob.body_ids)[np.asarray(lay.body_j)]
    return Context(
        res=res, r=np.asarray(res.residuals, float), J=np.asarray(J, float), w=w,
        valid=w > 0, t=t,
        role=np.concatenate([np.zeros(2 * n_l, int), np.ones(2 * n_b, int)]),
        axis=np.concatenate([np.zeros(n_l, int), np.ones(n_l, int), np.zeros(n_b, int),
                             np.ones(n_b, int)]),
        segment=np.concatenate([seg_l, seg_l, np.full(2 * n_b, 4)]),
        marker=np.concatenate([lug_marker, lug_marker, body_marker, body_marker]),
        xi=np.concatenate([xi_l, xi_l, np.full(2 * n_b, np.nan)]),
        u=np.concatenate([um, um, np.full(2 * n_b, np.nan)]), qx=qx, qy=qy,
        frame=frame.ravel(),
        x_ground=np.concatenate([lug_xg, lug_xg, X_b + float(p["x_off"]),
                                 X_b + float(p["x_off"])]),
        X=np.concatenate([X_l, X_l, X_b, X_b]),
        cx=np.concatenate([np.zeros(2 * n_l), cx_b, cx_b]),
        a=np.interp(t, grid, a_n),
        dr_dX=np.asarray(dr_dX), dr_dpsi=np.asarray(dr_dpsi), grid=grid, v_nodes=v_n,
        vt_nodes=vt_n, psi_nodes=psi_n, t_ref=float(lay.t_ref), D=D, R=R,
        pitch=P / float(lay.n_belt), x_off=float(p["x_off"]), n_body=lay.n_body,
        markers=tuple(prob.rec.markers))

