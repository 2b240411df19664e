"""Starting values of every catalog effect from the residuals it should explain.

Each effect's signature is its derivative columns at the current fit: the residual
change its parameters cause there. Regressing the residuals on those columns, after
removing what the current model's own parameters can already do (projection orthogonal
to their Jacobian), is one Gauss-Newton step from the current fit: its chi^2 drop is the
score statistic of the effect, and its coefficients are the starting values. Parameters
whose derivative vanishes at identity are scanned on a small grid instead:

- lug_ripple, wheel_runout: a, b (eps sin, eps cos) are linear at identity;
- body_bounce: columns for A at phi = 0 and pi/2 (the sin and cos of 2 pi psi / p), and
  the same for B with two or more body markers; A = hypot, phi = atan2;
- ground_sinkage: z for u_s on a grid (3 to 120 mm);
- lug_shear: h for tau on a grid (5 to 150 ms);
- lens_distortion: k1 for centres on a 5 x 3 grid over the field of view;
- frame_drop: dt for t* at every frame (the residual jump), by cumulative sums.

The Gauss-Newton step of lug_sliding is taken at the linear law (mu = 0), where its
column is the curvature s_lin^2 / 2: near the friction limit (F0/F_max of 0.5 and more)
the law is far from that and the step lands at a fraction of the true mu, with the linear
law's s0 and beta, which the sliding law must move by tens of percent. Its fit then starts
from the best of :func:`sliding_starts` as well: a grid over z0 = F0/F_max that keeps the
steady slip and its slope ds/da of the current fit (what the data fixed) and puts the
curvature in the law; each grid point is judged after one step of the engine's fit (the
belt coordinates and the speed spline follow the law by millimetres, so the raw chi^2 of
a grid point says little).

A long recording's Jacobian is the engine's NormalJacobian: :func:`screen_normal` takes
the same steps in normal form.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..model import CATALOG
from ._engine import _alternative_columns
from ._normal import NormalJacobian, pinv_factor, tdot

SINK_US_GRID = (3.0, 8.0, 20.0, 50.0, 120.0)
#: lug_shear's relaxation times tried (s): rubber lugs spring back in tens of ms
SHEAR_TAU_GRID = (0.005, 0.02, 0.06, 0.15)


@dataclass
class Alternative:
    """One starting configuration of an effect: fixed settings and linear columns."""

    settings: dict  # values set before differentiating (nonlinear parameters)
    columns: list  # [(extra settings, parameter name)]
    start: Callable  # linear coefficients -> parameter values
    label: str = ""


@dataclass
class Screened:
    """An effect's score at the current fit: chi^2 drop of one Gauss-Newton step."""

    effect: str
    dchi2: float
    theta_start: np.ndarray  # one Gauss-Newton step: every parameter moved
    theta_current: np.ndarray  # the current fit with the effect's nonlinear settings
    label: str = ""
    details: dict = field(default_factory=dict)


def _linear(names):
    return lambda b: {k: float(v) for k, v in zip(names, b)}


def alternatives(eid: str, engine, theta) -> list[Alternative]:
    """The starting configurations to try for effect `eid` at `theta`."""
    free = engine.free_names(eid)
    if eid in ("lug_ripple", "wheel_runout", "belt_sag", "marker_depth", "camera_tilt",
               "lug_sliding"):
        return [Alternative({}, [({}, k) for k in free], _linear(free))]
    if eid == "body_bounce":
        cols = [({"bounce_phi": 0.0}, "bounce_A"), ({"bounce_phi": math.pi / 2}, "bounce_A")]
        if "bounce_B" in free:
            cols += [({"bounce_phi": 0.0}, "bounce_B"),
                     ({"bounce_phi": math.pi / 2}, "bounce_B")]

        def start(b):
            A, phi = math.hypot(b[0], b[1]), math.atan2(b[1], b[0])
            out = {"bounce_A": A, "bounce_phi": phi}
            if len(b) > 2:
                out["bounce_B"] = b[2] * math.cos(phi) + b[3] * math.sin(phi)
            return out

        return [Alternative({}, cols, start)]
    if eid == "ground_sinkage":
        return [Alternative({"sink_us": u}, [({}, "sink_z")], _linear(["sink_z"]),
                            f"u_s={u:g} mm") for u in SINK_US_GRID]
    if eid == "lug_shear":  # the lag is linear in 1 - h; tau's column vanishes at h = 1
        return [Alternative({"shear_tau": tau}, [({}, "shear_h")], _linear(["shear_h"]),
                            f"tau={1000 * tau:g} ms") for tau in SHEAR_TAU_GRID]
    if eid == "lens_distortion":
        x, y = engine.field()
        xs = np.linspace(x[0], x[1], 5)
        ys = np.linspace(y[0], y[1], 3)
        return [Alternative({"lens_cx": float(cx), "lens_cy": float(cy)},
                            [({}, "lens_k1")], _linear(["lens_k1"]),
                            f"c=({cx:.0f}, {cy:.0f}) mm") for cx in xs for cy in ys]
    # any other effect: its free parameters' columns at identity
    return [Alternative({}, [({}, k) for k in free], _linear(free))]


