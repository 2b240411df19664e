"""Campaign benchmark: throughput on Dask workers, resume, and the coverage of k's 95 % band.

    python benchmarks/bench_campaign.py                 # 32 recordings, 1 and 2 workers, n=50
    python benchmarks/bench_campaign.py --quick         # 6 recordings, n=10
    python benchmarks/bench_campaign.py --skip-timing --n 200 --workers 16
    python benchmarks/bench_campaign.py --skip-timing --law janosi_hanamoto --where limit

Timing: a simulated campaign of --recordings short recordings (fitlug.sim SMALL_BASE:
3 s at 50 fps, 5 lug + 1 body markers) fitted with 1 and 2 local Dask workers (fresh output
folders), the recordings per minute of each, their ratio, and the time of a resumed run
(nothing changed). By default each recording is fitted as `--no-explain --no-mcmc` does
(least squares with the law's curvature, lug_sliding, free); --full adds the explanation and
a 10 s posterior per recording.

Coverage: --n campaigns whose per-recording points are drawn from the law
(fitlug.sim.simulate_points: each point's error the size of one short recording's fit),
NOT from simulated recordings (that would take hours); each is fitted by the campaign model
(law choice, flags, emcee) and we count how often the 95 % interval of k holds the truth
(target 90-98 %), of C_rr's and (sliding law) F_max's per ground (each band alone, and
both grounds' bands at once: ~90 % for two grounds), the sd of (estimate - truth)/std, and
how often each recording is flagged wrongly (every recording is drawn from the law); each law twice: the default campaign far from the friction limit, and
fitlug.sim's limit campaign (LIMIT_K, LIMIT_GROUNDS, limit_runs: pulls to ~0.86 F_max at
cruise, ramps to 0.97, two grounds; issue 32). Parallel over campaigns with --workers
processes (spawn).
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import shutil
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "src"))

K = 0.25
GROUNDS = {"concrete": {"C_rr": 0.06, "F_max": 50.0}, "sand": {"C_rr": 0.15, "F_max": 45.0}}


def _coverage_one(args):
    seed, law, n_rec, limit = args
    from fitlug.campaign import fit_points
    from fitlug.sim._campaign import (LIMIT_GROUNDS, LIMIT_K, default_runs, limit_runs,
                                      simulate_points)

    if limit:  # pulls up to ~0.86 F_max at cruise on both grounds (issue 32)
        k, grounds = LIMIT_K, LIMIT_GROUNDS
        runs = limit_runs(n_rec, grounds=grounds, masses=(1.5,))
    else:
        k, grounds = K, GROUNDS
        runs = default_runs(n_rec)
    pts = simulate_points(runs, k=k, grounds=grounds, law=law, seed=seed)
    res = fit_points(pts, seed=seed)
    lo, hi = res.stiffness["ci95"]
    crr = res.rolling_resistance
    c_in = all(crr[g]["ci95"][0] <= grounds[g]["C_rr"] <= crr[g]["ci95"][1] for g in crr)
    fm = res.F_max or {}
    f_in = (all(fm[g]["ci95"][0] <= grounds[g]["F_max"] <= fm[g]["ci95"][1] for g in fm)
            if fm else None)
    each = {f"C_rr[{g}]": (crr[g], grounds[g]["C_rr"]) for g in crr}
    each.update({f"F_max[{g}]": (fm[g], grounds[g]["F_max"]) for g in fm})
    bands = {nm: (e["ci95"][0] <= t <= e["ci95"][1], (e["value"] - t) / e["std"])
             for nm, (e, t) in each.items()}
    return {"k_in": lo <= k <= hi, "crr_in": c_in, "fmax_in": f_in, "law_ok": res.law == law,
            "flagged": len(res.flagged), "n_rec": len(pts),
            "flagged_names": [o.name for o in res.flagged], "bands": bands,
            "z": (res.stiffness["value"] - k) / res.stiffness["std"]}


def coverage(n: int, law: str, n_rec: int, workers: int, limit: bool = False) -> dict:
    jobs = [(1000 + i, law, n_rec, limit) for i in range(n)]
    if workers > 1:
        with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as ex:
            out = list(ex.map(_coverage_one, jobs))
    else:
        out = [_coverage_one(j) for j in jobs]
    import numpy as np

    fin = [o["fmax_in"] for o in out if o["fmax_in"] is not None]
    names = sorted({nm for o in out for nm in o["bands"]})
    each = {nm: (float(np.mean([o["bands"][nm][0] for o in out if nm in o["bands"]])),
                 float(np.std([o["bands"][nm][1] for o in out if nm in o["bands"]])))
            for nm in names}
    flags = {}
    for o in out:
        for nm in o["flagged_names"]:
            flags[nm] = flags.get(nm, 0) + 1
    return {"each": each, "flags_by_recording": flags,
            "campaigns_with_flags": sum(o["flagged"] > 0 for o in out),
            "n": n, "k_coverage": sum(o["k_in"] for o in out) / n,
            "crr_coverage": sum(o["crr_in"] for o in out) / n,
            "fmax_coverage": (sum(fin) / len(fin)) if fin else None,
            "law_named": sum(o["law_ok"] for o in out) / n,
            "false_flags": sum(o["flagged"] for o in out),
            "flag_rate": sum(o["flagged"] for o in out) / sum(o["n_rec"] for o in out),
            "z_sd": float(__import__("numpy").std([o["z"] for o in out]))}


def timing(n_rec: int, worker_counts, full: bool, keep: str | None) -> None:
    from fitlug.campaign import campaign
    from fitlug.sim._campaign import default_runs, simulate_campaign

    root = keep or tempfile.mkdtemp(prefix="bench_campaign_")
    data = os.path.join(root, "data")
    if not os.path.isdir(data):
        t = time.perf_counter()
        simulate_campaign(data, runs=default_runs(n_rec), k=K, grounds=GROUNDS, law="linear")
        print(f"simulated {n_rec} recordings in {time.perf_counter() - t:.1f} s")
    opts = dict(explain=full, mcmc=full, report=False)  # the chain stops on ESS (issue 43)
    rates = {}
    for w in worker_counts:
        out = os.path.join(root, f"fits_w{w}")
        shutil.rmtree(out, ignore_errors=True)
        t = time.perf_counter()
        res = campaign([data], out=out, workers=w, **opts)
        dt = time.perf_counter() - t
        rates[w] = n_rec / dt * 60
        fails = len(res.failed)
        print(f"workers={w}: {dt:.1f} s for {n_rec} recordings = {rates[w]:.2f} recordings/min "
              f"({fails} failed; law {res.law}, k = {res.stiffness['value']:.5f} "
              f"± {res.stiffness['std']:.2g})")
    if len(rates) >= 2:
        a, b = sorted(rates)[:2]
        print(f"scaling ratio {b} vs {a} workers: {rates[b] / rates[a]:.2f}")
    w = worker_counts[0]
    t = time.perf_counter()
    res = campaign([data], out=os.path.join(root, f"fits_w{w}"), workers=w, **opts)
    dt = time.perf_counter() - t
    n_un = sum(r.status == "unchanged" for r in res.recordings)
    print(f"resumed run (workers={w}): {dt:.1f} s, {n_un}/{n_rec} recordings unchanged")
    if not keep:
        shutil.rmtree(root, ignore_errors=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--recordings", type=int, default=32)
    ap.add_argument("--n", type=int, default=50, help="simulated campaigns for the coverage")
    ap.add_argument("--law", choices=("linear", "janosi_hanamoto", "both"), default="both")
    ap.add_argument("--workers", type=int, default=1, help="processes for the coverage part")
    ap.add_argument("--dask-workers", default="1,2", help="worker counts timed (default 1,2)")
    ap.add_argument("--full", action="store_true", help="explain + posterior per recording")
    ap.add_argument("--quick", action="store_true", help="6 recordings, n = 10")
    ap.add_argument("--skip-timing", action="store_true")
    ap.add_argument("--skip-coverage", action="store_true")
    ap.add_argument("--where", default="far,limit",
                    help="coverage campaigns: far (from F_max), limit (to 0.86 F_max), or both")
    ap.add_argument("--keep", help="work folder to keep (and reuse) the simulated recordings")
    a = ap.parse_args()
    if a.quick:
        a.recordings, a.n = 6, 10
    print(f"machine: {os.cpu_count()} CPUs (timings on a shared machine are inflated)")
    if not a.skip_timing:
        timing(a.recordings, [int(w) for w in a.dask_workers.split(",")], a.full, a.keep)
    if not a.skip_coverage:
        laws = ("linear", "janosi_hanamoto") if a.law == "both" else (a.law,)
        for law in laws:
            for limit in [w == "limit" for w in a.where.split(",")]:
                t = time.perf_counter()
                c = coverage(a.n, law, 8, a.workers, limit)
                fm = ("" if c["fmax_coverage"] is None else
                      f"F_max bands {100 * c['fmax_coverage']:.0f} %, ")
                where = "to 0.86 F_max" if limit else "far from F_max"
                print(f"coverage ({law}, {where}, {c['n']} campaigns of 8 simulated points): "
                      f"k 95 % band {100 * c['k_coverage']:.0f} %, C_rr bands "
                      f"{100 * c['crr_coverage']:.0f} %, {fm}law named "
                      f"{100 * c['law_named']:.0f} %, recordings flagged wrongly "
                      f"{c['false_flags']} ({100 * c['flag_rate']:.1f} %), sd of (k - truth)/std "
                      f"{c['z_sd']:.2f}  ({time.perf_counter() - t:.0f} s)")
                print("  each band alone (coverage, sd of z): " + ", ".join(
                    f"{nm} {100 * cv:.0f} % {sd:.2f}" for nm, (cv, sd) in c["each"].items()))
                print(f"  campaigns with a recording flagged: {c['campaigns_with_flags']} of "
                      f"{c['n']}; wrong flags by recording: {c['flags_by_recording'] or 'none'}")


if __name__ == "__main__":
    main()
