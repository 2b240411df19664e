"""An independent implementation of MODEL.md §2 and §3, written straight from the text.

Nothing from fitlug.model or fitlug.sim is used: plain numpy, a closed-form smoothstep
speed profile, brute-force integration on a 10 µs grid and the stadium table as printed.
It is the project's check that the model and fitter implement the contract, not just
agree with their own simulator.

The catalog effects of MODEL.md §3 are switched on with ``make(..., effects={id: {...}})``;
see `EFFECTS` for the parameter names (fitlug's names) and their defaults. Without
effects, or with ``effects={}``, the output is the base recording, bit for bit.

How each effect is read from MODEL.md §3 and its "Conventions":

- ``lug_ripple`` / ``wheel_runout``: the motor-profile speed v_b(t) becomes
  v = v_b·M(ψ), M = (1 + ε_r sin(2πψ/p + φ_r))·(1 + ε_w sin(ψ/R + φ_w)) (both present:
  applied one after the other). v is used everywhere: X' = v, a = dv/dt (which includes
  the v_b·M'(ψ)·ψ' term), F and s from that a, and ψ' = v/(1 − s). The phase uses the
  belt travel ψ itself, so X and ψ are integrated together (RK4, 0.1 ms steps, the
  implicit ψ' in a solved by fixed-point iteration; cubic Hermite to the frame times).
- ``lug_sliding``: s = −s_K ln(1 − s_lin/s_K), s_lin = 2F/(knL), for all t; the reported
  slip is −s_K ln(1 − s_lin0/s_K), s_lin0 = 2 m C_rr g/(knL).
- ``body_bounce``: body y += (A + B·c_xj) sin(2πψ/p + φ), c_xj the body marker's x offset.
- ``belt_sag``: top run, ξ = (u − D − πR)/D; path_y −= 4dξ(1 − ξ).
- ``ground_sinkage``: bottom run, u ∈ [0, D); path_y −= z(1 − exp(−u/u_s)).
- image effects on noise-free ground-frame points, in the order marker_depth (lug markers
  only, q → c + (1+ε)(q − c)), camera_tilt (counter-clockwise by θ about the origin),
  lens_distortion (q → c + (q − c)(1 + k1|q − c|²)); the measurement noise is added after.
- ``frame_drop``: rows keep their stamps t; for t ≥ t* the positions are those at the
  true time t + Δt (everything, ψ included, is evaluated at the true time).

The marker on the lug (MODEL.md §2, ``marker_h`` h and ``shear_tau`` τ; h = 1 is the
stadium path): each lug's shear d is stepped in time on the 10 µs grid as the text says it
(not as fitlug computes it): it is 0 where the lug touches down at the front of the bottom
run, grows at dd/dt = s·v_t while the lug is on the run, and relaxes as dd/dt = −d/τ after
lift-off; the marker is drawn at the stadium point of σ − (1 − h)·d. A lug already on the
run at t = 0 starts with the shear s(0)·u (the recording starts at rest, at the steady
slip's law).

Physics of MODEL.md §5 (beyond the catalog), each written from first principles here:

- arc radii per wheel (``R_front``, ``R_rear``): both wheels stand on the ground (the bottom
  run level, y = 0 at its pitch line, the rear centre at (−D/2, R_r), the front at (D/2,
  R_f)); the top run is the second common tangent, the mirror of the ground line in the
  line of centres: tilted by 2α, tan α = (R_f − R_r)/D, also D long; the rear wheel is
  wrapped over π − 2α, the front over π + 2α; P = 2D + R_r(π − 2α) + R_f(π + 2α) = N p
  fixes D (`stadium2`).
- a speed-dependent rolling resistance (``C_rr_v1``): C_rr(v) = C_rr (1 + |v|/v1), so
  F = m (a/1000 + C_rr(v) g) + F_d and the steady slip depends on the speed; ``speeds``
  gives any motor profile as a sum of smoothstep ramps (t0, t1, Δv) (accelerate, cruise,
  change speed, stop). The truth's slip is the steady slip at the highest cruise speed;
  ``slip_at_speed`` lists it at every plateau.
- a ground bump (``ground_bump``: height, x, width): the floor rises as
  h (1 + cos(2π(x − x_b)/w))/2 for |x − x_b| < w/2. Each wheel rides over it (its centre
  lifted by the highest point of the floor under a circle of radius R), the frame (body,
  wheels and the belt off the ground) heaves and pitches rigidly as the two wheels say
  (exact rotation about the middle of the bottom run's pitch line, so the body markers
  move in x too), and a lug on the bottom run sits on the floor.
"""

