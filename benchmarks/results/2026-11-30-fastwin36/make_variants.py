"""Session 36's second set (fitlug.sim.engine, MuJoCo; seed 17): fast, surging runs seen
through 400 mm windows, where the belt clock's window holds about two contact times, too
few for batch means (docs/engine.md, session 36: v400's three windowed views read 5 %
errors at z -2.0 to -0.7). Informational: measured, not acted on this session. Run as
benchmarks/_variants.py says: `python make_variants.py OUT [NAME ...]`.
"""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
from _variants import R, main  # noqa: E402 - benchmarks/_variants.py

from fitlug.sim.engine._case import EngineCase  # noqa: E402

W = (100.0, 500.0)
V = [
    EngineCase(name="v400_win", **R, v_belt_mm_s=400.0, cruise_s=2.0, camera_window_mm=W),
    EngineCase(name="v400_win_late", **R, v_belt_mm_s=400.0, cruise_s=2.0,
               camera_window_mm=(400.0, 800.0)),
    EngineCase(name="v300_win", **R, v_belt_mm_s=300.0, cruise_s=2.0, camera_window_mm=W),
    EngineCase(name="v300_win_heavy", **R, v_belt_mm_s=300.0, cruise_s=2.0,
               chassis_mass_kg=15.0, camera_window_mm=W),
    EngineCase(name="v250_win_k015", k_N_per_mm=0.15, fps=100.0, v_belt_mm_s=250.0,
               cruise_s=2.0, camera_window_mm=W),
    EngineCase(name="v400_win_250fps", k_N_per_mm=0.25, fps=250.0, v_belt_mm_s=400.0,
               cruise_s=2.0, camera_window_mm=W),
    EngineCase(name="v400_win_eight", **R, v_belt_mm_s=400.0, cruise_s=2.0,
               lug_markers=tuple(range(8)), camera_window_mm=W),
    EngineCase(name="v350_win_drawbar", **R, v_belt_mm_s=350.0, cruise_s=2.0,
               drawbar_pull_N=5.0, camera_window_mm=W),
    EngineCase(name="v200_win_heavy20", **R, v_belt_mm_s=200.0, chassis_mass_kg=20.0,
               camera_window_mm=W),
    EngineCase(name="v400_win_mu03", **R, v_belt_mm_s=400.0, cruise_s=2.0, mu=0.3,
               camera_window_mm=W),
]

if __name__ == "__main__":
    sys.exit(main(V, seed=17))
