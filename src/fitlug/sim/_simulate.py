"""Simulated recordings from known parameters: the project's own source of test data."""

from __future__ import annotations

import json
import os

import numpy as np

from ..io import Recording, Rig, write_json, write_rig, write_trajectories
from ..model import CATALOG, make_layout, steady_slip
from ..model._host import predict_host
from ..model._physics import delta_l
from ._profile import speed_profile
from ._scenario import Scenario


def _truth_layout(sc: Scenario, t_lug, i_lug, t_body, j_body):
    t_hi = sc.duration_s + 0.1
    breaks = np.arange(-0.05, t_hi + 1e-9, 0.01)  # dense: follows the profile to < 1e-6 mm
    return make_layout(breaks=breaks, t_lo=-0.05, t_hi=t_hi, fps=sc.fps, lug_t=t_lug,
                       lug_i=i_lug, body_t=t_body, body_j=j_body, n_lug=sc.lug_markers,
                       n_body=len(sc.body_markers), n_belt=sc.n_belt, n_contact=sc.n_contact,
                       L=sc.L_mm, effects=tuple(sc.effects), substeps=4), breaks


def truth_params(sc: Scenario, lay, breaks) -> dict:
    """The model's parameter dict for a scenario (speed spline fitted to the exact profile)."""
    import jax.numpy as jnp

    from ..model._spline import fit_banded

    tt = np.linspace(breaks[0], breaks[-1], 8 * len(breaks))
    v, _ = speed_profile(tt, v_cruise=sc.v_cruise, duration=sc.duration_s, rest=sc.rest_s,
                         ramp=sc.ramp_s, shape=sc.ramp)
    coef = fit_banded(tt, v, breaks)  # = lstsq on the dense design, in linear memory
    p = {
        "v": coef, "s0": sc.slip, "beta": sc.beta, "R": sc.R_mm, "D": sc.D_mm, "e": sc.e_mm,
        "x_off": sc.x_off_mm, "y_off": sc.y_off_mm,
        "sigma0": sc.sigma_start_mm + sc.lug_spacing * sc.pitch * np.arange(sc.lug_markers),
        "cx": np.array([c[0] for c in sc.body_markers], float),
        "cy": np.array([c[1] for c in sc.body_markers], float),
    }
    for eid, vals in sc.effects.items():
        cls = CATALOG[eid]
        unknown = set(vals) - set(cls.defaults)
        if unknown:
            raise ValueError(f"effect {eid}: unknown parameter(s) {sorted(unknown)}; "
                             f"known: {list(cls.defaults)}")
        p.update({k: vals.get(k, d) for k, d in cls.defaults.items()})
    return {k: jnp.asarray(v, float) for k, v in p.items()}


