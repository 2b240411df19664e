"""Session 35's engine variants (fitlug.sim.engine, MuJoCo; seed 11; none committed):
forty settings nobody had run, each an adversarial combination a user could build.

    python make_variants.py OUT [NAME ...]    # simulate into OUT/<name>/ (skips those done)
    python make_variants.py --list
"""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
from _variants import RUB, R, main  # noqa: E402 - benchmarks/_variants.py

from fitlug.sim.engine._case import EngineCase  # noqa: E402

V = [
    # rubber belts
    EngineCase(name="rub_wheel30", **R, **RUB, wheel_radius_mm=30.0),
    EngineCase(name="rub_fast250", **R, **RUB, v_belt_mm_s=250.0),
    EngineCase(name="rub_mu02", **R, **RUB, mu=0.2),
    EngineCase(name="rub_stiffbend", fps=100.0, **dict(RUB, bend_Nm_per_rad=0.5), k_N_per_mm=0.5),
    EngineCase(name="rub_links_h1", **R, **RUB, marker_h=1.0),
    # chains of other geometries
    EngineCase(name="p20_w30_n20", **R, n_links=20, link_pitch_mm=20.0, wheel_radius_mm=30.0),
    EngineCase(name="p10_w22_n40", **R, n_links=40, link_pitch_mm=10.0, wheel_radius_mm=22.0),
    EngineCase(name="p30_w28_n14", **R, n_links=14, link_pitch_mm=30.0, wheel_radius_mm=28.0),
    EngineCase(name="p14_every2", **R, n_links=30, link_pitch_mm=14.0, lug_every=2),
    # lugs
    EngineCase(name="k015_heavy15", k_N_per_mm=0.15, fps=100.0, chassis_mass_kg=15.0),
    EngineCase(name="k1_light3", k_N_per_mm=1.0, fps=100.0, chassis_mass_kg=3.0),
    EngineCase(name="tau001", **R, tau_s=0.01),
    EngineCase(name="tau05", **R, tau_s=0.5),
    EngineCase(name="lug10mm", **R, lug_height_mm=10.0),
    EngineCase(name="lug3mm", **R, lug_height_mm=3.0),
    EngineCase(name="knormal4", **R, k_normal_N_per_mm=4.0),
    # loads and friction
    EngineCase(name="drawbar8_k03", k_N_per_mm=0.3, fps=100.0, drawbar_pull_N=8.0),
    EngineCase(name="crr02", **R, c_rr=0.2),
    EngineCase(name="crr003", **R, c_rr=0.03),
    EngineCase(name="mu04_drawbar5", **R, mu=0.4, drawbar_pull_N=5.0),
    EngineCase(name="mu02_heavy15", **R, mu=0.2, chassis_mass_kg=15.0),
    EngineCase(name="mu_wheel05", **R, mu_wheel=0.5),
    EngineCase(name="tension25", **R, tension_N=25.0),
    EngineCase(name="tension150", **R, tension_N=150.0),
    # markers
    EngineCase(name="h07_three", **R, marker_h=0.7, lug_markers=(0, 1, 2)),
    EngineCase(name="h1_spread3", k_N_per_mm=0.25, fps=100.0, marker_h=1.0,
               lug_markers=(0, 7, 14)),
    EngineCase(name="one_marker", **R, lug_markers=(0,)),
    EngineCase(name="eight_tips", **R, lug_markers=tuple(range(8))),
    EngineCase(name="body_wide", **R, body_markers=((-150.0, 120.0), (150.0, 120.0))),
    EngineCase(name="noisy3_h04", **R, marker_h=0.4, noise_lug_mm=0.02, noise_body_mm=0.012),
    # cameras, speeds, windows
    EngineCase(name="fps25", k_N_per_mm=0.25, fps=25.0),
    EngineCase(name="fps500", k_N_per_mm=0.25, fps=500.0, cruise_s=2.0),
    EngineCase(name="fps200_v250", k_N_per_mm=0.25, fps=200.0, v_belt_mm_s=250.0),
    EngineCase(name="v100_cruise6", **R, v_belt_mm_s=100.0, cruise_s=6.0),
    EngineCase(name="v400", **R, v_belt_mm_s=400.0, cruise_s=2.0),
    EngineCase(name="cruise12", **R, cruise_s=1.2),
    EngineCase(name="ramp02", **R, ramp_s=0.2, cruise_s=2.0),
    EngineCase(name="window300", **R, camera_window_mm=(50.0, 350.0)),
    EngineCase(name="window_late", **R, camera_window_mm=(300.0, 650.0)),
    # the same physics at two frame rates (issue 41 item 3)
    EngineCase(name="heavy20_250fps", k_N_per_mm=0.25, fps=250.0, chassis_mass_kg=20.0),
    EngineCase(name="p14_n30_250fps", k_N_per_mm=0.25, fps=250.0, n_links=30,
               link_pitch_mm=14.0),
]

if __name__ == "__main__":
    sys.exit(main(V, seed=11))
