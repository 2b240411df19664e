"""The catalog effects of tests/independent_sim.py against the text of MODEL.md §3.

Each test checks a cheap, falsifiable property of the generated (mostly noise-free) data:
a zero amplitude gives the base recording, and each effect has the signature and the
size that MODEL.md gives it. Quantities are measured from the marker data (finite
differences of body and lug positions), not read back from the generator where possible.
"""

import math

import numpy as np
import pytest

import independent_sim as isim

G = 9.81
# a short recording: accelerate 0.2–0.8 s, cruise to 2.2 s, stop by 2.8 s
FAST = dict(duration=3.0, t_acc=(0.2, 0.8), t_dec=(2.2, 2.8), noise_lug=0.0, noise_body=0.0)
DENSE = dict(FAST, fps=1000.0, n_lug=20)  # every lug of the belt, 1 ms frames
M, K, CRR, NL, LL, R, PITCH, XOFF, YOFF, E = 6.0, 0.3, 0.08, 8, 127.0, 30.0, 20.0, 3.0, 4.0, 2.5
BODY = ((-50.0, 70.0), (45.0, 72.0))


def grid(rec):
    """x, y as (marker, frame) arrays and the frame stamps."""
    nm = len(rec.markers)
    t = rec.t[rec.marker_index == 0]
    return rec.x.reshape(nm, -1), rec.y.reshape(nm, -1), t


def body_kinematics(rec):
    """X(t), v, a of the body reference from body marker C0 (central differences)."""
    x, _, t = grid(rec)
    X = x[rec.markers.index("C0")] - BODY[0][0]
    h = t[1] - t[0]
    v = np.gradient(X, h)
    a = np.gradient(v, h)
    v[1:-1] = (X[2:] - X[:-2]) / (2 * h)
    a[1:-1] = (X[2:] - 2 * X[1:-1] + X[:-2]) / h**2
    return t, X, v, a


def measured_slip(rec):
    """s(t) = 1 − v/v_t with v_t = v − dx/dt of lug markers on the bottom run (y = y_off − e).

    Returns (mask of frames with a measurement, s); averaged over the lugs on the run."""
    x, y, t = grid(rec)
    _, _, v, _ = body_kinematics(rec)
    h = t[1] - t[0]
    lugs = [i for i, r in enumerate(rec.roles) if r == "lug"]
    acc = np.zeros(len(t))
    cnt = np.zeros(len(t))
    for i in lugs:
        on = np.abs(y[i] - (YOFF - E)) < 1e-9
        ok = np.zeros(len(t), bool)
        ok[1:-1] = on[:-2] & on[1:-1] & on[2:]
        dx = np.zeros(len(t))
        dx[1:-1] = (x[i, 2:] - x[i, :-2]) / (2 * h)
        acc[ok] += (v - dx)[ok]
        cnt[ok] += 1
    have = (cnt > 0) & (np.abs(v) > 20.0)
    vt = np.where(have, acc / np.maximum(cnt, 1), np.nan)
    return have, 1 - v / vt


def law(F, s_K=None):
    s_lin = 2 * F / (K * NL * LL)
    return s_lin if s_K is None else -s_K * np.log1p(-s_lin / s_K)


def lug_passing_phase(series, phi):
    return 2 * math.pi * series["psi"] / PITCH + phi


# ---------------------------------------------------------------- API and the base

def test_empty_effects_is_the_base_bit_for_bit():
    base = isim.make(seed=4, duration=2.0)
    for eff in (None, {}):
        rec, rig, truth = isim.make(seed=4, duration=2.0, effects=eff)
        assert np.array_equal(rec.x, base[0].x) and np.array_equal(rec.y, base[0].y)
        assert np.array_equal(rec.t, base[0].t) and rig == base[1]
        assert truth["effects"] == {} and truth["slip"] == base[2]["slip"]


ZERO = {
    "lug_ripple": {"ripple_eps": 0.0, "ripple_phi": 0.7},
    "wheel_runout": {"runout_eps": 0.0, "runout_phi": 0.7},
    "body_bounce": {"bounce_A": 0.0, "bounce_B": 0.0, "bounce_phi": 0.7},
    "lug_sliding": {"s_K": 1e9},
    "belt_sag": {"sag_d": 0.0},
    "ground_sinkage": {"sink_z": 0.0, "sink_us": 20.0},
    "lens_distortion": {"lens_k1": 0.0, "lens_cx": 10.0, "lens_cy": 30.0},
    "marker_depth": {"depth_eps": 0.0, "depth_cx": 10.0, "depth_cy": 30.0},
    "camera_tilt": {"tilt_theta": 0.0},
    "frame_drop": {"drop_dt": 0.0, "drop_tstar": 1.0},
}


