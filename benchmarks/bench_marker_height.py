"""The marker on the lug (MODEL.md §2's h and tau): found, fitted, and the slip covered?

Recordings from the independent generator (tests/independent_sim.py, which steps each
lug's shear in time as the text says) with markers at height fraction h of their lugs
(0 tip ... 1 pitch line) and the shear relaxing in tau; each is fitted with the base model
and explained as `fit-lug` does. Per case: the base fit's chi2/dof, the verdict, whether
the marker's place was found (`discrepancy.marker_on_lug`), h and tau against the truth,
the slip's z against the truth and sigma/s, the final chi2/dof and the seconds. h = 1 rows
are the control: nothing may be found there.

Workers are separate Python processes (JAX is never forked).

    python benchmarks/bench_marker_height.py --h 0,0.3,0.7,1 --tau 0.02,0.08 --seeds 1-2
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))


def one(seed: int, h: float, tau: float) -> dict:
    import independent_sim as isim
    from fitlug import explain, fit

    t0 = time.time()
    rec, rig, truth = isim.make(seed, marker_h=h, shear_tau=tau, duration=3.5,
                                t_acc=(0.3, 1.2), t_dec=(2.3, 3.2), fps=100.0)
    base = fit(rec, rig, require_convergence=False)
    ex = explain(base)
    s = ex.final.quantities["slip"]
    found = [st.effect for st in ex.base_steps]
    out = {"seed": seed, "h": h, "tau": tau, "base_chi2_per_dof": float(base.chi2_per_dof),
           "verdict": ex.verdict, "effects": list(ex.effects), "found": found,
           "chi2_per_dof": float(ex.final.chi2_per_dof), "slip": s.value,
           "z": (s.value - truth["slip"]) / s.std, "rel_std": s.std / truth["slip"],
           "seconds": time.time() - t0}
    if found:
        p = ex.final.effect_params("lug_shear")
        sd = ex.final.effect_params_std("lug_shear")
        out.update({"h_fit": p["h"], "h_std": sd.get("h"), "tau_fit": p["tau_s"],
                    "tau_std": sd.get("tau_s")})
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--h", default="0,0.3,0.7,1")
    ap.add_argument("--tau", default="0.02,0.08")
    ap.add_argument("--seeds", default="1-2")
    ap.add_argument("--one", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.one:
        seed, h, tau = a.one.split(":")
        print(json.dumps(one(int(seed), float(h), float(tau))))
        return 0
    lo, _, hi = a.seeds.partition("-")
    seeds = range(int(lo), int(hi or lo) + 1)
    rows = []
    for h in (float(v) for v in a.h.split(",")):
        for tau in (float(v) for v in a.tau.split(",")):
            for seed in seeds:
                p = subprocess.run([sys.executable, __file__, "--one", f"{seed}:{h}:{tau}"],
                                   capture_output=True, text=True)
                if p.returncode:
                    print(f"h {h} tau {tau} seed {seed}: FAILED {p.stderr.strip()[-300:]}")
                    continue
                r = json.loads(p.stdout.strip().splitlines()[-1])
                rows.append(r)
                hf = (f"h {r['h_fit']:+.3f}±{r['h_std']:.3f} tau {1000 * r['tau_fit']:.1f}"
                      f"±{1000 * (r['tau_std'] or 0):.1f} ms") if r["found"] else "not found"
                print(f"h {h:.2f} tau {1000 * tau:3.0f} ms seed {seed}: base chi2/dof "
                      f"{r['base_chi2_per_dof']:9.2f} -> {r['chi2_per_dof']:.3f}, "
                      f"{r['verdict']:11s} {hf:34s} slip z {r['z']:+.2f} sigma/s "
                      f"{r['rel_std']:.1e} ({r['seconds']:.0f} s)", flush=True)
    ctrl = [r for r in rows if r["h"] == 1.0]
    shear = [r for r in rows if r["h"] != 1.0]
    print(f"\nh < 1: found {sum(bool(r['found']) for r in shear)}/{len(shear)}, verdict none "
          f"{sum(r['verdict'] == 'none' for r in shear)}/{len(shear)}, |z| <= 3 "
          f"{sum(abs(r['z']) <= 3 for r in shear)}/{len(shear)}")
    print(f"h = 1 (control): found {sum(bool(r['found']) for r in ctrl)}/{len(ctrl)}, "
          f"|z| <= 3 {sum(abs(r['z']) <= 3 for r in ctrl)}/{len(ctrl)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