from __future__ import annotations

import copy
import math

import numpy as np

from fitlug.io import Recording, Rig

G = 9.81

# effect id -> {parameter: default}; None marks a required parameter.
EFFECTS = {
    "lug_ripple": {"ripple_eps": None, "ripple_phi": 0.0},
    "wheel_runout": {"runout_eps": None, "runout_phi": 0.0},
    "body_bounce": {"bounce_A": None, "bounce_B": 0.0, "bounce_phi": 0.0},
    "lug_sliding": {"s_K": None},
    "belt_sag": {"sag_d": None},
    "ground_sinkage": {"sink_z": None, "sink_us": None},
    "lens_distortion": {"lens_k1": None, "lens_cx": 0.0, "lens_cy": 0.0},
    "marker_depth": {"depth_eps": None, "depth_cx": 0.0, "depth_cy": 0.0},
    "camera_tilt": {"tilt_theta": None},
    "frame_drop": {"drop_dt": None, "drop_tstar": None},
}

ODE_STEP = 1e-4  # s, RK4 step of the speed-modulated kinematics


def stadium(u, R, D, e):
    """The MODEL.md table, literally."""
    P = 2 * D + 2 * math.pi * R
    u = np.mod(u, P)
    x = np.empty_like(u)
    y = np.empty_like(u)
    s1 = u < D
    s2 = (u >= D) & (u < D + math.pi * R)
    s3 = (u >= D + math.pi * R) & (u < 2 * D + math.pi * R)
    s4 = u >= 2 * D + math.pi * R
    x[s1], y[s1] = D / 2 - u[s1], -e
    phi = (u[s2] - D) / R
    x[s2], y[s2] = -D / 2 - (R + e) * np.sin(phi), R - (R + e) * np.cos(phi)
    x[s3], y[s3] = -D / 2 + (u[s3] - D - math.pi * R), 2 * R + e
    phi = (u[s4] - 2 * D - math.pi * R) / R
    x[s4], y[s4] = D / 2 + (R + e) * np.sin(phi), R + (R + e) * np.cos(phi)
    return x, y


def stadium2(u, R_r, R_f, D, e):
    """The belt's pitch-line path with a rear wheel of radius R_r and a front wheel of R_f
    (both on the ground; see the module's text), marker offset e outward. Equal radii give
    `stadium`."""
    al = math.atan2(R_f - R_r, D)
    wr, wf = math.pi - 2 * al, math.pi + 2 * al  # wrap angles
    P = 2 * D + R_r * wr + R_f * wf
    u = np.mod(u, P)
    x = np.empty_like(u)
    y = np.empty_like(u)
    b1, b2, b3 = D, D + R_r * wr, 2 * D + R_r * wr
    s1 = u < b1
    s2 = (u >= b1) & (u < b2)
    s3 = (u >= b2) & (u < b3)
    s4 = u >= b3
    x[s1], y[s1] = D / 2 - u[s1], -e
    phi = (u[s2] - b1) / R_r
    x[s2], y[s2] = -D / 2 - (R_r + e) * np.sin(phi), R_r - (R_r + e) * np.cos(phi)
    # top run: from the rear tangent point, along (cos 2α, sin 2α), offset e along its normal
    c2, s2a = math.cos(2 * al), math.sin(2 * al)
    q = u[s3] - b2
    x0, y0 = -D / 2 - R_r * s2a, R_r + R_r * c2
    x[s3] = x0 + q * c2 - e * s2a
    y[s3] = y0 + q * s2a + e * c2
    phi = -2 * al + (u[s4] - b3) / R_f
    x[s4], y[s4] = D / 2 + (R_f + e) * np.sin(phi), R_f + (R_f + e) * np.cos(phi)
    return x, y


