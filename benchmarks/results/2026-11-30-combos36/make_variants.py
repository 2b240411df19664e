"""Session 36's engine variants (fitlug.sim.engine, MuJoCo; seed 13): twenty-nine settings
nobody had run, each combining two or three stressors a user could build or film at once
(the single-knob variants of sessions 34-35 passed one at a time). One more, 16 or 20
links of 20-24 mm with a lug on every other, tipped over in the engine. Run as
benchmarks/_variants.py says: `python make_variants.py OUT [NAME ...]`.
"""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
from _variants import RUB, R, main  # noqa: E402 - benchmarks/_variants.py

from fitlug.sim.engine._case import EngineCase  # noqa: E402

V = [
    # a camera window with something else
    EngineCase(name="win_links250", k_N_per_mm=0.25, fps=250.0, marker_h=1.0,
               camera_window_mm=(150.0, 500.0)),
    EngineCase(name="win_heavy_drawbar", **R, chassis_mass_kg=15.0, drawbar_pull_N=5.0,
               camera_window_mm=(100.0, 450.0)),
    EngineCase(name="win_rubber", **R, **RUB, camera_window_mm=(150.0, 500.0)),
    EngineCase(name="win_p24_w32", **R, n_links=18, link_pitch_mm=24.0, wheel_radius_mm=32.0,
               camera_window_mm=(100.0, 450.0)),
    EngineCase(name="win_noisy_two", **R, noise_lug_mm=0.0195, noise_body_mm=0.0123,
               lug_markers=(0, 1), camera_window_mm=(150.0, 500.0)),
    EngineCase(name="win_early", **R, camera_window_mm=(0.0, 250.0)),
    EngineCase(name="win_end", **R, camera_window_mm=(450.0, 800.0)),
    EngineCase(name="win_eight", **R, lug_markers=tuple(range(8)),
               camera_window_mm=(150.0, 450.0)),
    EngineCase(name="win_body1", **R, body_markers=((20.0, 40.0),),
               camera_window_mm=(150.0, 500.0)),
    # friction, loads, lugs together
    EngineCase(name="mu025_drawbar5", **R, mu=0.25, drawbar_pull_N=5.0),
    EngineCase(name="crr03_mu05", **R, c_rr=0.3, mu=0.5),
    EngineCase(name="pushed8", **R, drawbar_pull_N=-8.0),
    EngineCase(name="heavy30_k06", k_N_per_mm=0.6, fps=100.0, chassis_mass_kg=30.0),
    EngineCase(name="tall12_k015", k_N_per_mm=0.15, fps=100.0, lug_height_mm=12.0),
    EngineCase(name="tau03_k015", k_N_per_mm=0.15, fps=100.0, tau_s=0.3),
    EngineCase(name="slack20_heavy", **R, tension_N=20.0, chassis_mass_kg=15.0),
    EngineCase(name="wheelslip03", **R, mu_wheel=0.3, drawbar_pull_N=3.0),
    # geometry
    EngineCase(name="tight_w15_p10", **R, n_links=40, link_pitch_mm=10.0,
               wheel_radius_mm=15.0),
    EngineCase(name="rub_h05_250", k_N_per_mm=0.25, fps=250.0, **RUB, marker_h=0.5),
    # markers and body
    EngineCase(name="body_high", **R, body_markers=((-60.0, 300.0), (60.0, 300.0))),
    EngineCase(name="body_low", **R, body_markers=((-60.0, -10.0), (60.0, -10.0))),
    EngineCase(name="spread_half", **R, lug_markers=(0, 11)),
    EngineCase(name="h06_spread4", **R, marker_h=0.6, lug_markers=(0, 5, 11, 16)),
    # speeds, rates, timing
    EngineCase(name="fps25_v250", k_N_per_mm=0.25, fps=25.0, v_belt_mm_s=250.0),
    EngineCase(name="v300_250fps_heavy", k_N_per_mm=0.25, fps=250.0, v_belt_mm_s=300.0,
               chassis_mass_kg=15.0, cruise_s=2.0),
    EngineCase(name="v80_k06_long", k_N_per_mm=0.6, fps=100.0, v_belt_mm_s=80.0, cruise_s=5.0),
    EngineCase(name="slow_ramp", **R, ramp_s=2.0, cruise_s=1.5),
    EngineCase(name="no_rest", **R, rest_s=0.0, ramp_s=0.3),
    EngineCase(name="long_tail", **R, settle_s=1.5, cruise_s=2.0),
]

if __name__ == "__main__":
    sys.exit(main(V, seed=13))