def _basis(J: np.ndarray) -> tuple:
    """(U, s, W): orthonormal basis U of J's columns, and the factors of its pseudo-inverse
    J^+ = W^T diag(1/s) U^T, from the eigen-decomposition of its column-scaled normal
    matrix: ten times cheaper than a tall SVD, and accurate enough for projections with
    the columns scaled to unit norm first (condition number squared stays below 1e12)."""
    d = np.sqrt(np.sum(J * J, 0))
    d = np.where(d > 0, d, 1.0)
    Js = J / d
    w, V = np.linalg.eigh(Js.T @ Js)
    keep = w > 1e-12 * w.max()
    w, V = w[keep][::-1], V[:, keep][:, ::-1]
    s = np.sqrt(w)
    U = (Js @ V) / s
    # returned so that the pseudo-inverse is J^+ = W^T diag(1/s) U^T with W = V^T / d
    return U, s, V.T / d


def screen(engine, theta, r, J, effects, extra_names, geo) -> dict:
    """Score every effect in `effects` at the current fit (theta, residuals r, Jacobian J).

    `extra_names`: the added-effect parameters of J's last columns (after the base block).
    Returns effect id -> :class:`Screened` with a full starting vector for the fit.
    A long recording's J is the engine's NormalJacobian: screened in normal form.
    """
    if not isinstance(J, np.ndarray):
        return screen_normal(engine, theta, r, J, effects, extra_names, geo)
    U, s, Vt = _basis(J)
    r_perp = r - U @ (U.T @ r)
    idx = np.r_[engine.cur_idx, [engine.index(k) for k in extra_names]].astype(int)

    def gn_start(th, C, beta):
        # the model's own parameters follow the effect: -J^+ (r + C beta)
        rr = r + C @ beta
        delta = -(Vt.T @ ((U.T @ rr) / s))
        out = th.copy()
        out[idx] += delta
        return out

    out = {}
    for eid in effects:
        if eid == "frame_drop":
            out[eid] = _screen_frame_drop(engine, theta, r, U, geo, gn_start)
            continue
        best = None
        for alt in alternatives(eid, engine, theta):
            th = engine.with_values(theta, alt.settings)
            C = engine.fd_columns(alt.columns, th)
            Cp = C - U @ (U.T @ C)
            norms = np.sqrt(np.sum(Cp * Cp, 0))
            ok = norms > 1e-9 * max(norms.max(), 1e-300)
            if not ok.any():
                continue
            beta = np.zeros(C.shape[1])
            beta[ok] = np.linalg.lstsq(Cp[:, ok], -r_perp, rcond=None)[0]
            d = float(np.sum((Cp @ beta) ** 2))
            if best is None or d > best[0]:
                best = (d, alt, th, C, beta)
        if best is None:
            out[eid] = Screened(eid, 0.0, theta.copy(), theta.copy(), "no signature")
            continue
        d, alt, th, C, beta = best
        start = gn_start(th, C, beta)
        start = engine.with_values(start, alt.start(beta))
        out[eid] = Screened(eid, d, start, th, alt.label)
    return out


