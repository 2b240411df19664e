"""s0 0.396 (F0/F_max 0.88, ramp to 0.97 F_max) on more noise seeds: verdict, named,
chi2/dof and z of s_K, k, C_rr, slip (bench_explain's limit case; seed 100 is its seed 0).

    PYTHONPATH=src python benchmarks/results/2026-11-27-friction32/seeds040.py 101 102
"""
import math
import sys
import time

from fitlug.explain import explain
from fitlug.fit import fit
from fitlug.sim import rig_of, simulate
from fitlug.sim._campaign import LIMIT_K, SMALL_BASE

n, L, m, crr, F_max, s0 = 8, 127.0, 1.5, 0.06, 5.0, 0.396
s_K = 2 * F_max / (LIMIT_K * n * L)
F0 = F_max * (1 - math.exp(-s0 / s_K))
base = SMALL_BASE.replace(duration_s=4.0, fps=60.0, travel_mm=400.0, ramp_s=0.8)
sc = base.replace(mass_kg=m, rolling_resistance=crr, drawbar_pull_N=F0 - m * crr * 9.81,
                  slip=2 * F0 / (LIMIT_K * n * L), effects={"lug_sliding": {"slide_mu": 1 / s_K}})
for seed in map(int, sys.argv[1:]):
    rec, tr = simulate(sc, seed=seed)
    t0 = time.perf_counter()
    ex = explain(fit(rec, rig_of(sc)))
    q = ex.final.quantities
    doc = ex.to_json()
    zs = [(e["params"]["s_K"] - s_K) / e["params_std"]["s_K"] for e in doc["effects"]
          if e["id"] == "lug_sliding" and e["params_std"]]
    z = lambda est, want: (est.value - want) / est.std  # noqa: E731
    print(f"seed {seed}: {ex.verdict} {ex.effects} chi2/dof {ex.final.chi2_per_dof:.2f} "
          f"z(s_K) {zs[0] if zs else float('nan'):.2f} z(k) {z(q['stiffness_N_per_mm'], LIMIT_K):.2f} "
          f"z(C_rr) {z(q['rolling_resistance'], crr):.2f} z(slip) {z(q['slip'], tr['slip']):.2f} "
          f"{time.perf_counter() - t0:.0f} s", flush=True)
