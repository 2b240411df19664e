"""What the engine itself measured (truth.json): slip, shear, contacts, body motion, checks.

All from the 1 kHz probes of `run_case` (SI in, mm / N / s out), over the cruise window.
"""

from __future__ import annotations

import math

import numpy as np

from ._case import EngineCase


def body_frame(o: dict, xy: np.ndarray) -> np.ndarray:
    """World points (T, K, 2) in m -> the chassis frame (origin the wheel-centre midpoint,
    x forward along the chassis, z up), mm."""
    ox = o["chassis_x0"] + o["X"]
    oz = o["chassis_z0"] + o["Z"]
    th = o["pitch"]
    dx = xy[..., 0] - ox[:, None]
    dz = xy[..., 1] - oz[:, None]
    c, s = np.cos(th)[:, None], np.sin(th)[:, None]
    return np.stack([dx * c - dz * s, dx * s + dz * c], axis=-1) * 1e3


def belt_travel(case: EngineCase, o: dict) -> np.ndarray:
    """The chain's own travel psi(t), mm, relative to the chassis: the bottom-run pins'
    crossings of the chassis' mid-line (psi = -x_j - j p for the pin j just past it)."""
    rel = body_frame(o, o["pins"])
    p, N = case.link_pitch_mm, case.n_links
    r_mid = o["geometry0"]["r_mid"]
    psi = np.empty(len(o["t"]))
    for r in range(len(psi)):
        x, z = rel[r, :, 0], rel[r, :, 1]
        ok = (z < -0.5 * r_mid) & (x <= 0) & (x > -2 * p)
        j = int(np.flatnonzero(ok)[np.argmax(x[ok])])
        psi[r] = -x[j] - j * p
    return np.unwrap(psi, period=N * p)


def _lug_force_x(case: EngineCase, o: dict) -> np.ndarray:
    """(T, lugs) horizontal force, N, that each lug's shear and compression springs and
    dampers put on its link (forward positive): the traction the lug passes to the belt."""
    pins = o["pins"]
    i = np.arange(case.n_lugs) * case.lug_every
    d = pins[:, (i + 1) % case.n_links] - pins[:, i]
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    ux, uz_x = d[..., 0], -d[..., 1]  # local x and local z's world-x components
    k, kn = case.k_N_per_mm * 1e3, case.k_normal_N_per_mm * 1e3
    f_shear = k * o["shear"] + k * case.tau_s * o["shear_v"]
    f_press = kn * o["press"] + kn * case.press_tau_s * o["press_v"]
    return f_shear * ux + f_press * uz_x


def _wheel_distance(o: dict, win: np.ndarray) -> float:
    """Mean distance between the wheel centres (mm): the straight runs' length."""
    g = o["geometry0"]
    rear = g["rear_x"] - g["front_x"] + g["d_nom"] / 2 + o["idler"][win] * 1e3
    return float(np.mean(g["d_nom"] / 2 - rear))


def _hann_mean(v, w):
    return float(np.sum(v * w) / np.sum(w))


def _episodes(flag: np.ndarray):
    """(start, end) index pairs of runs of True (end exclusive)."""
    d = np.diff(np.concatenate([[0], flag.astype(int), [0]]))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


#: a chassis pitched further than this (rad) has tipped over (a cruise pitches 6-35 mrad)
MAX_PITCH_RAD = 0.2


