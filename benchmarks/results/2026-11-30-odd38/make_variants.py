"""Session 38's set (fitlug.sim.engine, MuJoCo; seed 23): settings of the engine no earlier
set moved, each something a user's rig could have: a slow robot, a slack chain (its top
run sags), a belt slipping on its drive wheel, tall lugs, soft lugs that compress, an
abrupt start, heavy links, body markers far apart at different heights. Run as
benchmarks/_variants.py says: `python make_variants.py OUT [NAME ...]`.
"""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
from _variants import R, RUB, main  # noqa: E402 - benchmarks/_variants.py

from fitlug.sim.engine._case import EngineCase  # noqa: E402

V = [
    EngineCase(name="slow60", **R, v_belt_mm_s=60.0, ramp_s=0.6, cruise_s=3.5),
    EngineCase(name="slack_tension20", **R, tension_N=20.0),
    EngineCase(name="drive_slips_muw04", **R, mu_wheel=0.4, drawbar_pull_N=4.0),
    EngineCase(name="tall_lugs10_k06", fps=100.0, k_N_per_mm=0.6, lug_height_mm=10.0),
    EngineCase(name="soft_press_kn3", **R, k_normal_N_per_mm=3.0),
    EngineCase(name="abrupt_start", **R, ramp_s=0.15, rest_s=0.1, cruise_s=3.0),
    EngineCase(name="heavy_links30g", **R, link_mass_g=30.0, lug_mass_g=10.0),
    EngineCase(name="body_far_apart", **R, body_markers=((-110.0, 80.0), (45.0, 12.0)),
               lug_markers=(0, 5, 11, 16)),
]

if __name__ == "__main__":
    sys.exit(main(V, seed=23))
