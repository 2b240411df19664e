"""The ladder's effects and sizes, shared by bench_explain.py and bench_ladder.py (no fitlug
import here: bench_ladder runs the same table in other source trees' processes)."""

from __future__ import annotations

import math


def _mod(eps, phi, prefix):
    return {f"{prefix}_a": eps * math.cos(phi), f"{prefix}_b": eps * math.sin(phi)}


# effect -> (function size -> effect params, rough detection threshold of the size)
LADDER = {
    "lug_ripple": (lambda a: {"lug_ripple": _mod(a, 0.7, "ripple")}, 3e-4),
    "wheel_runout": (lambda a: {"wheel_runout": _mod(a, -0.4, "runout")}, 5e-5),
    "body_bounce": (lambda a: {"body_bounce": {"bounce_A": a, "bounce_B": 0.0,
                                               "bounce_phi": 0.3}}, 1.5e-3),
    "lug_sliding": (lambda a: {"lug_sliding": {"slide_mu": a}}, 0.3),
    "belt_sag": (lambda a: {"belt_sag": {"sag_d": a}}, 3e-3),
    "ground_sinkage": (lambda a: {"ground_sinkage": {"sink_z": a, "sink_us": 30.0}}, 3e-3),
    "lens_distortion": (lambda a: {"lens_distortion": {"lens_k1": a, "lens_cx": 300.0,
                                                       "lens_cy": 40.0}}, 5e-11),
    "marker_depth": (lambda a: {"marker_depth": {"depth_eps": a}}, 5e-6),
    "camera_tilt": (lambda a: {"camera_tilt": {"tilt_theta": a}}, 2e-6),
    "frame_drop": (lambda a: {"frame_drop": {"drop_dt": a, "drop_tstar": 3.27}}, 8e-5),
}
