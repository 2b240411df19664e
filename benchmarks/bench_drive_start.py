"""The base fit on drawn drive-throughs of a plain robot: does it converge, to the noise,
with the slip covered?

Each seed draws a rig and a motion (tests/mechanisms.py's `null`: no effect, no
mechanism) and films it through a window (tests/realism.py's `drive_through`: misses,
occlusions, glitches, ids split after gaps). `--window` picks the drawn window's width:
`default` (mechanisms.make's 300-637 mm, a speed change in view) or `narrow` (150-300 mm,
edge losses up to 15 mm, any phase of the motion in view). What is varied is what a user
films - where the window sits, what is in view when (lugs long before or after the body,
the robot at rest at the picture's edge, one marker the last thing in view), the rate, the
rig - not what the code is known to handle.

Prints one line per recording and a summary: fits that failed or stopped short,
chi2/dof > 1.1, |z| > 3 of the slip against the truth. Workers are separate Python
processes (JAX is never forked).

    python benchmarks/bench_drive_start.py --seeds 1020-1079 --workers 2 --log nulls.jsonl
    python benchmarks/bench_drive_start.py --window narrow --seeds 2000-2029
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))


def one(seed: int, window: str) -> dict:
    import numpy as np

    import mechanisms as M
    import realism
    from fitlug.fit import fit

    t0 = time.time()
    try:
        if window == "default":
            rec, rig, truth = M.make("null", seed)
            win = truth["window"]
        else:
            rec, rig, truth = M.make("null", seed, faults=False)
            rec, info = realism.drive_through(rec, seed=seed + 777, window_mm=(150.0, 300.0),
                                              edge_mm=(0.0, 15.0), need_motion=False)
            win = info["window"]
        ok = np.isfinite(rec.x)
        body = ok & np.isin(rec.marker_index,
                            [m for m, r in enumerate(rec.roles) if r == "body"])
        res = fit(rec, rig, require_convergence=False)
        z = (res.slip.value - truth["slip"]) / res.slip.std
        return {"seed": seed, "window": [round(float(v), 1) for v in win],
                "fps": truth["fps"], "converged": bool(res.converged),
                "chi2_per_dof": float(res.chi2_per_dof), "slip": res.slip.value,
                "std": res.slip.std, "truth": truth["slip"], "z": float(z),
                "lugs_before_body_s": float(rec.t[body].min() - rec.t[ok].min()),
                "lugs_after_body_s": float(rec.t[ok].max() - rec.t[body].max()),
                "seconds": time.time() - t0}
    except Exception as e:  # a failed fit is a result
        return {"seed": seed, "error": f"{type(e).__name__}: {e}"[:300],
                "seconds": time.time() - t0}


def _bad(r: dict) -> str | None:
    if "error" in r:
        return "error"
    if not r["converged"]:
        return "not converged"
    if r["chi2_per_dof"] > 1.1:
        return "chi2/dof > 1.1"
    if not math.isfinite(r["z"]) or abs(r["z"]) > 3:
        return "|z| > 3"
    return None


def _line(r: dict) -> str:
    if "error" in r:
        return f"{r['seed']:6d}  {r['error']}"
    return (f"{r['seed']:6d}  {r['fps']:5.0f} fps  window {r['window'][0]:7.1f} "
            f"{r['window'][1]:7.1f}  lugs alone {r['lugs_before_body_s']:4.2f} s before, "
            f"{r['lugs_after_body_s']:4.2f} s after  chi2/dof {r['chi2_per_dof']:9.4g}  "
            f"z {r['z']:+8.2f}  {r['seconds']:4.0f} s  {_bad(r) or ''}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="1020-1049", help="first-last (inclusive)")
    ap.add_argument("--window", choices=("default", "narrow"), default="default")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--log", default=None, help="JSON lines, appended")
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)  # "k/N"
    a = ap.parse_args(argv)
    lo, hi = (int(v) for v in a.seeds.split("-"))
    seeds = list(range(lo, hi + 1))
    if a.worker:  # a worker process: its share of the seeds, one JSON line each
        k, n = (int(v) for v in a.worker.split("/"))
        for s in seeds[k::n]:
            print(json.dumps(one(s, a.window)), flush=True)
        return 0
    t0 = time.time()
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    procs = [subprocess.Popen([sys.executable, __file__, "--seeds", a.seeds, "--window",
                               a.window, "--worker", f"{k}/{a.workers}"],
                              stdout=subprocess.PIPE, text=True, env=env)
             for k in range(max(1, a.workers))]
    rows = []
    try:
        for p in procs:
            for line in p.stdout:
                r = json.loads(line)
                rows.append(r)
                print(_line(r), flush=True)
                if a.log:
                    with open(a.log, "a") as f:
                        f.write(json.dumps({**r, "window_kind": a.window}) + "\n")
            p.wait()
    finally:
        for p in procs:
            if p.poll() is None:
                p.terminate()
    bad = [r for r in rows if _bad(r)]
    zs = [r["z"] for r in rows if "z" in r and math.isfinite(r["z"])]
    rms = math.sqrt(sum(z * z for z in zs) / len(zs)) if zs else float("nan")
    which = ", ".join(f"{r['seed']} {_bad(r)}" for r in bad) or "none"
    print(f"\n{len(rows)} recordings ({a.window} window), {time.time() - t0:.0f} s: "
          f"{len(bad)} bad ({which}); slip z rms {rms:.2f}, |z| <= 3 in "
          f"{sum(abs(z) <= 3 for z in zs)}/{len(zs)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
