"""Regenerate data/reference/: the reference rig's numbers, simulated (seed 2026).

n = 8, L = 127 mm, 100 fps, 6.5 s, 0.7 m of travel, s0 = 0.07716 (the paper's
dl' = 1.4 mm), noise 0.0065 mm (lug) and 0.0041 mm (body), 10 lug and 2 body markers.
Run: python data/make_reference.py
"""

import os

from fitlug.sim import Scenario, write_simulation

if __name__ == "__main__":
    here = os.path.dirname(os.path.abspath(__file__))
    rec, truth = write_simulation(os.path.join(here, "reference"), Scenario(), seed=2026)
    print(f"data/reference: {len(rec.t)} samples, true slip {truth['slip']:.5f}")
