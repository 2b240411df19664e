"""An independent implementation of MODEL.md §2, written straight from the text.

Nothing from fitlug.model or fitlug.sim is used: plain numpy, a closed-form smoothstep
speed profile, brute-force integration on a 10 µs grid and the stadium table as printed.
It is the project's check that the model and fitter implement the contract, not just
agree with their own simulator.
"""

from __future__ import annotations

import math

import numpy as np

from fitlug.io import Recording, Rig

G = 9.81


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


def make(seed=0, *, fps=120.0, duration=5.0, v_max=120.0, t_acc=(0.4, 1.6), t_dec=(3.4, 4.6),
         m=6.0, k=0.3, C_rr=0.08, n=8, L=127.0, R=30.0, pitch=20.0, N=20, e=2.5,
         x_off=3.0, y_off=4.0, n_lug=8, body=((-50.0, 70.0), (45.0, 72.0)),
         noise_lug=0.0065, noise_body=0.0041):
    """A recording (Recording, truth dict) from the contract's equations."""
    P = N * pitch
    D = (P - 2 * math.pi * R) / 2

    def smoothstep(x):
        x = np.clip(x, 0, 1)
        return x * x * (3 - 2 * x)

    def dsmooth(x):
        return np.where((x > 0) & (x < 1), 6 * x * (1 - x), 0.0)

    h = 1e-5
    tt = np.arange(0, duration + h / 2, h)
    xa = (tt - t_acc[0]) / (t_acc[1] - t_acc[0])
    xd = (tt - t_dec[0]) / (t_dec[1] - t_dec[0])
    v = v_max * (smoothstep(xa) - smoothstep(xd))
    a = v_max * (dsmooth(xa) / (t_acc[1] - t_acc[0]) - dsmooth(xd) / (t_dec[1] - t_dec[0]))
    F = m * (a / 1000.0 + C_rr * G)
    s = 2 * F / (k * n * L)
    vt = v / (1 - s)
    X = np.concatenate([[0], np.cumsum((v[1:] + v[:-1]) / 2 * h)])
    psi = np.concatenate([[0], np.cumsum((vt[1:] + vt[:-1]) / 2 * h)])

    t = np.arange(int(round(duration * fps))) / fps
    Xs, psis = np.interp(t, tt, X), np.interp(t, tt, psi)
    rng = np.random.default_rng(seed)
    sigma0 = 11.0 + pitch * np.arange(n_lug)  # consecutive lugs
    xs, ys, mi, ts = [], [], [], []
    for i in range(n_lug):
        px, py = stadium(sigma0[i] + psis, R, D, e)
        xs.append(Xs + x_off + px + rng.normal(0, noise_lug, len(t)))
        ys.append(y_off + py + rng.normal(0, noise_lug, len(t)))
        mi.append(np.full(len(t), i))
        ts.append(t)
    for j, (cx, cy) in enumerate(body):
        xs.append(Xs + cx + rng.normal(0, noise_body, len(t)))
        ys.append(cy + rng.normal(0, noise_body, len(t)))
        mi.append(np.full(len(t), n_lug + j))
        ts.append(t)
    markers = tuple([f"L{i}" for i in range(n_lug)] + [f"C{j}" for j in range(len(body))])
    roles = tuple(["lug"] * n_lug + ["body"] * len(body))
    rec = Recording(markers=markers, roles=roles, t=np.concatenate(ts),
                    marker_index=np.concatenate(mi).astype(np.int64), x=np.concatenate(xs),
                    y=np.concatenate(ys), meta={"fps": str(fps)})
    s0 = 2 * m * C_rr * G / (k * n * L)
    truth = {"slip": s0, "delta_l_mm": s0 * L / (n - 1), "stiffness_N_per_mm": k,
             "rolling_resistance": C_rr, "R_mm": R, "D_mm": D, "e_mm": e, "pitch_mm": pitch}
    rig = Rig(load_bearing_length_mm=L, lugs_in_contact=n, lug_pitch_mm=pitch, mass_kg=m)
    return rec, rig, truth
