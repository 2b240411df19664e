"""Stepping the engine: settle, drive the motor's profile, probe the state at 1 kHz."""

from __future__ import annotations

import math
import time

import numpy as np

from ._case import EngineCase
from ._mjcf import build_mjcf

PROBE_HZ = 1000.0
_V_COULOMB = 0.005  # m/s: the speed over which the resistances' tanh reaches full force


def run_case(case: EngineCase) -> dict:
    """Simulate `case`; return the probes (SI units, recording time from the settled start).

    Keys: t (s), X, Z, pitch (chassis), vX, pins (T, N, 2), tips, bases (T, lugs, 2),
    shear, shear_v, press (T, lugs), in_contact, fn, ft (T, lugs), omega (drive wheel),
    torque, idler, resist (the rolling resistance and drawbar force on the chassis, N),
    wall_s, and the model's masses.
    """
    import mujoco

    xml, geom0 = build_mjcf(case)
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    dt = case.timestep_s
    probe_every = round(1.0 / (PROBE_HZ * dt))
    if abs(probe_every * dt * PROBE_HZ - 1) > 1e-9:
        raise ValueError(f"{case.name}: the time step does not divide 1 ms")
    if abs(PROBE_HZ / case.fps - round(PROBE_HZ / case.fps)) > 1e-9:
        raise ValueError(f"{case.name}: fps must divide {PROBE_HZ:g}")
    jadr = {n: model.joint(n).qposadr[0] for n in ("X", "Z", "pitch", "tensioner", "drive")}
    vadr = {n: model.joint(n).dofadr[0] for n in ("X", "tensioner", "drive")}
    nl = case.n_lugs
    shear_q = np.array([model.joint(f"shear{j}").qposadr[0] for j in range(nl)])
    shear_v = np.array([model.joint(f"shear{j}").dofadr[0] for j in range(nl)])
    press_q = np.array([model.joint(f"press{j}").qposadr[0] for j in range(nl)])
    press_v = np.array([model.joint(f"press{j}").dofadr[0] for j in range(nl)])
    pin_site = np.array([model.site(f"pin{i}").id for i in range(case.n_links)])
    tip_site = np.array([model.site(f"tip{j}").id for j in range(nl)])
    base_site = np.array([model.site(f"base{j}").id for j in range(nl)])
    tip_geom = {model.geom(f"tip{j}").id: j for j in range(nl)}
    ground = model.geom("ground").id
    chassis = model.body("chassis").id
    mass_total = float(model.body_subtreemass[0])
    weight = mass_total * 9.81
    f6 = np.zeros(6)

    def resist(v):
        return -(case.c_rr * weight + case.drawbar_pull_N) * math.tanh(v / _V_COULOMB)

    n_settle = round(case.settle_s / dt)
    n_run = round(case.duration_s / dt)
    T = n_run // probe_every + 1
    out = {k: np.zeros(T) for k in ("t", "X", "Z", "pitch", "vX", "omega", "torque", "idler",
                                    "resist")}
    out.update(pins=np.zeros((T, case.n_links, 2)), tips=np.zeros((T, nl, 2)),
               bases=np.zeros((T, nl, 2)))
    for k in ("shear", "shear_v", "press", "press_v", "fn", "ft", "fx"):
        out[k] = np.zeros((T, nl))
    out["in_contact"] = np.zeros((T, nl), bool)
    wall = time.perf_counter()
    for i in range(n_settle + n_run + 1):
        t_rec = (i - n_settle) * dt
        data.qfrc_applied[vadr["tensioner"]] = -case.tension_N * min(1.0, i / (0.5 * n_settle))
        data.ctrl[0] = case.motor_omega(t_rec) if t_rec > 0 else 0.0
        fx = resist(data.qvel[vadr["X"]]) if t_rec > 0 else 0.0
        data.xfrc_applied[chassis, 0] = fx
        if i >= n_settle and (i - n_settle) % probe_every == 0:
            r = (i - n_settle) // probe_every
            out["t"][r] = t_rec
            out["X"][r], out["Z"][r] = data.qpos[jadr["X"]], data.qpos[jadr["Z"]]
            out["pitch"][r] = data.qpos[jadr["pitch"]]
            out["vX"][r] = data.qvel[vadr["X"]]
            out["omega"][r] = data.qvel[vadr["drive"]]
            out["torque"][r] = data.actuator_force[0]
            out["idler"][r] = data.qpos[jadr["tensioner"]]
            out["resist"][r] = fx
            out["pins"][r] = data.site_xpos[pin_site][:, [0, 2]]
            out["tips"][r] = data.site_xpos[tip_site][:, [0, 2]]
            out["bases"][r] = data.site_xpos[base_site][:, [0, 2]]
            out["shear"][r] = data.qpos[shear_q]
            out["shear_v"][r] = data.qvel[shear_v]
            out["press"][r] = data.qpos[press_q]
            out["press_v"][r] = data.qvel[press_v]
            for c in range(data.ncon):
                con = data.contact[c]
                g1, g2 = con.geom1, con.geom2
                if ground not in (g1, g2):
                    continue
                j = tip_geom.get(g2 if g1 == ground else g1)
                if j is None:
                    continue
                mujoco.mj_contactForce(model, data, c, f6)
                out["in_contact"][r, j] = True
                out["fn"][r, j] += f6[0]
                out["ft"][r, j] += math.hypot(f6[1], f6[2])
                # the ground's force on the tip in the world frame (frame rows: normal first)
                fr = con.frame.reshape(3, 3)
                sgn = 1.0 if g1 == ground else -1.0  # the force acts on geom2 from geom1
                out["fx"][r, j] += sgn * float(fr[:, 0] @ f6[:3])
        mujoco.mj_step(model, data)
    out["wall_s"] = time.perf_counter() - wall
    out["mass_total_kg"] = mass_total
    out["geometry0"] = {k: v for k, v in geom0.items() if k != "pins"}
    out["chassis_x0"] = float(model.body_pos[chassis][0])
    out["chassis_z0"] = float(model.body_pos[chassis][2])
    return out