def belt_length2(R_r, R_f, D):
    """P of `stadium2`."""
    al = math.atan2(R_f - R_r, D)
    return 2 * D + R_r * (math.pi - 2 * al) + R_f * (math.pi + 2 * al)


def _solve_D(P, R_r, R_f):
    """D with belt_length2(R_r, R_f, D) = P (bisection)."""
    lo, hi = 1e-3, P / 2
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if belt_length2(R_r, R_f, mid) < P:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def bump_height(x, bump):
    """The floor's height (mm) at ground x under ``ground_bump`` {height, x, width}."""
    h, xb, w = bump["height"], bump["x"], bump["width"]
    z = (np.asarray(x, float) - xb) / (w / 2)
    return np.where(np.abs(z) < 1, h * 0.5 * (1 + np.cos(np.pi * z)), 0.0)


def wheel_lift(xc, R, bump):
    """Lift of the centre of a wheel of radius R at ground x `xc` rolling on the floor."""
    s = np.linspace(-R, R, 401)
    prof = bump_height(np.asarray(xc)[:, None] + s[None, :], bump) + \
        np.sqrt(R * R - s * s)[None, :] - R
    return np.maximum(prof.max(axis=1), 0.0)


def path_corrections(u, R, D, sag=None, sink=None):
    """Extra path_y of belt_sag (top run) and ground_sinkage (bottom run), MODEL.md §3."""
    P = 2 * D + 2 * math.pi * R
    u = np.mod(u, P)
    dy = np.zeros_like(u)
    if sag is not None:
        top = (u >= D + math.pi * R) & (u < 2 * D + math.pi * R)
        xi = (u[top] - D - math.pi * R) / D
        dy[top] -= 4 * sag * xi * (1 - xi)
    if sink is not None:
        z, us = sink
        bot = u < D
        dy[bot] -= z * (1 - np.exp(-u[bot] / us))
    return dy


def _resolve(effects):
    """Validated {id: {param: value}} with defaults filled in."""
    out = {}
    for eid, params in (effects or {}).items():
        if eid not in EFFECTS:
            raise ValueError(f"unknown effect {eid!r}; known: {sorted(EFFECTS)}")
        params = dict(params or {})
        unknown = set(params) - set(EFFECTS[eid])
        if unknown:
            raise ValueError(f"{eid}: unknown parameters {sorted(unknown)}")
        full = {}
        for name, default in EFFECTS[eid].items():
            if name in params:
                full[name] = float(params[name])
            elif default is None:
                raise ValueError(f"{eid}: parameter {name!r} is required")
            else:
                full[name] = float(default)
        out[eid] = full
    return out


def _hermite(tq, tg, y, dy):
    """Cubic Hermite interpolation of (y, y') given on the uniform grid tg."""
    h = tg[1] - tg[0]
    i = np.clip(np.floor((tq - tg[0]) / h).astype(np.int64), 0, len(tg) - 2)
    s = (tq - tg[i]) / h
    h00 = 2 * s**3 - 3 * s**2 + 1
    h10 = s**3 - 2 * s**2 + s
    h01 = -2 * s**3 + 3 * s**2
    h11 = s**3 - s**2
    return h00 * y[i] + h10 * h * dy[i] + h01 * y[i + 1] + h11 * h * dy[i + 1]


def make(seed=0, *, fps=120.0, duration=5.0, v_max=120.0, t_acc=(0.4, 1.6), t_dec=(3.4, 4.6),
         m=6.0, k=0.3, C_rr=0.08, n=8, L=127.0, R=30.0, pitch=20.0, N=20, e=2.5,
         x_off=3.0, y_off=4.0, n_lug=8, body=((-50.0, 70.0), (45.0, 72.0)),
         noise_lug=0.0065, noise_body=0.0041, effects=None, F_d=0.0, ground=None,
         marker_h=1.0, shear_tau=0.0, R_front=None, R_rear=None, speeds=None, C_rr_v1=None,
         ground_bump=None):
    """A recording (Recording, Rig, truth dict) from the contract's equations.

    F_d: drawbar pull (N), added to the traction load F = m (a/1000 + C_rr g) + F_d.
    ground: the rig's [ground] name.

    effects: {effect_id: {param: value}} with the ids and parameter names of `EFFECTS`.
    """
    rec, rig, truth, _ = make_detailed(
        seed, fps=fps, duration=duration, v_max=v_max, t_acc=t_acc, t_dec=t_dec, m=m, k=k,
        C_rr=C_rr, n=n, L=L, R=R, pitch=pitch, N=N, e=e, x_off=x_off, y_off=y_off,
        n_lug=n_lug, body=body, noise_lug=noise_lug, noise_body=noise_body, effects=effects,
        F_d=F_d, ground=ground, marker_h=marker_h, shear_tau=shear_tau, R_front=R_front,
        R_rear=R_rear, speeds=speeds, C_rr_v1=C_rr_v1, ground_bump=ground_bump)
    return rec, rig, truth


