"""Residuals of a fit laid out sample by sample, with where and when each one was taken.

Every weighted residual of a fit (order [lug_x, lug_y, body_x, body_y], as in
:class:`fitlug.fit.FitResult`) gets its marker, role, axis, time, path segment, motion
phase and belt travel. The geometry comes from one parameter set (the base fit) and is
shared by the residuals of every candidate model, which use the same samples.

Structured misfit. Besides chi^2 the tables measure the misfit with lag-1 products of
consecutive residuals of one series (one marker, one axis): M = sum r_t r_{t+1}. White
noise gives E[M] = 0 with sd sqrt(pairs) whatever its scale, while a misfit m(t) that is
smooth at the frame rate adds about |m|^2. So M is the chi^2 the misfit carries, free of
the 2 % uncertainty of the noise estimate that makes chi^2 - dof unreliable as an excess.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import numpy as np

from .. import _exported, _jaxconfig  # noqa: F401
from ..fit._buckets import pad_model
from ..model._buckets import bucket

SEGMENTS = ("bottom", "rear_arc", "top", "front_arc", "body")
PHASES = ("rest", "accelerate", "cruise", "decelerate")
AXES = ("x", "y")
#: |v| below this fraction of its peak is rest; |a| above this fraction of its peak is a ramp
REST_FRACTION = 0.05
RAMP_FRACTION = 0.1


@dataclass(frozen=True)
class Geometry:
    """Per-sample bookkeeping of a problem's residual vector, (S,) arrays each.

    S = 2 S_l + 2 S_b. `order` sorts the samples by (series, time); `pair_a`, `pair_b`
    index consecutive valid samples of one series one frame apart (positions in the
    residual vector, not in `order`).
    """

    t: np.ndarray  # s
    marker: np.ndarray  # index into markers
    role: np.ndarray  # 0 lug, 1 body
    axis: np.ndarray  # 0 x, 1 y
    segment: np.ndarray  # index into SEGMENTS
    phase: np.ndarray  # index into PHASES
    psi: np.ndarray  # belt travel at t, mm
    v: np.ndarray  # body speed at t, mm/s
    valid: np.ndarray  # bool
    series: np.ndarray  # marker * 2 + axis
    weight: np.ndarray  # 1 / sigma, 1/mm (0 where invalid)
    pair_a: np.ndarray
    pair_b: np.ndarray
    markers: tuple  # names
    roles: tuple
    fps: float
    v_cruise: float  # mm/s, body speed at cruise (median within 20 % of its peak)
    vt_cruise: float  # mm/s, belt speed there
    pitch: float  # mm
    R: float  # mm
    t_lo: float
    t_hi: float

    @property
    def n(self) -> int:
        return int(self.valid.sum())

    @property
    def f_lug(self) -> float:
        """Lug-passing frequency at cruise, Hz."""
        return self.vt_cruise / self.pitch

    @property
    def f_wheel(self) -> float:
        """Wheel-revolution frequency at cruise, Hz."""
        return self.vt_cruise / (2 * np.pi * self.R)

    def series_ids(self) -> np.ndarray:
        return np.unique(self.series[self.valid])

    def series_name(self, s: int) -> str:
        return f"{self.markers[s // 2]}.{AXES[s % 2]}"


@jax.jit
def _kinematics_segments(p, lay, t):
    from ..model import kinematics, segments

    return kinematics(p, lay, t), segments(p, lay)


def geometry(res) -> Geometry:
    """The :class:`Geometry` of a fit result's residual vector (from its parameters)."""
    prob = res.problem
    lay = prob.lay
    p = {k: np.asarray(v) for k, v in res.params.items()}
    S_l, S_b = len(prob.lug_rows), len(prob.body_rows)
    lug_t, body_t = np.asarray(lay.lug_t), np.asarray(lay.body_t)
    t = np.concatenate([lug_t, lug_t, body_t, body_t])
    lug_m = np.asarray(prob.lug_ids)[np.asarray(lay.lug_i)]
    body_m = np.asarray(prob.body_ids)[np.asarray(lay.body_j)]
    marker = np.concatenate([lug_m, lug_m, body_m, body_m])
    role = np.r_[np.zeros(2 * S_l, int), np.ones(2 * S_b, int)]
    axis = np.r_[np.zeros(S_l, int), np.ones(S_l, int), np.zeros(S_b, int), np.ones(S_b, int)]
    tu = np.unique(t)
    # on bucketed shapes (fitlug.fit._buckets: a new length compiles nothing new), cut back
    pj = {k: jax.device_put(np.asarray(v, float)) for k, v in p.items()}  # no program
    pm = pad_model(pj, lay)
    tb = np.concatenate([tu, np.full(bucket(len(tu)) - len(tu), tu[-1])]) if pm else tu
    kin, seg_l = _exported.call("kinematics_segments", _kinematics_segments, (),
                                *(pm or (pj, lay))[:2], jax.device_put(tb))
    kin = {k: np.asarray(v)[:len(tu)] for k, v in kin.items()}
    seg_l = np.asarray(seg_l)[:S_l].astype(int)
    segment = np.r_[seg_l, seg_l, np.full(2 * S_b, 4)]
    w = prob.weights
    valid = w > 0

    v, psi_u = np.asarray(kin["v"]), np.asarray(kin["psi"])
    vt = np.asarray(kin["v_t"])
    ph_u = _phases(tu, v)
    idx = np.searchsorted(tu, t)
    phase, psi, v_s = ph_u[idx], psi_u[idx], v[idx]
    # the cruise's speeds: the median over the frames within 20 % of the peak (a chain's
    # body overshoots after its ramp: at the peak the engine's belt ran 187 mm/s for 148)
    near = np.abs(v) >= 0.8 * float(np.max(np.abs(v)))

    series = marker * 2 + axis
    order = np.lexsort((t, series))
    fps = float(prob.init_info.get("fps") or 1.0 / np.median(np.diff(tu)))
    so, to, vo = series[order], t[order], valid[order]
    same = (so[1:] == so[:-1]) & vo[1:] & vo[:-1] & (np.abs(np.diff(to) - 1.0 / fps) < 0.5 / fps)
    pa, pb = order[:-1][same], order[1:][same]
    from ..model import belt_length

    P = float(belt_length(p["R"], p["D"]))
    # small integer types: S of each on a long recording (100 000 frames: 2.8 M rows; int64
    # throughout held ~120 MB more); every use compares, indexes or counts them
    i8, i32 = np.int8, (np.int32 if len(t) < 2 ** 31 else np.int64)
    return Geometry(t=t, marker=marker.astype(i32), role=role.astype(i8), axis=axis.astype(i8),
                    segment=segment.astype(i8), phase=phase.astype(i8), psi=psi, v=v_s,
                    valid=valid, series=series.astype(i32), weight=w, pair_a=pa.astype(i32),
                    pair_b=pb.astype(i32),
                    markers=tuple(prob.rec.markers), roles=tuple(prob.rec.roles), fps=fps,
                    v_cruise=float(np.median(np.abs(v[near]))),
                    vt_cruise=float(np.median(np.abs(vt[near]))),
                    pitch=P / float(lay.n_belt), R=float(p["R"]), t_lo=float(tu[0]),
                    t_hi=float(tu[-1]))