def simulate(sc: Scenario, seed: int = 0) -> tuple[Recording, dict]:
    """Draw one recording of `sc` (noise seeded by `seed`); returns (recording, truth)."""
    sc.check()
    rng = np.random.default_rng(seed)
    frames = np.arange(int(round(sc.duration_s * sc.fps)))
    t = frames / sc.fps
    nl, nb = sc.lug_markers, len(sc.body_markers)
    t_lug, i_lug = np.repeat(t, nl), np.tile(np.arange(nl), len(t))
    t_body, j_body = np.repeat(t, nb), np.tile(np.arange(nb), len(t))
    lay, breaks = _truth_layout(sc, t_lug, i_lug, t_body, j_body)
    p = truth_params(sc, lay, breaks)
    lx, ly, bx, by = (np.asarray(a) for a in predict_host(p, lay))
    lx = lx + rng.normal(0, sc.noise_lug_mm, lx.shape)
    ly = ly + rng.normal(0, sc.noise_lug_mm, ly.shape)
    bx = bx + rng.normal(0, sc.noise_body_mm, bx.shape)
    by = by + rng.normal(0, sc.noise_body_mm, by.shape)

    lug_names = [f"B{i + 1:02d}" for i in range(nl)]
    body_names = [f"C{j + 1}" for j in range(nb)]
    markers = tuple(lug_names + body_names)
    roles = tuple(["lug"] * nl + ["body"] * nb)
    # long form, sorted by marker then time
    order_l = np.lexsort((t_lug, i_lug))
    order_b = np.lexsort((t_body, j_body))
    mi = np.r_[i_lug[order_l], nl + j_body[order_b]]
    rec = Recording(
        markers=markers, roles=roles, t=np.r_[t_lug[order_l], t_body[order_b]],
        marker_index=mi.astype(np.int64), x=np.r_[lx[order_l], bx[order_b]],
        y=np.r_[ly[order_l], by[order_b]],
        sigma=(np.where(mi < nl, sc.noise_lug_mm, sc.noise_body_mm) if sc.write_sigma else None),
        frame=np.r_[np.repeat(frames, nl)[order_l], np.repeat(frames, nb)[order_b]].astype(np.int64),
        meta={"fps": f"{sc.fps:g}", "source": "fitlug simulate", "units": "mm"},
    )
    s_ss = float(steady_slip(p, lay))
    truth = {
        "slip": s_ss,
        "slip_linear_s0": sc.slip,
        "delta_l_mm": float(delta_l(sc.slip, sc.n_contact, sc.L_mm)),
        "stiffness_N_per_mm": sc.stiffness,
        "rolling_resistance": sc.rolling_resistance,
        "beta_per_mm_s2": sc.beta,
        "mass_kg": sc.mass_kg,
        "drawbar_pull_N": sc.drawbar_pull_N,
        "traction_N": sc.traction_N,
        "ground": sc.ground,
        "geometry": {"R_mm": sc.R_mm, "D_mm": sc.D_mm, "e_mm": sc.e_mm,
                     "pitch_mm": sc.pitch, "n_belt": sc.n_belt,
                     "x_off_mm": sc.x_off_mm, "y_off_mm": sc.y_off_mm},
        "sigma0_mm": [float(v) for v in p["sigma0"]],
        "body_offsets_mm": [list(map(float, c)) for c in sc.body_markers],
        "noise_mm": {"body": sc.noise_body_mm, "lug": sc.noise_lug_mm},
        "profile": {"shape": sc.ramp, "v_cruise_mm_s": sc.v_cruise, "duration_s": sc.duration_s,
                    "rest_s": sc.rest_s, "ramp_s": sc.ramp_s, "fps": sc.fps},
        "effects": {eid: {k: float(p[k]) for k in CATALOG[eid].defaults} for eid in sc.effects},
        "seed": seed,
    }
    return rec, truth


def rig_of(sc: Scenario) -> Rig:
    return Rig(load_bearing_length_mm=sc.L_mm, lugs_in_contact=sc.n_contact,
               lug_pitch_mm=sc.lug_pitch_mm, mass_kg=sc.mass_kg, fps=sc.fps,
               drawbar_pull_N=sc.drawbar_pull_N, ground=sc.ground)


def write_simulation(out_dir: str | os.PathLike, sc: Scenario, seed: int = 0, *,
                     truth: bool = True) -> tuple[Recording, dict]:
    """Write trajectories.csv, rig.toml and (unless truth=False) truth.json into out_dir."""
    rec, tr = simulate(sc, seed)
    os.makedirs(out_dir, exist_ok=True)
    write_trajectories(os.path.join(out_dir, "trajectories.csv"), rec)
    write_rig(os.path.join(out_dir, "rig.toml"), rig_of(sc))
    if truth:
        write_json(os.path.join(out_dir, "truth.json"), tr)
    return rec, tr


def scenario_from_json(text: str) -> Scenario:
    """Scenario from a JSON object of its fields (for `fit-lug simulate --scenario`)."""
    d = json.loads(text)
    if "body_markers" in d:
        d["body_markers"] = tuple(tuple(c) for c in d["body_markers"])
    return Scenario(**d)