def make_detailed(seed=0, *, fps=120.0, duration=5.0, v_max=120.0, t_acc=(0.4, 1.6),
                  t_dec=(3.4, 4.6), m=6.0, k=0.3, C_rr=0.08, n=8, L=127.0, R=30.0, pitch=20.0,
                  N=20, e=2.5, x_off=3.0, y_off=4.0, n_lug=8,
                  body=((-50.0, 70.0), (45.0, 72.0)), noise_lug=0.0065, noise_body=0.0041,
                  effects=None, F_d=0.0, ground=None, marker_h=1.0, shear_tau=0.0,
                  R_front=None, R_rear=None, speeds=None, C_rr_v1=None, ground_bump=None):
    """As `make`, plus a dict of noise-free series at the frame stamps for tests.

    R_front, R_rear: the wheels' pitch radii (mm; either None: R for it), `stadium2`.
    speeds: ((t0, t1, dv), ...) smoothstep ramps of the motor speed (None: up to v_max over
    t_acc, down over t_dec). C_rr_v1: mm/s, C_rr(v) = C_rr (1 + |v| / C_rr_v1).
    ground_bump: {"height", "x", "width"} (mm), a raised-cosine rise of the floor.

    series: t (stamps, one per frame), tau (true times), X, psi, v (the possibly modulated
    speed), vt (belt speed), s (slip) at tau; sigma0 (lug markers' σ_i0); P, D.
    """
    eff = _resolve(effects)
    P = N * pitch
    two = R_front is not None or R_rear is not None
    R_f = float(R if R_front is None else R_front)
    R_r = float(R if R_rear is None else R_rear)
    D = _solve_D(P, R_r, R_f) if two else (P - 2 * math.pi * R) / 2
    if two and (marker_h != 1.0 or "belt_sag" in eff or "ground_sinkage" in eff):
        raise ValueError("R_front/R_rear with marker_h or a path effect: not implemented")
    ramps = (((t_acc[0], t_acc[1], v_max), (t_dec[0], t_dec[1], -v_max)) if speeds is None
             else tuple(tuple(map(float, q)) for q in speeds))

    def smoothstep(x):
        x = np.clip(x, 0, 1)
        return x * x * (3 - 2 * x)

    def dsmooth(x):
        return np.where((x > 0) & (x < 1), 6 * x * (1 - x), 0.0)

    def profile(tt):
        v = 0.0 * tt
        a = 0.0 * tt
        for t0, t1, dv in ramps:
            xa = (tt - t0) / (t1 - t0)
            v = v + dv * smoothstep(xa)
            a = a + dv * dsmooth(xa) / (t1 - t0)
        return v, a

    def crr(v):
        return C_rr if C_rr_v1 is None else C_rr * (1 + np.abs(v) / C_rr_v1)

    sK = eff["lug_sliding"]["s_K"] if "lug_sliding" in eff else None

    def slip_law(s_lin):
        if sK is None:
            return s_lin
        arg = s_lin / sK
        if isinstance(arg, float):  # the scalar ODE loop
            if arg >= 1:
                raise ValueError("lug_sliding: the load reaches F_max (s_lin >= s_K)")
            return -sK * math.log1p(-arg)
        if np.any(arg >= 1):
            raise ValueError("lug_sliding: the load reaches F_max (s_lin >= s_K)")
        return -sK * np.log1p(-arg)

    # stamps and true times
    t = np.arange(int(round(duration * fps))) / fps
    tau = t
    if "frame_drop" in eff:
        fd = eff["frame_drop"]
        tau = np.where(t >= fd["drop_tstar"] - 1e-9, t + fd["drop_dt"], t)
        if np.any(tau < 0):
            raise ValueError("frame_drop: a true time before 0")
    t_end = max(duration, float(np.max(tau)) if len(tau) else 0.0)

    modulated = "lug_ripple" in eff or "wheel_runout" in eff
    if not modulated:
        h = 1e-5
        tt = np.arange(0, t_end + h / 2, h)
        v, a = profile(tt)
        F = m * (a / 1000.0 + crr(v) * G) + F_d
        s = 2 * F / (k * n * L)
        if sK is not None:
            s = slip_law(s)
        vt = v / (1 - s)
        X = np.concatenate([[0], np.cumsum((v[1:] + v[:-1]) / 2 * h)])
        psi = np.concatenate([[0], np.cumsum((vt[1:] + vt[:-1]) / 2 * h)])
        Xs, psis = np.interp(tau, tt, X), np.interp(tau, tt, psi)
        vs, vts, ss = np.interp(tau, tt, v), np.interp(tau, tt, vt), np.interp(tau, tt, s)
        if marker_h != 1.0:
            shear = _lug_shear(11.0 + pitch * np.arange(n_lug), psi, v, vt, s, h, D, P,
                               shear_tau)
            lag = (1.0 - marker_h) * np.stack([np.interp(tau, tt, d) for d in shear])
    else:
        if marker_h != 1.0 or C_rr_v1 is not None:
            raise ValueError("marker_h != 1 or C_rr_v1 with a speed modulation: not "
                             "implemented here")
        er = eff.get("lug_ripple", {}).get("ripple_eps", 0.0)
        pr = eff.get("lug_ripple", {}).get("ripple_phi", 0.0)
        ew = eff.get("wheel_runout", {}).get("runout_eps", 0.0)
        pw = eff.get("wheel_runout", {}).get("runout_phi", 0.0)
        kr = 2 * math.pi / pitch
        kw = 1.0 / R

        def rates(vb, ab, ps, sin, cos):
            """(v, ψ', a, s): v = v_b·M(ψ), a = a_b·M + v_b·M'·ψ', ψ' = v/(1 − s(a))"""
            mr = 1 + er * sin(kr * ps + pr)
            mw = 1 + ew * sin(kw * ps + pw)
            dM = er * kr * cos(kr * ps + pr) * mw + mr * ew * kw * cos(kw * ps + pw)
            vv = vb * mr * mw
            w = vv
            for _ in range(4):  # ψ' enters a only through v_b·M'·ψ': fast fixed point
                aa = ab * mr * mw + vb * dM * w
                ss = slip_law(2 * (m * (aa / 1000.0 + C_rr * G) + F_d) / (k * n * L))
                w = vv / (1 - ss)
            return vv, w, aa, ss

        h = ODE_STEP
        nstep = int(math.ceil(t_end / h)) + 1
        tg = np.arange(nstep + 1) * h
        vb_g, ab_g = profile(tg)
        vb_m, ab_m = profile(tg[:-1] + h / 2)
        vb_g, ab_g, vb_m, ab_m = (q.tolist() for q in (vb_g, ab_g, vb_m, ab_m))
        Xg = np.zeros(nstep + 1)
        Pg = np.zeros(nstep + 1)
        x_, p_ = 0.0, 0.0
        sin, cos = math.sin, math.cos
        for i in range(nstep):
            k1x, k1p = rates(vb_g[i], ab_g[i], p_, sin, cos)[:2]
            k2x, k2p = rates(vb_m[i], ab_m[i], p_ + h / 2 * k1p, sin, cos)[:2]
            k3x, k3p = rates(vb_m[i], ab_m[i], p_ + h / 2 * k2p, sin, cos)[:2]
            k4x, k4p = rates(vb_g[i + 1], ab_g[i + 1], p_ + h * k3p, sin, cos)[:2]
            x_ += h / 6 * (k1x + 2 * k2x + 2 * k3x + k4x)
            p_ += h / 6 * (k1p + 2 * k2p + 2 * k3p + k4p)
            Xg[i + 1], Pg[i + 1] = x_, p_
        vg, wg, _, _ = rates(np.asarray(vb_g), np.asarray(ab_g), Pg, np.sin, np.cos)
        Xs = _hermite(tau, tg, Xg, vg)
        psis = _hermite(tau, tg, Pg, wg)
        vb_s, ab_s = profile(tau)
        vs, vts, _, ss = rates(vb_s, ab_s, psis, np.sin, np.cos)

    # noise-free ground-frame points
    sigma0 = 11.0 + pitch * np.arange(n_lug)  # consecutive lugs
    sag = eff["belt_sag"]["sag_d"] if "belt_sag" in eff else None
    sink = ((eff["ground_sinkage"]["sink_z"], eff["ground_sinkage"]["sink_us"])
            if "ground_sinkage" in eff else None)
    cx_, cy_ = [], []
    for i in range(n_lug):
        ui = sigma0[i] + psis - (lag[i] if marker_h != 1.0 else 0.0)
        px, py = stadium2(ui, R_r, R_f, D, e) if two else stadium(ui, R, D, e)
        if sag is not None or sink is not None:
            py = py + path_corrections(ui, R, D, sag, sink)
        cx_.append(Xs + x_off + px)
        cy_.append(y_off + py)
    for j, (cx, cy) in enumerate(body):
        cx_.append(Xs + cx)
        yb = cy
        if "body_bounce" in eff:
            bb = eff["body_bounce"]
            yb = cy + (bb["bounce_A"] + bb["bounce_B"] * cx) * np.sin(
                2 * math.pi * psis / pitch + bb["bounce_phi"])
        cy_.append(yb)
    if ground_bump is not None:
        _ride(cx_, cy_, n_lug, sigma0, psis, Xs, x_off, y_off, R, D, P, e, ground_bump)

    def image(qx, qy, lug):
        if "marker_depth" in eff and lug:
            md = eff["marker_depth"]
            qx = md["depth_cx"] + (1 + md["depth_eps"]) * (qx - md["depth_cx"])
            qy = md["depth_cy"] + (1 + md["depth_eps"]) * (qy - md["depth_cy"])
        if "camera_tilt" in eff:
            th = eff["camera_tilt"]["tilt_theta"]
            c, sn = math.cos(th), math.sin(th)
            qx, qy = c * qx - sn * qy, sn * qx + c * qy
        if "lens_distortion" in eff:
            ld = eff["lens_distortion"]
            dx, dy = qx - ld["lens_cx"], qy - ld["lens_cy"]
            f = 1 + ld["lens_k1"] * (dx * dx + dy * dy)
            qx, qy = ld["lens_cx"] + dx * f, ld["lens_cy"] + dy * f
        return qx, qy

    if any(q in eff for q in ("marker_depth", "camera_tilt", "lens_distortion")):
        for i in range(n_lug + len(body)):
            cx_[i], cy_[i] = image(cx_[i] + 0 * t, cy_[i] + 0 * t, i < n_lug)

    # measurement noise, drawn in the base generator's order
    rng = np.random.default_rng(seed)
    xs, ys, mi, ts = [], [], [], []
    for i in range(n_lug):
        xs.append(cx_[i] + rng.normal(0, noise_lug, len(t)))
        ys.append(cy_[i] + rng.normal(0, noise_lug, len(t)))
        mi.append(np.full(len(t), i))
        ts.append(t)
    for j in range(len(body)):
        xs.append(cx_[n_lug + j] + rng.normal(0, noise_body, len(t)))
        ys.append(cy_[n_lug + j] + rng.normal(0, noise_body, len(t)))
        mi.append(np.full(len(t), n_lug + j))
        ts.append(t)
    markers = tuple([f"L{i}" for i in range(n_lug)] + [f"C{j}" for j in range(len(body))])
    roles = tuple(["lug"] * n_lug + ["body"] * len(body))
    rec = Recording(markers=markers, roles=roles, t=np.concatenate(ts),
                    marker_index=np.concatenate(mi).astype(np.int64), x=np.concatenate(xs),
                    y=np.concatenate(ys), meta={"fps": str(fps)})
    plateaus = sorted({round(float(np.sum([dv for t0_, t1_, dv in ramps if t1_ <= tq])), 9)
                       for tq in [r_[1] for r_ in ramps]} - {0.0})
    v_top = max(plateaus, key=abs) if plateaus else 0.0
    s_lin0 = 2 * (m * float(crr(v_top)) * G + F_d) / (k * n * L)
    s0 = float(slip_law(s_lin0)) if sK is not None else s_lin0
    truth = {"slip": s0, "delta_l_mm": s_lin0 * L / (n - 1), "stiffness_N_per_mm": k,
             "rolling_resistance": C_rr, "R_mm": R, "D_mm": D, "e_mm": e, "pitch_mm": pitch,
             "effects": copy.deepcopy(eff), "drawbar_pull_N": F_d,
             "traction_N": m * float(crr(v_top)) * G + F_d, "marker_h": marker_h,
             "shear_tau": shear_tau}
    if two:
        truth.update({"R_front_mm": R_f, "R_rear_mm": R_r, "R_mm": 0.5 * (R_f + R_r),
                      "delta_R_mm": R_f - R_r})
    if C_rr_v1 is not None:
        truth.update({"v_ref_mm_s": v_top, "C_rr_v1_mm_s": C_rr_v1,
                      "slip_at_rest": 2 * (m * C_rr * G + F_d) / (k * n * L),
                      "slip_at_speed": {v_: 2 * (m * float(crr(v_)) * G + F_d) / (k * n * L)
                                        for v_ in plateaus}})
    if ground_bump is not None:
        truth["ground_bump"] = dict(ground_bump)
    if sK is not None:
        truth["slip_linear"] = s_lin0
    rig = Rig(load_bearing_length_mm=L, lugs_in_contact=n, lug_pitch_mm=pitch, mass_kg=m,
              drawbar_pull_N=F_d, ground=ground)
    series = {"t": t, "tau": tau, "X": Xs, "psi": psis, "v": vs, "vt": vts, "s": ss,
              "sigma0": sigma0, "P": P, "D": D}
    return rec, rig, truth, series