@pytest.mark.parametrize("eid", sorted(ZERO))
def test_zero_amplitude_is_the_base(eid):
    kw = dict(FAST, noise_lug=0.0065, noise_body=0.0041)
    base, _, _ = isim.make(seed=7, **kw)
    rec, _, truth = isim.make(seed=7, **kw, effects={eid: ZERO[eid]})
    assert truth["effects"] == {eid: ZERO[eid]}
    assert np.array_equal(rec.t, base.t)
    # the speed-modulated path integrates separately (RK4): agreement to 1e-6 mm
    assert np.max(np.abs(rec.x - base.x)) < 1e-6
    assert np.max(np.abs(rec.y - base.y)) < 1e-6


def test_bad_effects_raise():
    with pytest.raises(ValueError, match="unknown effect"):
        isim.make(**FAST, effects={"lug_wobble": {}})
    with pytest.raises(ValueError, match="unknown parameters"):
        isim.make(**FAST, effects={"lug_ripple": {"ripple_eps": 0.1, "eps": 0.1}})
    with pytest.raises(ValueError, match="required"):
        isim.make(**FAST, effects={"belt_sag": {}})
    with pytest.raises(ValueError, match="F_max"):  # the steady load already beyond F_max
        isim.make(**FAST, effects={"lug_sliding": {"s_K": 0.02}})


# ---------------------------------------------------------------- speed modulations

def _speed_ratio(eff):
    base = isim.make(**DENSE)[0]
    rec, _, truth, series = isim.make_detailed(**DENSE, effects=eff)
    _, _, v, _ = body_kinematics(rec)
    _, _, vb, _ = body_kinematics(base)
    use = vb > 20.0
    use[[0, -1]] = False
    return rec, truth, series, use, v[use] / vb[use] - 1


def test_psi_is_the_belt_travel_seen_by_the_lugs():
    """The series ψ used below is the one the lug markers follow (bottom run: x − X)."""
    rec, _, _, series = isim.make_detailed(
        **DENSE, effects={"lug_ripple": {"ripple_eps": 0.05, "ripple_phi": 0.4}})
    x, y, _ = grid(rec)
    X = series["X"]
    D, P = series["D"], series["P"]
    for i in range(20):
        on = np.abs(y[i] - (YOFF - E)) < 1e-9
        u = np.mod(series["sigma0"][i] + series["psi"], P)
        assert np.allclose((x[i] - X - XOFF)[on], (D / 2 - u)[on], atol=1e-9)


def test_lug_ripple_speed_locked_to_belt_phase():
    eps, phi = 0.05, 0.4
    rec, truth, series, use, ratio = _speed_ratio(
        {"lug_ripple": {"ripple_eps": eps, "ripple_phi": phi}})
    expect = eps * np.sin(lug_passing_phase(series, phi))[use]
    assert np.max(np.abs(ratio - expect)) < 2e-4
    # the phase is the belt travel, not v_b·t / the body travel X
    wrong = eps * np.sin(2 * math.pi * series["X"] / PITCH + phi)[use]
    assert np.max(np.abs(ratio - wrong)) > 0.02


def test_lug_ripple_x_content_at_lug_passing_frequency():
    eps = 0.05
    kw = dict(FAST, fps=200.0, n_lug=4)
    base = isim.make(**kw)[0]
    rec, _, truth = isim.make(**kw, effects={"lug_ripple": {"ripple_eps": eps}})
    xb, _, t = grid(base)
    xr, _, _ = grid(rec)
    cruise = (t > 0.9) & (t < 2.1)
    f_lug = 120.0 / (1 - truth["slip"]) / PITCH
    for i in (rec.markers.index("C0"), rec.markers.index("C1")):  # body (lugs add path terms)
        d = (xr[i] - xb[i])[cruise]
        d = d - np.polyval(np.polyfit(t[cruise], d, 1), t[cruise])
        spec = np.abs(np.fft.rfft(d * np.hanning(len(d)), 8192))
        f = np.fft.rfftfreq(8192, t[1] - t[0])
        assert abs(f[np.argmax(spec)] - f_lug) < 0.3
        # amplitude ε p (1 − s0)/(2π) to first order in ε
        amp = (d.max() - d.min()) / 2
        assert abs(amp / (eps * PITCH * (1 - truth["slip"]) / (2 * math.pi)) - 1) < 0.15


