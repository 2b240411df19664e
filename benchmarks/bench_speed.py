"""How long a whole `fit-lug` run takes, first and warm, per kind of recording (issue 43).

    python benchmarks/bench_speed.py [--kinds bundled,null,effect,engine,newlen]
        [--before REF] [--repeat 2] [--engine CSV] [--json FILE]

Per kind of recording (the bundled one; a null drive-through: the reference robot seen
through a 400 mm window with a tracker's faults; an effect: lug_sliding, slide_mu 6,
through a drawn window that sees a speed change; an engine recording given by --engine, skipped without it), each run is a
fresh `python -m fitlug.cli CSV --out DIR -q` process (posterior and report: the default
run):

- first: with an empty temporary JAX cache (FITLUG_CACHE_DIR), as on a fresh machine;
- warm: again with that cache, `--repeat` times (the median is printed).

`newlen` (issue 43, item 2: shape buckets): a recording never seen before of a kind
already seen. Two simulated recordings of the reference robot, 5.8 s and 6.0 s long
(other frames and samples, the same buckets); the 5.8 s one is run first into an
empty cache (the kind seen), then the 6.0 s one's first run (new to that cache) and its
warm runs, and the first's CPU seconds over the warm median's (issue 43: at most 1.5).

Wall and CPU seconds (user + sys of the whole process, its threads included, interpreter
start and imports too, and of its report process) come from the parent (getrusage of the
children); the peak memory (MB) is the run's own peak resident memory (ru_maxrss) plus its
report process's (fitlug.report._aside), an upper bound of both at once; the stage split
(start-up, read, fit, explain, posterior, report: wall and the process's CPU) from the
child, which times the CLI's own stage lines. With `--before REF` the same runs are made
with the code of git REF (exported to a temporary folder) interleaved with this tree's,
and printed side by side: both versions see the same machine load.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
STAGES = ("startup", "reading", "fitting", "explaining", "sampling", "report")


def _worker(csv: str, out: str) -> None:
    """In the child: run the CLI on `csv`, timing each stage from its stage line."""
    t0, c0 = time.perf_counter(), time.process_time()
    marks = [("startup", t0, c0)]
    import fitlug.cli as cli

    # start as the `fit-lug` executable starts (fitlug.cli.entry), where the code has it
    if hasattr(cli, "executable_setup"):
        cli.executable_setup([csv])
    else:
        getattr(cli, "_without_dask", lambda: None)()
    import fitlug.cli._fit as fitmod

    orig = fitmod.stage

    def stage(args, name, detail=""):
        marks.append((name, time.perf_counter(), time.process_time()))
        return orig(args, name, detail)

    fitmod.stage = stage
    from _workers import report_process_peaks

    child_peak = report_process_peaks()  # the report process's own peak, where it has one
    rc = cli.main([csv, "--out", out, "-q"])
    marks.append(("end", time.perf_counter(), time.process_time()))
    split = {}
    for (name, t, c), (_, t2, c2) in zip(marks[:-1], marks[1:]):
        split[name] = {"wall": t2 - t, "cpu": c2 - c}
    with open(os.path.join(out, "fit.json"), encoding="utf-8") as fh:
        doc = json.load(fh)
    mc = doc.get("mcmc") or {}
    print(json.dumps({"rc": rc, "split": split, "slip": (doc.get("slip") or {}).get("value"),
                      "steps": mc.get("steps"), "converged": mc.get("converged"),
                      "verdict": (doc.get("discrepancy") or {}).get("verdict"),
                      # own peak: ru_maxrss (this worker's parent, the bench, is far
                      # smaller, so the size it inherits at the fork does not count)
                      "peak_mb": (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
                                  + sum(child_peak)) / 2**20}))
    # end as the `fit-lug` executable ends (fitlug.cli.entry), where the code has it
    getattr(cli, "exit_now", lambda status: None)(0)


def _child(src: str, csv: str, cache: str) -> dict:
    env = dict(os.environ, PYTHONPATH=src, FITLUG_CACHE_DIR=cache)
    out = tempfile.mkdtemp(prefix="bench_speed_out_")
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, os.path.abspath(__file__), "--worker", csv, out],
                       env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    shutil.rmtree(out, ignore_errors=True)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if p.returncode != 0:
        return {"error": (p.stderr or p.stdout).strip().splitlines()[-1:], "wall": wall,
                "cpu": cpu}
    doc = json.loads(p.stdout.strip().splitlines()[-1])
    doc.update(wall=wall, cpu=cpu)
    return doc


def _recordings(kinds, folder, engine):
    """{kind: csv path}: the bundled one, and drive-throughs written into `folder`."""
    out = {}
    if "bundled" in kinds:
        out["bundled"] = os.path.join(ROOT, "data", "reference", "trajectories.csv")
    sys.path.insert(0, os.path.join(ROOT, "tests"))
    sys.path.insert(0, os.path.join(ROOT, "src"))
    for kind, effects in (("null", {}), ("effect", {"lug_sliding": {"slide_mu": 6.0}})):
        if kind not in kinds:
            continue
        from fitlug.sim import Scenario, rig_of, simulate
        from realism import drive_through, write_realistic

        sc = Scenario(effects=effects)
        rec = simulate(sc, seed=5)[0]
        # the null through a fixed 400 mm window; the effect through a drawn one that sees
        # a speed change (lug_sliding shows only where the traction changes)
        cut, _ = (drive_through(rec, seed=5, window=(100.0, 500.0), faults=True) if not effects
                  else drive_through(rec, seed=5, faults=True, need_motion=True))
        out[kind] = write_realistic(os.path.join(folder, kind), cut, rig_of(sc), wide=False)
    if "newlen" in kinds:
        from fitlug.sim import Scenario, write_simulation

        base, pair = Scenario(), []
        for d, seed in ((5.8, 5), (6.0, 6)):
            k = d / base.duration_s  # as `fit-lug simulate --duration`: the profile stretched
            sc = Scenario(duration_s=d, rest_s=base.rest_s * k, ramp_s=base.ramp_s * k,
                          travel_mm=base.travel_mm * k)
            sub = os.path.join(folder, f"newlen{d}")
            write_simulation(sub, sc, seed, truth=False)
            pair.append(os.path.join(sub, "trajectories.csv"))
        out["newlen"] = tuple(pair)
    if "engine" in kinds:
        if engine:
            out["engine"] = os.path.abspath(engine)
        else:
            print("engine: skipped (no --engine CSV: the real-tracks issue's recordings)")
    return out


def _export(ref: str, folder: str) -> str:
    dest = os.path.join(folder, "before")
    os.makedirs(dest)
    arch = subprocess.run(["git", "-C", ROOT, "archive", ref, "src"], check=True,
                          capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", dest], input=arch, check=True)
    return os.path.join(dest, "src")


def _fmt(r):
    if r is None:
        return "-"
    if "error" in r:
        return f"failed: {r['error']}"
    return f"{r['wall']:6.1f} {r['cpu']:6.1f}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worker", nargs=2, metavar=("CSV", "OUT"), help=argparse.SUPPRESS)
    ap.add_argument("--kinds", default="bundled,null,effect,engine,newlen")
    ap.add_argument("--before", metavar="REF", help="git ref to compare with, side by side")
    ap.add_argument("--repeat", type=int, default=2, help="warm runs per version (median)")
    ap.add_argument("--engine", metavar="CSV", help="an engine recording (rig.toml beside)")
    ap.add_argument("--json", metavar="FILE", help="append every run as a JSON line")
    a = ap.parse_args(argv)
    if a.worker:
        _worker(*a.worker)
        return 0
    tmp = tempfile.mkdtemp(prefix="bench_speed_")
    try:
        versions = {"now": os.path.join(ROOT, "src")}
        if a.before:
            versions = {"before": _export(a.before, tmp), **versions}
        recs = _recordings(a.kinds.split(","), os.path.join(tmp, "rec"), a.engine)
        rows = {}
        for kind, csv in recs.items():
            for ver, src in versions.items():
                cache = tempfile.mkdtemp(prefix="jaxcache_", dir=tmp)
                run = csv
                if kind == "newlen":  # the kind seen first, then the new recording
                    seen, run = csv
                    _child(src, seen, cache)
                first = _child(src, run, cache)
                warm = [_child(src, run, cache) for _ in range(a.repeat)]
                rows[kind, ver] = (first, warm)
                ok = [w for w in warm if "error" not in w]
                med = ({k: statistics.median(w[k] for w in ok) for k in ("wall", "cpu")}
                       if ok else None)
                print(f"{kind:8} {ver:7} first {_fmt(first)}   warm median {_fmt(med)}  "
                      f"(wall, CPU s)", flush=True)
                if kind == "newlen" and med and "error" not in first:
                    print(f"newlen   {ver:7} a never-seen recording of a seen kind: first "
                          f"{first['cpu']:.1f} s CPU, second {med['cpu']:.1f} s CPU, "
                          f"ratio {first['cpu'] / med['cpu']:.2f}", flush=True)
                if a.json:
                    with open(a.json, "a", encoding="utf-8") as fh:
                        fh.write(json.dumps({"kind": kind, "version": ver, "first": first,
                                             "warm": warm}) + "\n")
        _table(rows, versions)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


def _table(rows, versions) -> None:
    print("\nkind     version | first wall   CPU | warm wall   CPU  peak MB | warm stages, CPU s "
          "(wall s): " + " ".join(STAGES) + " | slip, steps, verdict")
    for (kind, ver), (first, warm) in rows.items():
        ok = [w for w in warm if "error" not in w]
        if not ok or "error" in first:
            print(f"{kind:8} {ver:7} | {_fmt(first)} | failed")
            continue
        med = {k: statistics.median(w[k] for w in ok) for k in ("wall", "cpu")}
        st = []
        for s in STAGES:
            c = [w["split"].get(s, {}).get("cpu", 0.0) for w in ok]
            t = [w["split"].get(s, {}).get("wall", 0.0) for w in ok]
            st.append(f"{statistics.median(c):.1f}({statistics.median(t):.1f})")
        w0 = ok[0]
        peak = [w["peak_mb"] for w in ok if w.get("peak_mb")]
        print(f"{kind:8} {ver:7} | {first['wall']:10.1f} {first['cpu']:5.1f} | "
              f"{med['wall']:9.1f} {med['cpu']:5.1f} "
              f"{statistics.median(peak) if peak else float('nan'):6.0f} | {' '.join(st)} | "
              f"{w0['slip']}, {w0['steps']}, {w0['verdict']}")


if __name__ == "__main__":
    sys.exit(main())