def _lug_shear(sigma0, psi, v, vt, s, h, D, P, tau):
    """Each lug's shear d (mm) on the fine grid, stepped in time (see the module's text)."""
    u = np.mod(sigma0[:, None] + psi[None, :], P)  # (lugs, steps)
    on = u < D
    gain = (vt - v) * h  # s v_t dt
    decay = math.exp(-h / tau) if tau > 0 else 0.0
    d = np.where(on[:, 0], s[0] * u[:, 0], 0.0)
    out = np.empty_like(u)
    out[:, 0] = d
    was = on[:, 0]
    for k in range(1, u.shape[1]):
        now = on[:, k]
        d = np.where(now, np.where(was, d + gain[k], 0.0), d * decay)
        out[:, k] = d
        was = now
    return list(out)


def _ride(cx_, cy_, n_lug, sigma0, psis, Xs, x_off, y_off, R, D, P, e, bump):
    """The frame riding over the floor's bump (module text): in place on the noise-free
    lists of points cx_, cy_ (lugs first, then the body markers)."""
    mid = Xs + x_off  # ground x of the middle of the bottom run
    lr = wheel_lift(mid - D / 2, R, bump)
    lf = wheel_lift(mid + D / 2, R, bump)
    th = np.arcsin((lf - lr) / D)
    heave = 0.5 * (lf + lr)
    c, sn = np.cos(th), np.sin(th)
    for i in range(len(cx_)):
        qx, qy = cx_[i] - mid, cy_[i] - y_off  # about the bottom run's pitch-line middle
        rx, ry = mid + c * qx - sn * qy, y_off + heave + sn * qx + c * qy
        if i < n_lug:
            u = np.mod(sigma0[i] + psis, P)
            bottom = u < D
            # on the ground: its x is the belt's, its y the floor's (the lug's rubber takes
            # up the difference to the line between the wheels' feet)
            yb = cy_[i] + bump_height(cx_[i], bump)
            rx, ry = np.where(bottom, cx_[i], rx), np.where(bottom, yb, ry)
        cx_[i], cy_[i] = rx, ry