def _running(x: np.ndarray, k: int, fn) -> np.ndarray:
    if k < 2 or len(x) < k:
        return x
    pad = np.pad(x, (k // 2, k - 1 - k // 2), mode="edge")
    win = np.lib.stride_tricks.sliding_window_view(pad, k)
    return fn(win, axis=1)


def _phases(t: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Motion phase per time: rest, accelerate, cruise, decelerate (indices into PHASES).

    Accelerate / decelerate are where the speed magnitude grows / falls faster than
    RAMP_FRACTION of the peak |a|. The speed is first median-filtered over 0.3 s: a base
    fit that absorbs a mismatch (a jump of every marker) into a short speed spike must
    not turn cruise into a ramp.
    """
    if len(t) < 3:
        return np.full(len(t), 2)
    dt = float(np.median(np.diff(t)))
    k = max(int(round(0.3 / dt)) | 1, 1)
    v = _running(np.asarray(v, float), k, np.median)
    a = _running(np.gradient(v, t), k, np.mean)
    vmax = float(np.max(np.abs(v))) if len(v) else 0.0
    amax = float(np.max(np.abs(a))) if len(a) else 0.0
    sgn = np.sign(v) if vmax > 0 else np.ones_like(v)
    a_along = a * sgn
    ph = np.full(len(v), 2)
    if amax > 0:
        ph[a_along > RAMP_FRACTION * amax] = 1
        ph[a_along < -RAMP_FRACTION * amax] = 3
    ph[np.abs(v) < REST_FRACTION * max(vmax, 1e-12)] = 0
    return ph


def lag_products(geo: Geometry, r: np.ndarray) -> np.ndarray:
    """Per-sample share of the structured misfit: r_t (r_{t-1} + r_{t+1}) / 2 within a series.

    Summed over any set of samples it estimates the misfit chi^2 there (see module doc).
    """
    out = np.zeros(len(r))
    prod = r[geo.pair_a] * r[geo.pair_b]
    np.add.at(out, geo.pair_a, 0.5 * prod)
    np.add.at(out, geo.pair_b, 0.5 * prod)
    return out


def structured_misfit(geo: Geometry, r: np.ndarray) -> tuple[float, float]:
    """(M, its standard deviation under white noise) for one residual vector."""
    prod = r[geo.pair_a] * r[geo.pair_b]
    return float(prod.sum()), float(np.sqrt(max(len(prod), 1)))
