"""The command line of the results folders' make_variants.py scripts: simulate a list of
engine cases (fitlug.sim.engine, MuJoCo) into OUT/<name>/, skipping those already there.

    python make_variants.py OUT [NAME ...]
    python make_variants.py --list
"""
from __future__ import annotations

import os
import sys
import time

#: the reference rig's lugs and camera
R = dict(k_N_per_mm=0.25, fps=100.0)
#: a rubber belt: 88 short links, a lug on every fourth, bending stiffness at the pins
RUB = dict(n_links=88, link_pitch_mm=4.59, lug_every=4, link_mass_g=2.5,
           link_radius_mm=1.0, bend_Nm_per_rad=0.1)


def main(cases, seed: int, argv=None) -> int:
    """Simulate `cases` (EngineCase list) with `seed`; prints each case's engine slip, its
    slip per contact period and the wall seconds, or why the engine gave none."""
    from fitlug.sim.engine import simulate_engine

    argv = sys.argv[1:] if argv is None else argv
    if not argv:
        print(__doc__, file=sys.stderr)
        return 2
    if argv[0] == "--list":
        print(" ".join(c.name for c in cases))
        return 0
    out, names = argv[0], argv[1:]
    for c in cases:
        if names and c.name not in names:
            continue
        if os.path.exists(f"{out}/{c.name}/truth.json"):
            continue
        t = time.time()
        try:
            tr = simulate_engine(c, out_dir=f"{out}/{c.name}", seed=seed)
            print(c.name, round(tr["slip"], 4),
                  [round(float(x), 4) for x in tr["slip_per_contact_period"]],
                  f"{time.time() - t:.0f}s", flush=True)
        except Exception as e:  # noqa: BLE001 - a case the engine cannot run is reported
            print(c.name, "FAILED", repr(e)[:300], flush=True)
    return 0