def measure(case: EngineCase, o: dict) -> dict:
    """The engine's own figures at cruise (see docs/engine.md for each)."""
    t = o["t"]
    t1, t2 = case.cruise_window_s
    tilt = float(np.max(np.abs(o["pitch"])))
    if tilt > MAX_PITCH_RAD:  # e.g. lugs on every other link of the reference chain
        raise RuntimeError(f"{case.name}: the chassis pitched {tilt:.2f} rad: the crawler "
                           "tipped over, it has no cruise and no slip to measure")
    win = (t >= t1) & (t <= t2)
    w = np.hanning(win.sum() + 2)[1:-1]
    psi = belt_travel(case, o)
    X = o["X"] * 1e3
    v_belt = np.gradient(psi, t)
    v_body = np.gradient(X, t)
    vb, vc = _hann_mean(v_belt[win], w), _hann_mean(v_body[win], w)
    # the slip of a brush of stuck lugs answers its load one contact time late (each lug's
    # shear is the slip integrated over its time on the ground), so after the ramp it swings
    # with period T_c = D / v_belt: the cruise slip is taken over whole periods of it, from
    # one period after the ramp (the swing settled) to the cruise's end
    D0 = _wheel_distance(o, win)
    T_c = D0 / vb
    if t2 - t1 >= 2 * T_c:
        t1 = t1 + T_c
        win = (t >= t1) & (t <= t2)
        w = np.hanning(win.sum() + 2)[1:-1]
    k_per = max(1, int((t2 - t1) / T_c))
    per = []
    for q in range(k_per):
        b = t2 - q * T_c
        ia, ib = np.searchsorted(t, b - T_c), np.searchsorted(t, b)
        per.append(1.0 - (X[ib] - X[ia]) / (psi[ib] - psi[ia]))
    ia, ib = np.searchsorted(t, t2 - k_per * T_c), np.searchsorted(t, t2)
    slip = 1.0 - (X[ib] - X[ia]) / (psi[ib] - psi[ia])
    vc, vb = (X[ib] - X[ia]) / (t[ib] - t[ia]), (psi[ib] - psi[ia]) / (t[ib] - t[ia])
    v_wheel = _hann_mean(o["omega"][win], w) * case.r_eff_mm
    slip_wheel = 1.0 - vc / v_wheel
    D = D0
    p_lug = case.lug_pitch_mm
    n_rig = int(round(D / p_lug)) + 1
    L_rig = round(D, 1)
    weight = o["mass_total_kg"] * 9.81
    F = case.c_rr * weight + case.drawbar_pull_N
    k = case.k_N_per_mm
    ic = o["in_contact"]
    count = ic[win].sum(axis=1)
    # lug shear, mm, positive when the tip trails forward of its base (traction)
    shear = -o["shear"] * 1e3
    tips_x = o["tips"][..., 0] * 1e3
    rear = np.where(ic, tips_x, np.inf).argmin(axis=1)
    rear_shear = shear[np.arange(len(t)), rear][win]
    lift, growth, tip_drift, travel, stall, local = [], [], [], [], [], []
    for j in range(case.n_lugs):
        for a, b in _episodes(ic[:, j]):
            if b >= len(t) or not (t1 <= t[a] and t[b - 1] <= t2) or b - a < 50:
                continue
            # the middle of the contact: past the landing (the link still turning flat) and
            # before the lift-off (the link turning up round the rear wheel)
            a2, b2 = a + (b - a) // 5, b - (b - a) // 5
            lift.append(shear[b - 1, j])
            travel.append(psi[b - 1] - psi[a])
            tip_drift.append(tips_x[b2, j] - tips_x[a2, j])
            stall.append(psi[b2] - psi[a2])
            growth.append(np.polyfit(psi[a2:b2], shear[a2:b2, j], 1)[0])
            local.append(1.0 - (X[b2] - X[a2]) / (psi[b2] - psi[a2]))
    lift, travel, stall = np.array(lift), np.array(travel), np.array(stall)
    fn, ft = o["fn"][win], o["ft"][win]
    at_limit = (ft >= 0.97 * case.mu * fn) & ic[win] & (fn > 1e-3)
    traction_shear = np.sum(np.where(ic, k * shear + k * case.tau_s * (-o["shear_v"] * 1e3),
                                     0.0), axis=1)
    traction_springs = np.sum(np.where(ic, _lug_force_x(case, o), 0.0), axis=1)
    traction_ground = o["fx"].sum(axis=1)
    pitch = o["pitch"][win] * 1e3
    heave = o["Z"][win] * 1e3
    vcw = (v_body[win] - vc) * w
    nfft = 8 * len(vcw)  # zero-padded: the peak between the bins
    freqs = np.fft.rfftfreq(nfft, t[1] - t[0])
    spec = np.abs(np.fft.rfft(vcw, nfft))
    f_lug = vb / p_lug
    band = (freqs > 0.8) & (freqs < 0.6 * f_lug)
    surge = float(freqs[band][np.argmax(spec[band])]) if band.any() else None
    smooth = np.convolve(v_belt, np.ones(5) / 5, mode="same")  # 5 ms
    ripple_wheel = np.ptp(smooth[win]) / vb
    return {
        "slip": slip,
        "slip_per_contact_period": per[::-1],
        "slip_window_s": [float(t[ia]), float(t[ib])],
        "contact_period_s": T_c,
        "slip_from_wheel": slip_wheel,
        "v_belt_mm_s": vb, "v_chassis_mm_s": vc, "v_wheel_times_r_eff_mm_s": v_wheel,
        "cruise_window_s": [t1, t2],  # the figures below, but the slip, are over it
        "rig": {"L_mm": L_rig, "n": n_rig, "lug_pitch_mm": p_lug,
                "mass_kg": round(o["mass_total_kg"], 4), "drawbar_pull_N": case.drawbar_pull_N},
        "wheel_distance_mm": D,
        "traction_load_N": F,
        # power: what the motor gives against what the belt delivers (F v_belt: towing
        # F v_chassis plus the slip's loss F s v_belt)
        "power_motor_W": float(np.mean((o["torque"] * o["omega"])[win])),
        "power_traction_W": F * vb * 1e-3,
        "traction_springs_N": float(np.mean(traction_springs[win])),
        "traction_shear_only_N": float(np.mean(traction_shear[win])),
        "traction_ground_N": float(np.mean(traction_ground[win])),
        "k_eff_N_per_mm": 2 * F / (slip * n_rig * L_rig),
        "slip_law_2F_knL": 2 * F / (k * n_rig * L_rig),
        "rear_lug_shear_mm": float(np.mean(rear_shear)),
        "liftoff_shear_mm": float(np.mean(lift)) if len(lift) else None,
        "liftoff_shear_max_mm": float(np.max(lift)) if len(lift) else None,
        "contact_travel_mm": float(np.mean(travel)) if len(travel) else None,
        "slip_from_shear_growth": float(np.mean(growth)) if growth else None,
        "slip_over_the_same_contacts": float(np.mean(local)) if local else None,
        "contact_episodes": len(lift),
        "slip_from_rear_shear_over_L": float(np.mean(lift)) / L_rig if len(lift) else None,
        "tip_drift_in_contact_mm": float(np.mean(tip_drift)) if tip_drift else None,
        "tip_drift_abs_max_mm": float(np.max(np.abs(tip_drift))) if tip_drift else None,
        "pitch_line_stall_in_contact_mm": float(slip * np.mean(stall)) if len(stall) else None,
        "lugs_in_contact": {"mean": float(count.mean()), "min": int(count.min()),
                            "max": int(count.max()),
                            "share": {str(c): float(np.mean(count == c))
                                      for c in range(int(count.min()), int(count.max()) + 1)}},
        "tip_contacts_at_friction_limit": float(at_limit.sum() / max(ic[win].sum(), 1)),
        "body_pitch_pp_mrad": float(np.ptp(pitch)),
        "body_heave_pp_mm": float(np.ptp(heave)),
        "surge_frequency_hz": surge,
        "surge_estimate_hz": math.sqrt(n_rig * k * 1e3 / o["mass_total_kg"]) / (2 * math.pi),
        "lug_passing_hz": f_lug,
        "belt_speed_ripple_pp": float(ripple_wheel),
        "chassis_speed_ripple_pp": float(np.ptp(v_body[win]) / vc),
        "wall_s": o["wall_s"],
    }