def frame_drop_tstar(engine, theta, r, geo, projected) -> tuple[float, float]:
    """(t*, its jump score): the frame where a time shift of all later samples best fits
    the residual jump. `projected(d, order, suffix, tu)` gives |U^T (d 1[t >= t_k])|^2 for
    each unique frame time t_k (U: an orthonormal basis of the current model's columns),
    from the dense basis or the chunked normal equations."""
    th = engine.with_values(theta, {"drop_tstar": -1e9})
    d = engine.fd_columns([({}, "drop_dt")], th)[:, 0]  # every sample shifted
    order = np.argsort(geo.t, kind="stable")
    # suffix sums over samples with t >= t_k, for each unique frame time t_k
    tu, first = np.unique(geo.t[order], return_index=True)

    def suffix(a):
        c = np.cumsum(a[::-1], axis=0)[::-1]
        return c[first]

    dd = d[order]
    cc = suffix(dd * dd)
    rc = suffix(r[order] * dd)
    den = cc - projected(d, order, suffix, tu)
    with np.errstate(divide="ignore", invalid="ignore"):
        score = np.where(den > 1e-12 * max(cc.max(), 1e-300), rc ** 2 / den, 0.0)
    score[0] = 0.0  # t* at the first frame shifts everything: no jump
    k = int(np.argmax(score))
    return float(tu[k]), float(score[k])


def _screen_frame_drop(engine, theta, r, U, geo, gn_start):
    """t* (:func:`frame_drop_tstar`), then one Gauss-Newton step of drop_dt there."""
    def projected(d, order, suffix, tu):
        qa = suffix(U[order] * d[order][:, None])
        return np.sum(qa * qa, 1)

    t_star, jump = frame_drop_tstar(engine, theta, r, geo, projected)
    th = engine.with_values(theta, {"drop_tstar": t_star})
    C = engine.fd_columns([({}, "drop_dt")], th)
    Cp = C - U @ (U.T @ C)
    r_perp = r - U @ (U.T @ r)
    beta = np.linalg.lstsq(Cp, -r_perp, rcond=None)[0]
    start = gn_start(th, C, beta)
    start = engine.with_values(start, {"drop_dt": float(beta[0])})
    return Screened("frame_drop", float(np.sum((Cp @ beta) ** 2)), start, th, f"t*={t_star:.4f} s",
                    {"t_star_s": t_star, "jump_score": jump})


#: the grid of F0/F_max of :func:`sliding_starts`
SLIDING_Z0_GRID = (0.15, 0.35, 0.55, 0.7, 0.8, 0.88, 0.94)


def sliding_starts(engine, theta) -> list:
    """Starting vectors of lug_sliding at F0/F_max = z0 on SLIDING_Z0_GRID, from a fit
    `theta` without it (slide_mu = 0 there, or the law's current value).

    Each keeps the steady slip S and the slope B = ds/da of `theta`'s slip law: with
    z0 = mu s0_lin, S = -ln(1 - z0) / mu and B = beta_lin / (1 - z0), so
    mu = -ln(1 - z0) / S, s0_lin = z0 / mu and beta_lin = B (1 - z0). Vectors whose ramps
    take the traction to F_max come out with huge chi^2 and lose."""
    s0 = engine.get(theta, "s0")
    beta = engine.get(theta, "beta")
    mu0 = engine.get(theta, "slide_mu")
    z = mu0 * s0
    if not (0 <= z < 1) or s0 <= 0:
        return []
    S = s0 if z == 0 else -math.log1p(-z) / mu0  # steady slip of the current law
    B = beta / (1.0 - z)
    out = []
    for z0 in SLIDING_Z0_GRID:
        mu = -math.log1p(-z0) / S
        out.append(engine.with_values(theta, {"slide_mu": mu, "s0": z0 / mu,
                                              "beta": B * (1.0 - z0)}))
    return out


