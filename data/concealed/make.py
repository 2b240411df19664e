"""Generate the concealed test recordings: python data/concealed/make.py [--out DIR]

Each recording is simulated from MODEL.md by fitlug.sim with hidden effects, then (for the
two disturbances outside the catalog) post-processed. Folders rec01..rec16 hold
trajectories.csv and rig.toml, which carry no hint of the answer, and truth.json, which
holds it (for the tests only): {"concealed": {"verdict", "effects", "disturbance"}, ...}.

The set: one recording per catalog effect (10), two combinations of two effects, two
clean recordings, and two disturbances outside the catalog:
- a camera vibration: every marker's x oscillates at 3.3 Hz fixed in time (not locked to
  the belt), 0.015 mm;
- a lug marker that shifts on its lug: from t_j on, its belt coordinate sigma_0 is
  0.5 mm larger (it slipped along the lug's side).
Amplitudes are clearly detectable yet realistic (see AMPLITUDES below). Which folder is
which is decided by a seeded shuffle, so the names say nothing.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys

import numpy as np

SEED = 20261121
FPS = 100.0


def _speed_mod(eps, phi, prefix):
    return {f"{prefix}_a": eps * math.cos(phi), f"{prefix}_b": eps * math.sin(phi)}


#: name -> (scenario changes, effects {id: params}, out-of-catalog disturbance or None)
CASES = {
    "lug_ripple": ({}, {"lug_ripple": _speed_mod(0.003, 1.0, "ripple")}, None),
    "body_bounce": ({}, {"body_bounce": {"bounce_A": 0.03, "bounce_B": 1e-4,
                                         "bounce_phi": 0.5}}, None),
    "lug_sliding": ({}, {"lug_sliding": {"slide_mu": 5.0}}, None),
    "belt_sag": ({"ramp": "smoothstep"}, {"belt_sag": {"sag_d": 0.5}}, None),
    "ground_sinkage": ({}, {"ground_sinkage": {"sink_z": 0.3, "sink_us": 30.0}}, None),
    "wheel_runout": ({"ramp": "quintic"}, {"wheel_runout": _speed_mod(0.006, -0.7, "runout")},
                     None),
    "lens_distortion": ({}, {"lens_distortion": {"lens_k1": 2e-8, "lens_cx": 300.0,
                                                 "lens_cy": 40.0}}, None),
    "marker_depth": ({"travel_mm": 650.0}, {"marker_depth": {"depth_eps": 0.005,
                                                            "depth_cx": 120.0,
                                                            "depth_cy": 30.0}}, None),
    "camera_tilt": ({}, {"camera_tilt": {"tilt_theta": 1e-3}}, None),
    "frame_drop": ({}, {"frame_drop": {"drop_dt": 1.0 / FPS, "drop_tstar": 3.27}}, None),
    "ripple+sag": ({}, {"lug_ripple": _speed_mod(0.0025, -2.0, "ripple"),
                        "belt_sag": {"sag_d": 0.4}}, None),
    "sinkage+frame_drop": ({"ramp": "smoothstep"},
                           {"ground_sinkage": {"sink_z": 0.25, "sink_us": 20.0},
                            "frame_drop": {"drop_dt": 1.0 / FPS, "drop_tstar": 2.13}}, None),
    "clean_a": ({}, {}, None),
    "clean_b": ({"ramp": "quintic", "travel_mm": 750.0}, {}, None),
    "vibration": ({}, {}, {"kind": "periodic_x", "frequency_hz": 3.3, "amplitude_mm": 0.015,
                           "phase_rad": 0.4}),
    "marker_shift": ({}, {}, {"kind": "marker_shift", "marker": "B04", "t_jump_s": 2.8,
                              "delta_sigma0_mm": 0.5}),
}


def _marker_shift(sc, rec, dist):
    """Add the displacement of one lug marker whose sigma_0 grows by delta from t_j on."""
    from fitlug.model import predict
    from fitlug.sim._simulate import _truth_layout, truth_params

    k = rec.markers.index(dist["marker"])
    sel = np.flatnonzero(rec.marker_index == k)
    t = rec.t[sel]
    lay, breaks = _truth_layout(sc, t, np.full(len(t), k), t[:1], np.zeros(1, int))
    p = truth_params(sc, lay, breaks)
    x0, y0, _, _ = (np.asarray(a) for a in predict(p, lay))
    p2 = dict(p)
    p2["sigma0"] = p["sigma0"].at[k].add(dist["delta_sigma0_mm"])
    x1, y1, _, _ = (np.asarray(a) for a in predict(p2, lay))
    after = t >= dist["t_jump_s"]
    x, y = rec.x.copy(), rec.y.copy()
    x[sel[after]] += (x1 - x0)[after]
    y[sel[after]] += (y1 - y0)[after]
    return rec.with_(x=x, y=y)


def _vibration(rec, dist):
    x = rec.x + dist["amplitude_mm"] * np.sin(2 * math.pi * dist["frequency_hz"] * rec.t
                                              + dist["phase_rad"])
    return rec.with_(x=x)


def make(out_dir: str) -> dict:
    """Write every recording under out_dir; returns folder -> case name."""
    sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "..", "src"))
    from fitlug.io import write_json, write_rig, write_trajectories
    from fitlug.sim import Scenario, rig_of, simulate

    rng = np.random.default_rng(SEED)
    names = list(CASES)
    order = rng.permutation(len(names))
    folders = {}
    for slot, i in enumerate(order):
        name = names[i]
        changes, effects, dist = CASES[name]
        sc = Scenario(fps=FPS, effects=effects, **changes)
        seed = int(rng.integers(1_000_000))
        rec, truth = simulate(sc, seed)
        if dist and dist["kind"] == "marker_shift":
            rec = _marker_shift(sc, rec, dist)
        elif dist and dist["kind"] == "periodic_x":
            rec = _vibration(rec, dist)
        rec = rec.with_(meta={"fps": f"{FPS:g}", "units": "mm"})
        folder = os.path.join(out_dir, f"rec{slot + 1:02d}")
        os.makedirs(folder, exist_ok=True)
        write_trajectories(os.path.join(folder, "trajectories.csv"), rec)
        write_rig(os.path.join(folder, "rig.toml"), rig_of(sc))
        truth["concealed"] = {
            "case": name,
            "verdict": "none" if not effects and not dist else
                       ("unexplained" if dist else "explained"),
            "effects": sorted(effects),
            "disturbance": dist,
            "scenario_changes": changes,
        }
        write_json(os.path.join(folder, "truth.json"), truth)
        folders[os.path.basename(folder)] = name
    return folders


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=os.path.dirname(os.path.abspath(__file__)))
    args = ap.parse_args(argv)
    folders = make(args.out)
    print(json.dumps({k: folders[k] for k in sorted(folders)}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