def test_wheel_runout_speed_locked_to_wheel_phase():
    eps, phi = 0.03, 1.1
    rec, truth, series, use, ratio = _speed_ratio(
        {"wheel_runout": {"runout_eps": eps, "runout_phi": phi}})
    expect = eps * np.sin(series["psi"] / R + phi)[use]
    assert np.max(np.abs(ratio - expect)) < 2e-4
    assert np.ptp(ratio) > 1.5 * eps  # at least most of a wheel revolution is seen


@pytest.mark.parametrize("eff", [
    {"lug_ripple": {"ripple_eps": 0.05, "ripple_phi": 0.4}},
    {"wheel_runout": {"runout_eps": 0.05, "runout_phi": 1.1}},
    {"lug_sliding": {"s_K": 0.06}},
    {"lug_ripple": {"ripple_eps": 0.05}, "lug_sliding": {"s_K": 0.06}},
], ids=["ripple", "runout", "sliding", "ripple+sliding"])
def test_slip_follows_the_acceleration_of_the_final_speed(eff):
    """s(t) from the lugs' stall drift equals the slip law at F = m(a/1000 + C_rr g),
    with a the measured acceleration of the (modulated) body motion."""
    rec = isim.make(**DENSE, effects=eff)[0]
    _, _, _, a = body_kinematics(rec)
    have, s = measured_slip(rec)
    s_K = eff.get("lug_sliding", {}).get("s_K")
    predicted = law(M * (a / 1000.0 + CRR * G), s_K)
    assert have.sum() > 1500
    assert np.max(np.abs(s - predicted)[have]) < 5e-5
    if "lug_ripple" in eff or "wheel_runout" in eff:
        # falsifiable: ignoring the modulation in a (a = a_b) misses by far more
        base = isim.make(**DENSE)[0]
        _, _, _, ab = body_kinematics(base)
        off = np.abs(s - law(M * (ab / 1000.0 + CRR * G), s_K))[have]
        assert np.max(off) > 10 * 5e-5


def test_lug_sliding_steady_slip_and_superlinear_growth():
    s_K = 0.06
    rec, _, truth = isim.make(**DENSE, effects={"lug_sliding": {"s_K": s_K}})
    s_lin0 = 2 * M * CRR * G / (K * NL * LL)
    assert truth["slip_linear"] == pytest.approx(s_lin0, rel=1e-12)
    assert truth["slip"] == pytest.approx(-s_K * math.log(1 - s_lin0 / s_K), rel=1e-12)
    assert truth["slip"] > s_lin0
    t, _, _, a = body_kinematics(rec)
    have, s = measured_slip(rec)
    cruise = have & (t > 1.0) & (t < 2.0)
    assert np.max(np.abs(s[cruise] - truth["slip"])) < 1e-5
    # accelerating: slip above the linear law by more than at steady speed (and less below)
    F = M * (a / 1000.0 + CRR * G)
    acc = have & (a > 200)
    dec = have & (a < -200)
    assert acc.any() and dec.any()
    assert np.all(s[acc] / law(F[acc]) > truth["slip"] / s_lin0 + 0.1)
    assert np.all(s[dec] / law(F[dec]) < truth["slip"] / s_lin0)


# ---------------------------------------------------------------- path effects

def test_body_bounce_moves_body_y_at_lug_passing_phase():
    A, B, phi = 0.05, 0.001, 0.3
    base = isim.make(**DENSE)[0]
    rec, _, _, series = isim.make_detailed(
        **DENSE, effects={"body_bounce": {"bounce_A": A, "bounce_B": B, "bounce_phi": phi}})
    xb, yb, _ = grid(base)
    x, y, _ = grid(rec)
    assert np.array_equal(x, xb)  # x untouched
    lugs = [i for i, r in enumerate(rec.roles) if r == "lug"]
    assert np.array_equal(y[lugs], yb[lugs])  # lug markers untouched
    ph = lug_passing_phase(series, phi)
    for j, (cx, cy) in enumerate(BODY):
        i = rec.markers.index(f"C{j}")
        assert np.allclose(y[i] - cy, (A + B * cx) * np.sin(ph), atol=1e-12, rtol=0)
    # pitch: the two body markers bounce with different amplitudes
    c0, c1 = rec.markers.index("C0"), rec.markers.index("C1")
    assert np.ptp(y[c0] - BODY[0][1]) < np.ptp(y[c1] - BODY[1][1])


def _relative(rec, series):
    """Lug-marker x relative to the middle of the bottom run, and y."""
    x, y, _ = grid(rec)
    lugs = [i for i, r in enumerate(rec.roles) if r == "lug"]
    return x[lugs] - series["X"] - XOFF, y[lugs]


