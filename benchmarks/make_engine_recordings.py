"""Write the engine's recordings (fitlug.sim.engine, MuJoCo) into data/engine/<case>/.

Each folder: trajectories.csv (DATA.md long form, 4 decimals in mm), rig.toml (L, n, the
lug pitch and the mass as the engine measured them), truth.json (what the engine itself
measured: slip at cruise, lug shear, contacts, body motion, the self-checks, the settings).
Prints per case the engine's slip and the wall time (a case that differs from an earlier
one only in its camera, e.g. ref_250fps or markers_on_links, reuses its simulation).

    python benchmarks/make_engine_recordings.py                 # every case
    python benchmarks/make_engine_recordings.py ref_100fps mu025 --out /tmp/engine
"""

from __future__ import annotations

import argparse
import os
import sys
import time


def main(argv=None) -> int:
    from fitlug.sim.engine import CASES, same_physics, simulate_engine

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cases", nargs="*", help=f"case names (default all: {', '.join(CASES)})")
    ap.add_argument("--out", default=os.path.join("data", "engine"))
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    names = args.cases or list(CASES)
    bad = [n for n in names if n not in CASES]
    if bad:
        ap.error(f"unknown case(s) {', '.join(bad)}; known: {', '.join(CASES)}")
    print(f"{'case':18s} {'slip':>7s} {'per period':>18s} {'k_eff':>6s} {'rear shear':>10s} "
          f"{'lugs':>5s} {'limit':>6s} {'pitch':>6s} {'surge':>6s} {'wall s':>7s}")
    for name in names:
        t0 = time.perf_counter()
        tr = simulate_engine(CASES[name], os.path.join(args.out, name), 
                             seed=args.seed + list(CASES).index(name))
        per = " ".join(f"{p:.4f}" for p in tr["slip_per_contact_period"])
        tr = {k: (float("nan") if v is None else v) for k, v in tr.items()}
        print(f"{name:18s} {tr['slip']:7.4f} {per:>18s} {tr['k_eff_N_per_mm']:6.3f} "
              f"{tr['liftoff_shear_mm']:8.2f}mm {tr['lugs_in_contact']['mean']:5.2f} "
              f"{tr['tip_contacts_at_friction_limit']:6.3f} {tr['body_pitch_pp_mrad']:6.1f} "
              f"{tr['surge_frequency_hz']:6.2f} {time.perf_counter() - t0:7.1f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