def physical(eid: str, p: dict) -> str | None:
    """Why fitted parameters are not the physics the effect names (None when they are)."""
    g = lambda k: float(np.asarray(p[k]))  # noqa: E731
    if eid == "lug_sliding" and g("slide_mu") <= 0:
        return "the fitted slip grows slower than linearly (mu <= 0), not lug sliding"
    if eid == "belt_sag" and g("sag_d") <= 0:
        return "the top run bulges upward (d <= 0), not a sag"
    if eid == "ground_sinkage" and g("sink_z") <= 0:
        return "the lugs rise (z <= 0), not sinkage"
    if eid == "lug_shear" and not -0.25 <= g("shear_h") <= 1.0:
        where = "above the pitch line" if g("shear_h") > 1 else "below the lug tips"
        return f"the lug markers would sit {where} (h = {g('shear_h'):.2f}), not on the lugs"
    if eid == "lug_shear" and abs(g("shear_tau")) > 2.0:
        return f"the lugs' shear would take {abs(g('shear_tau')):.1f} s to relax, not rubber"
    if eid == "frame_drop" and g("drop_dt") <= 0:
        return "the stamps jump forward (dt <= 0), not a lost frame"
    return None


#: the largest radial distortion a lens left uncorrected makes at the farthest point seen,
#: k1 r^2 (a sane lens: a few per cent at the picture's corner)
LENS_MAX_DISTORTION = 0.1


#: a lost frame is seen as a jump of every marker in view: at least this many markers seen
#: within FRAME_DROP_WINDOW frames on both sides of t*
FRAME_DROP_MIN_MARKERS = 2
FRAME_DROP_WINDOW = 5


def in_picture(eid: str, p: dict, rec) -> str | None:
    """Why an effect's fitted parameters are not what the picture shows (issue 42), given
    the recording fitted (`rec`: its points seen, ground mm, and their times).

    - lens_distortion: a lens centre far outside the picture (more than its width from its
      middle) or a distortion beyond LENS_MAX_DISTORTION at the farthest point seen is a
      smooth warp fitted to something else (a tracker's drift), not a lens;
    - frame_drop: a lost frame moves every marker in view at one instant; a jump where fewer
      than FRAME_DROP_MIN_MARKERS markers are seen on both sides of t* (within
      FRAME_DROP_WINDOW frames) is one marker's (its tracker's, or the model's where one
      marker alone holds the motion), not a lost frame."""
    if eid == "frame_drop":
        return _one_marker_jump(float(np.asarray(p["drop_tstar"])), rec)
    if eid != "lens_distortion":
        return None
    x, y = rec.x, rec.y
    ok = np.isfinite(x) & np.isfinite(y)
    if ok.sum() < 2:
        return None
    x, y = x[ok], y[ok]
    cx, cy, k1 = (float(np.asarray(p[k])) for k in ("lens_cx", "lens_cy", "lens_k1"))
    width = max(float(np.ptp(x)), float(np.ptp(y)), 1.0)
    mx, my = 0.5 * (float(x.min()) + float(x.max())), 0.5 * (float(y.min()) + float(y.max()))
    if abs(cx - mx) > width or abs(cy - my) > width:
        return (f"the lens centre ({cx:.0f}, {cy:.0f}) mm lies more than the picture's width "
                f"({width:.0f} mm) from its middle: not a camera's lens")
    r2 = float(np.max((x - cx) ** 2 + (y - cy) ** 2))
    if abs(k1) * r2 > LENS_MAX_DISTORTION:
        return (f"a radial distortion of {100 * abs(k1) * r2:.0f} % at the farthest point "
                f"seen (k1 r^2; a lens: at most {100 * LENS_MAX_DISTORTION:.0f} %): not a lens")
    return None


def _one_marker_jump(t_star: float, rec) -> str | None:
    ok = np.asarray(rec.valid, bool) & np.isfinite(rec.x) & np.isfinite(rec.y)
    t, m = np.asarray(rec.t)[ok], np.asarray(rec.marker_index)[ok]
    w = FRAME_DROP_WINDOW / (rec.fps or 1.0)  # (no frame rate: fewer than two times seen)
    before = set(m[(t < t_star) & (t >= t_star - w)].tolist())
    after = set(m[(t >= t_star) & (t < t_star + w)].tolist())
    n = len(before & after)
    if n >= FRAME_DROP_MIN_MARKERS:
        return None
    return (f"{n} marker{'s' if n != 1 else ''} seen on both sides of t* = {t_star:.4f} s: a "
            f"jump of one marker is its tracker's, not a lost frame (every marker in view "
            f"jumps)")


