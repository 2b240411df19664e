"""Session 37's set (fitlug.sim.engine, MuJoCo; seed 19): more fast, surging runs seen
through narrow camera windows, made after the belt clock's error took in the body's own
surge (docs/engine.md, session 37), to look for what is still over-confident: heavier
and softer, a rubber belt, a 300 mm window, markers half way up, a drawbar, 50 fps, 14 mm
links, a late window, slow damping. Run as benchmarks/_variants.py says:
`python make_variants.py OUT [NAME ...]`.
"""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
from _variants import R, RUB, main  # noqa: E402 - benchmarks/_variants.py

from fitlug.sim.engine._case import EngineCase  # noqa: E402

W = (100.0, 500.0)
V = [
    EngineCase(name="v250_win_heavy20_k015", k_N_per_mm=0.15, fps=100.0, v_belt_mm_s=250.0,
               cruise_s=2.0, chassis_mass_kg=20.0, camera_window_mm=W),
    EngineCase(name="rub_v300_win", **R, **RUB, v_belt_mm_s=300.0, cruise_s=2.0,
               camera_window_mm=W),
    EngineCase(name="v300_win300", **R, v_belt_mm_s=300.0, cruise_s=2.0,
               chassis_mass_kg=15.0, camera_window_mm=(150.0, 450.0)),
    EngineCase(name="v350_win_h05", **R, v_belt_mm_s=350.0, cruise_s=2.0, marker_h=0.5,
               camera_window_mm=W),
    EngineCase(name="v300_win_heavy_drawbar8", **R, v_belt_mm_s=300.0, cruise_s=2.0,
               chassis_mass_kg=15.0, drawbar_pull_N=8.0, camera_window_mm=W),
    EngineCase(name="v200_win_k015_heavy15", k_N_per_mm=0.15, fps=100.0, v_belt_mm_s=200.0,
               cruise_s=2.0, chassis_mass_kg=15.0, camera_window_mm=W),
    EngineCase(name="v300_win_50fps", k_N_per_mm=0.25, fps=50.0, v_belt_mm_s=300.0,
               cruise_s=2.0, chassis_mass_kg=15.0, camera_window_mm=W),
    EngineCase(name="v300_win_p14", **R, n_links=30, link_pitch_mm=14.0, v_belt_mm_s=300.0,
               cruise_s=2.0, camera_window_mm=W),
    EngineCase(name="v300_win_late_heavy", **R, v_belt_mm_s=300.0, cruise_s=2.0,
               chassis_mass_kg=15.0, camera_window_mm=(400.0, 800.0)),
    EngineCase(name="v300_win_tau02", **R, v_belt_mm_s=300.0, cruise_s=2.0, tau_s=0.2,
               chassis_mass_kg=15.0, camera_window_mm=W),
]

if __name__ == "__main__":
    sys.exit(main(V, seed=19))
