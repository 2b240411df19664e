"""Linear-law recordings of the light track (issue 32 items 1 and 4): a heavy load with
nothing hidden (lug_sliding must not be named), a wheel runout of 4 % and a strong sag
(3 mm): named alone with their parameters covered? Printed, not asserted.

    PYTHONPATH=src python benchmarks/results/2026-11-27-friction32/others.py
"""
import math
import sys
import time

from fitlug.explain import explain
from fitlug.fit import fit
from fitlug.sim import rig_of, simulate
from fitlug.sim._campaign import LIMIT_K, SMALL_BASE

n, L, m, crr = 8, 127.0, 1.5, 0.06
base = SMALL_BASE.replace(duration_s=4.0, fps=60.0, travel_mm=400.0, ramp_s=0.8)
CASES = {
    "linear_s0.30": {},
    "linear_s0.10": {},
    "runout_4pct": {"wheel_runout": {"runout_a": 0.04 * math.cos(-0.4),
                                     "runout_b": 0.04 * math.sin(-0.4)}},
    "runout_3pct": {"wheel_runout": {"runout_a": 0.0, "runout_b": 0.03}},
    "runout_5pct": {"wheel_runout": {"runout_a": -0.05 * math.cos(1.0),
                                     "runout_b": 0.05 * math.sin(1.0)}},
    "sag_3mm": {"belt_sag": {"sag_d": 3.0}},
    "sag_6mm": {"belt_sag": {"sag_d": 6.0}},
}
for name in (sys.argv[1:] or CASES):
    eff = CASES[name]
    s0 = 0.3 if name == "linear_s0.30" else 0.1
    F0 = s0 * LIMIT_K * n * L / 2
    sc = base.replace(mass_kg=m, rolling_resistance=crr, drawbar_pull_N=F0 - m * crr * 9.81,
                      slip=s0, effects=eff)
    rec, tr = simulate(sc, seed=7)
    t0 = time.perf_counter()
    res = fit(rec, rig_of(sc))
    ex = explain(res)
    doc = ex.to_json()
    q = ex.final.quantities
    z = lambda est, want: (est.value - want) / est.std  # noqa: E731
    print(f"{name}: base chi2/dof {res.chi2_per_dof:.2f} -> {ex.verdict} {ex.effects} "
          f"chi2/dof {ex.final.chi2_per_dof:.2f}; z(k) {z(q['stiffness_N_per_mm'], LIMIT_K):.2f} "
          f"z(C_rr) {z(q['rolling_resistance'], crr):.2f} z(slip) {z(q['slip'], tr['slip']):.2f}; "
          f"{time.perf_counter() - t0:.0f} s", flush=True)
    for e in doc["effects"]:
        truth = eff.get(e["id"], {})
        print("   ", e["id"], {k: round(v, 6) for k, v in e["params"].items()
                                if isinstance(v, float)},
              "std", {k: float(f"{v:.3g}") for k, v in (e.get("params_std") or {}).items()
                      if isinstance(v, float)}, "truth", truth, flush=True)