def n_free(eid: str, n_body: int) -> int:
    return CATALOG[eid].n_free(n_body)


# ---------------------------------------------------------------------------------------
# The screening of :mod:`._candidates` on a NormalJacobian (long recordings): the same
# Gauss-Newton step per effect, with the projections orthogonal to J's columns written
# through J^T J's pseudo-inverse M M^T (the `_basis` eigen-decomposition of the same
# column-scaled normal matrix): x_perp . y_perp = x.y - (M^T J^T x).(M^T J^T y).
# ---------------------------------------------------------------------------------------
def screen_normal(engine, theta, r, NJ: NormalJacobian, effects, extra_names, geo) -> dict:
    """:func:`fitlug.explain._candidates.screen` for a :class:`NormalJacobian`."""
    M = pinv_factor(NJ.A, 1e-12)
    qr = M.T @ NJ.g  # M^T J^T r
    idx = np.r_[engine.cur_idx, [engine.index(k) for k in extra_names]].astype(int)

    def gn_start(th, JtC, beta):
        delta = -(M @ (qr + M.T @ (JtC @ beta)))  # -J^+ (r + C beta)
        out = th.copy()
        out[idx] += delta
        return out

    def project(C, JtC):
        Q = M.T @ JtC
        gram = tdot(C, C) - Q.T @ Q  # Cp^T Cp
        rhs = tdot(C, r) - Q.T @ qr  # Cp^T r_perp
        return gram, rhs

    out = {}
    for eid in effects:
        if eid == "frame_drop":
            out[eid] = _screen_frame_drop_normal(engine, theta, r, NJ, M, qr, geo, gn_start,
                                                 project)
            continue
        best = None
        for alt, th, C, JtC in _alternative_columns(engine, NJ, theta,
                                                    alternatives(eid, engine, theta)):
            gram, rhs = project(C, JtC)
            norms = np.sqrt(np.maximum(np.diag(gram), 0.0))
            ok = norms > 1e-9 * max(norms.max(), 1e-300)
            if not ok.any():
                continue
            beta = np.zeros(C.shape[1])
            beta[ok] = np.linalg.lstsq(gram[np.ix_(ok, ok)], -rhs[ok], rcond=None)[0]
            d = float(beta @ gram @ beta)
            if best is None or d > best[0]:
                best = (d, alt, th, JtC, beta)
        if best is None:
            out[eid] = Screened(eid, 0.0, theta.copy(), theta.copy(), "no signature")
            continue
        d, alt, th, JtC, beta = best
        start = gn_start(th, JtC, beta)
        start = engine.with_values(start, alt.start(beta))
        out[eid] = Screened(eid, d, start, th, alt.label)
    # the screening is the normal Jacobian's last use in a round: its chunks and columns
    # would otherwise stay resident through the round's candidate fits
    NJ.release()
    return out


def _screen_frame_drop_normal(engine, theta, r, NJ, M, qr, geo, gn_start, project):
    t_star, jump = frame_drop_tstar(
        engine, theta, r, geo,
        lambda d, order, suffix, tu: NJ.suffix_projections(d, geo.t, tu, M))  # |U^T d_k|^2
    th = engine.with_values(theta, {"drop_tstar": t_star})
    C = engine.fd_columns([({}, "drop_dt")], th)
    JtC = NJ.Jt(C)
    gram, rhs = project(C, JtC)
    beta = np.linalg.lstsq(gram, -rhs, rcond=None)[0]
    start = gn_start(th, JtC, beta)
    start = engine.with_values(start, {"drop_dt": float(beta[0])})
    return Screened("frame_drop", float(beta @ gram @ beta), start, th, f"t*={t_star:.4f} s",
                    {"t_star_s": t_star, "jump_score": jump})