def test_belt_sag_dips_top_run_by_d_at_mid_span():
    d = 0.8
    kw = dict(FAST, fps=200.0, n_lug=20)
    base, _, _, sb = isim.make_detailed(**kw)
    rec, _, _, series = isim.make_detailed(**kw, effects={"belt_sag": {"sag_d": d}})
    rel, y = _relative(rec, series)
    _, y0 = _relative(base, sb)
    D = series["D"]
    top = (y0 > YOFF + R) & (np.abs(rel) < D / 2)
    xi = (rel[top] + D / 2) / D  # ξ from the rear wheel forward: the top run's direction
    assert np.allclose(y[top], YOFF + 2 * R + E - 4 * d * xi * (1 - xi), atol=1e-9)
    mid = np.abs(xi - 0.5) < 0.02
    assert mid.sum() > 10 and np.allclose(y[top][mid], YOFF + 2 * R + E - d, atol=0.01 * d)
    assert np.array_equal(y[~top], y0[~top])  # nothing else moves


def test_ground_sinkage_lowers_bottom_run_with_time_in_contact():
    z, us = 0.5, 30.0
    kw = dict(FAST, fps=200.0, n_lug=20)
    base, _, _, sb = isim.make_detailed(**kw)
    rec, _, _, series = isim.make_detailed(
        **kw, effects={"ground_sinkage": {"sink_z": z, "sink_us": us}})
    rel, y = _relative(rec, series)
    _, y0 = _relative(base, sb)
    D = series["D"]
    bot = (y0 < YOFF + R) & (np.abs(rel) < D / 2) & (np.abs(y0 - (YOFF - E)) < 1e-12)
    u = D / 2 - rel[bot]  # counted from the run's start, the front end
    assert np.allclose(y[bot], YOFF - E - z * (1 - np.exp(-u / us)), atol=1e-9)
    assert np.all(y[bot] <= YOFF - E)
    assert np.min(y[bot]) < YOFF - E - 0.9 * z * (1 - math.exp(-D / us))
    assert np.array_equal(y[~bot], y0[~bot])  # wheels and top run untouched: a step at the rear


# ---------------------------------------------------------------- image effects

def _pair(eff, **kw):
    kw = dict(FAST, fps=100.0, n_lug=6, **kw)
    return grid(isim.make(**kw)[0]), grid(isim.make(**kw, effects=eff)[0])


def test_camera_tilt_body_y_linear_in_x_with_slope_tan_theta():
    th = 0.004
    (xb, yb, _), (x, y, _) = _pair({"camera_tilt": {"tilt_theta": th}})
    for j in range(len(BODY)):
        i = 6 + j
        slope, icpt = np.polyfit(x[i], y[i], 1)
        assert slope == pytest.approx(math.tan(th), rel=1e-9)
        assert np.max(np.abs(y[i] - (slope * x[i] + icpt))) < 1e-9
        assert icpt == pytest.approx(BODY[j][1] / math.cos(th), rel=1e-12)
    # counter-clockwise about the origin, for every point
    c, s = math.cos(th), math.sin(th)
    assert np.allclose(x, c * xb - s * yb, atol=1e-10) and np.allclose(y, s * xb + c * yb,
                                                                        atol=1e-10)


def test_lens_distortion_is_radial_cubic_about_the_centre():
    k1, c = 2e-7, np.array([150.0, 40.0])
    (xb, yb, _), (x, y, _) = _pair({"lens_distortion": {"lens_k1": k1, "lens_cx": c[0],
                                                        "lens_cy": c[1]}})
    dxb, dyb, dx, dy = xb - c[0], yb - c[1], x - c[0], y - c[1]
    r = np.hypot(dxb, dyb)
    assert np.allclose(dxb * dy - dyb * dx, 0, atol=1e-8)  # radial
    assert np.allclose(np.hypot(dx, dy), r * (1 + k1 * r**2), atol=1e-10)
    # the straight bottom run bows: its y now varies with x
    lug_y_bottom = y[:6][np.abs(yb[:6] - (YOFF - E)) < 1e-12]
    assert np.ptp(lug_y_bottom) > 1e-3


