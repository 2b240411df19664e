"""Batch benchmark: recordings per minute fitted one by one (fitlug.fit) against
fitlug.fit_many, side by side in one run, with the peak memory of each.

    python benchmarks/bench_batch.py              # 6 recordings
    python benchmarks/bench_batch.py --n 3        # quicker

The recordings are simulated, of one rig, of different lengths (1.4 to 2.4 s at 100 fps,
so each has its own sample count, grid and number of speed-spline knots: one by one, each
compiles its own solver). Each mode runs in a fresh process with an empty compile cache
(the cold start a new campaign pays), in turn: one by one, then fit_many. Reported: wall
time, recordings per minute, the peak resident memory of the process, and the largest
difference of the slip between the two modes in units of its standard error.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import textwrap

_CHILD = textwrap.dedent("""
    import json, resource, sys, time
    import numpy as np
    import fitlug
    from fitlug.fit import fit_many
    from fitlug.sim import Scenario, rig_of, simulate

    n, mode = int(sys.argv[1]), sys.argv[2]
    recs = []
    for i in range(n):
        d = 1.4 + 1.0 * i / max(n - 1, 1)
        sc = Scenario(duration_s=d, travel_mm=100 * d, rest_s=0.2, ramp_s=0.4)
        recs.append(simulate(sc, 100 + i)[0])
    rig = rig_of(sc)
    t0 = time.perf_counter()
    res = [fitlug.fit(r, rig) for r in recs] if mode == "one" else fit_many(recs, rig)
    wall = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # MiB (Linux: KiB)
    print(json.dumps({"wall_s": wall, "peak_mib": peak,
                      "slip": [r.slip.value for r in res], "std": [r.slip.std for r in res]}))
""")


def run(n: int, mode: str) -> dict:
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, FITLUG_CACHE_DIR=cache)
        out = subprocess.run([sys.executable, "-c", _CHILD, str(n), mode], env=env,
                             capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=6, help="recordings (default 6)")
    a = ap.parse_args(argv)
    rows = {m: run(a.n, m) for m in ("one", "many")}
    print(f"{a.n} recordings of one rig, cold compile cache each")
    print(f"{'mode':<12}{'wall s':>9}{'rec/min':>9}{'peak MiB':>10}")
    for m, label in (("one", "one by one"), ("many", "fit_many")):
        r = rows[m]
        print(f"{label:<12}{r['wall_s']:>9.1f}{60 * a.n / r['wall_s']:>9.2f}{r['peak_mib']:>10.0f}")
    z = max(abs(x - y) / s for x, y, s in zip(rows["one"]["slip"], rows["many"]["slip"],
                                               rows["one"]["std"]))
    print(f"speed-up x{rows['one']['wall_s'] / rows['many']['wall_s']:.2f}; "
          f"largest slip difference {z:.3f} standard errors")


if __name__ == "__main__":
    main()