def test_marker_depth_scales_lug_markers_only():
    eps, c = 0.02, (100.0, 20.0)
    kw = dict(n_lug=20, fps=1000.0)
    base = isim.make(**dict(DENSE, **kw))[0]
    rec = isim.make(**dict(DENSE, **kw), effects={"marker_depth": {
        "depth_eps": eps, "depth_cx": c[0], "depth_cy": c[1]}})[0]
    xb, yb, t = grid(base)
    x, y, _ = grid(rec)
    assert np.array_equal(x[20:], xb[20:]) and np.array_equal(y[20:], yb[20:])
    assert np.allclose(x[:20], c[0] + (1 + eps) * (xb[:20] - c[0]), atol=1e-10)
    assert np.allclose(y[:20], c[1] + (1 + eps) * (yb[:20] - c[1]), atol=1e-10)
    # signature: mean of top-run and bottom-run lug speeds is (1+ε) × the body speed
    h = t[1] - t[0]
    cruise = (t > 1.0) & (t < 2.0)
    vbody = np.gradient(x[20], h)[cruise].mean()
    ylev = c[1] + (1 + eps) * (np.array([YOFF - E, YOFF + 2 * R + E]) - c[1])
    speeds = []
    for lev in ylev:
        vs = []
        for i in range(20):
            on = np.abs(y[i] - lev) < 1e-9
            ok = on[:-2] & on[1:-1] & on[2:] & cruise[1:-1]
            vs.append(((x[i, 2:] - x[i, :-2]) / (2 * h))[ok])
        speeds.append(np.concatenate(vs).mean())
    assert (speeds[0] + speeds[1]) / 2 / vbody == pytest.approx(1 + eps, abs=1e-6)


def test_image_effects_compose_in_the_order_the_light_takes():
    eff = {"lens_distortion": {"lens_k1": 3e-7, "lens_cx": 50.0, "lens_cy": 20.0},
           "camera_tilt": {"tilt_theta": 0.01},
           "marker_depth": {"depth_eps": 0.03, "depth_cx": -40.0, "depth_cy": 10.0}}
    (xb, yb, _), (x, y, _) = _pair(eff)

    def depth(qx, qy):
        return -40.0 + 1.03 * (qx + 40.0), 10.0 + 1.03 * (qy - 10.0)

    def tilt(qx, qy):
        c, s = math.cos(0.01), math.sin(0.01)
        return c * qx - s * qy, s * qx + c * qy

    def lens(qx, qy):
        dx, dy = qx - 50.0, qy - 20.0
        f = 1 + 3e-7 * (dx * dx + dy * dy)
        return 50.0 + dx * f, 20.0 + dy * f

    lug = np.arange(len(xb)) < 6
    qx, qy = xb.copy(), yb.copy()
    qx[lug], qy[lug] = depth(qx[lug], qy[lug])
    qx, qy = lens(*tilt(qx, qy))
    assert np.allclose(x, qx, atol=1e-9) and np.allclose(y, qy, atol=1e-9)
    # falsifiable: the reverse order is measurably different
    rx, ry = tilt(*lens(xb, yb))
    rx[lug], ry[lug] = depth(rx[lug], ry[lug])
    assert np.max(np.hypot(x - rx, y - ry)) > 1e-3


# ---------------------------------------------------------------- frame drop

@pytest.mark.parametrize("dt_frames", [1.0, 0.5])
def test_frame_drop_jumps_by_v_dt_at_t_star(dt_frames):
    fps = 100.0
    dt, k_star = dt_frames / fps, 150  # t* = 1.5 s, in the cruise
    kw = dict(FAST, fps=fps, n_lug=6)
    base = isim.make(**kw)[0]
    rec, _, truth = isim.make(**kw, effects={"frame_drop": {"drop_dt": dt,
                                                            "drop_tstar": k_star / fps}})
    assert np.array_equal(rec.t, base.t) and len(rec.x) == len(base.x)  # every row kept
    xb, yb, t = grid(base)
    x, y, _ = grid(rec)
    assert np.array_equal(x[:, :k_star], xb[:, :k_star])
    body = 6
    jump = (x[body, k_star] - x[body, k_star - 1]) - (xb[body, k_star] - xb[body, k_star - 1])
    assert jump == pytest.approx(120.0 * dt, rel=1e-3)
    # every marker jumps at t* (lugs by v·Δt plus their path motion)
    assert np.all(np.hypot(x[:, k_star] - xb[:, k_star], y[:, k_star] - yb[:, k_star])
                  > 0.5 * 120.0 * dt)
    if dt_frames == 1.0:  # positions at stamp t ≥ t* are the base's at the next frame
        assert np.allclose(x[:, k_star:-1], xb[:, k_star + 1:], atol=1e-9)
        assert np.allclose(y[:, k_star:-1], yb[:, k_star + 1:], atol=1e-9)
