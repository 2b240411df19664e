"""Detection power side by side (issue 42 item 3): per catalog effect, the smallest amplitude
found 90 % of the time, for two or more source trees in one run. Prints figures; asserts nothing.

    python benchmarks/bench_ladder.py --tree before=/tmp/old/src --tree now=src \\
        [--effects lug_ripple,...] [--seeds 10] [--rungs 0.5,0.63,...] [--workers 8] \\
        [--log ladder.jsonl] [--from-log ladder.jsonl]

The recordings and the rule are bench_explain.py's `ladder` part (its LADDER table: each
effect at multiples of a rough threshold size on fitlug.sim's default 650-frame recording,
white noise at the reference levels), on a finer ladder of rungs (default x0.5 to x4 in
steps of about 1.26, so that a 30 % growth is one rung) and with more seeds per rung
(default 10). Rung k, seed s uses simulation seed 2000 + 100 k + s in every tree, so the
trees see the same recordings (fitlug.sim's default recording is checked to be the same
in each: the figures compare the fit and the explanation, not the data). Found means
verdict 'explained' naming exactly that effect. A rung stops once more than 10 % of its
seeds are missed; an effect's ladder stops at the first rung found >= 90 % of the time.

Each (tree, effect) ladder runs in one worker process whose `sys.path` starts with that
tree's `src` (spawned: JAX is never forked); workers are shared round-robin between the
trees. Every finished rung is one JSON line in --log (appended by the worker), so a run cut
short keeps its rungs. The table gives, per effect, each tree's smallest amplitude found
>= 90 % (size and RMS displacement in noise sigmas) and the ratio of the last tree's to the
first's: the issue's target is a ratio <= 1.3.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed

HERE = os.path.dirname(os.path.abspath(__file__))
RUNGS = (0.5, 0.63, 0.8, 1.0, 1.26, 1.59, 2.0, 2.52, 3.17, 4.0)


# bench_explain.py's table (imported from a module without fitlug: this process may not
# import fitlug from this tree)
sys.path.insert(0, HERE)
from _ladder_table import LADDER  # noqa: E402


def _init(src):
    sys.path.insert(0, os.path.abspath(src))


def _noise_units(sc, simulate, np):
    """RMS of the effect's noise-free displacement over all samples, in noise sigmas."""
    quiet = dict(noise_lug_mm=0.0, noise_body_mm=0.0)
    a, _ = simulate(sc.replace(**quiet), 0)
    b, _ = simulate(sc.replace(effects={}, **quiet), 0)
    sig = np.where(np.asarray(a.roles)[a.marker_index] == "lug", sc.noise_lug_mm,
                   sc.noise_body_mm)
    return float(np.sqrt(np.mean(((a.x - b.x) ** 2 + (a.y - b.y) ** 2) / sig ** 2) / 2))


def ladder(task):
    """One effect's ladder in one tree (runs in a worker); returns its rungs."""
    tree, eid, seeds, rungs, log, done = task
    import numpy as np

    import fitlug
    from fitlug.explain import explain
    from fitlug.fit import fit
    from fitlug.sim import Scenario, rig_of, simulate

    make, thr = LADDER[eid]
    rows = []
    for k, f in enumerate(rungs):
        key = (tree, eid, f)
        if key in done:  # resumed from the log
            rows.append(done[key])
            if done[key]["found"] >= 0.9 * seeds:
                break
            continue
        sc = Scenario(effects=make(thr * f))
        found = tried = 0
        t0 = time.process_time()
        named = []
        for s in range(seeds):
            rec, _ = simulate(sc, 2000 + 100 * k + s)
            ex = explain(fit(rec, rig_of(sc)))
            hit = ex.verdict == "explained" and list(ex.effects) == [eid]
            found += hit
            tried += 1
            if not hit:
                named.append([ex.verdict] + list(ex.effects))
            if tried - found > 0.1 * seeds:  # this rung can no longer reach 90 %
                break
        row = {"tree": tree, "src": os.path.dirname(fitlug.__file__), "effect": eid,
               "rung": f, "size": thr * f, "noise_units": _noise_units(sc, simulate, np),
               "found": found, "of": tried, "planned": seeds, "missed_as": named,
               "cpu_s": time.process_time() - t0}
        rows.append(row)
        if log:
            with open(log, "a") as fh:
                fh.write(json.dumps(row) + "\n")
        print(f"{tree} {eid} x{f:g} ({row['noise_units']:.3f} sigma rms): {found}/{tried} "
              f"found, {row['cpu_s']:.0f} s CPU", flush=True)
        if found >= 0.9 * seeds:  # larger sizes are found at least as often
            break
    return rows


def smallest(rows, seeds):
    ok = sorted((r for r in rows if r["found"] >= 0.9 * seeds), key=lambda r: r["rung"])
    return ok[0] if ok else None


def summarise(rows, trees, effects, seeds):
    print(f"\nsmallest amplitude found >= 90 % of {seeds} seeds (RMS displacement / noise "
          f"sigma; size)")
    print("| effect | " + " | ".join(trees) + f" | {trees[-1]} / {trees[0]} |")
    print("| --- " * (len(trees) + 2) + "|")
    worst = 0.0
    for e in effects:
        cells, best = [], {}
        for t in trees:
            mine = [r for r in rows if r["tree"] == t and r["effect"] == e]
            s = best[t] = smallest(mine, seeds)
            if s is None:
                cells.append("not reached" if mine else "not run")
            else:
                cells.append(f"{s['noise_units']:.3f} (x{s['rung']:g}, {s['size']:.3g})")
        first, last = best[trees[0]], best[trees[-1]]
        ratio = (last["noise_units"] / first["noise_units"]) if first and last else None
        if ratio is not None:
            worst = max(worst, ratio)
        print(f"| {e} | " + " | ".join(cells) + f" | {'-' if ratio is None else f'{ratio:.2f}'} |")
    print(f"largest ratio {worst:.2f} (target <= 1.30)")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tree", action="append", default=None, metavar="LABEL=SRC",
                    help="a source tree (its src folder); repeat; default now=<this src>")
    ap.add_argument("--effects", default=",".join(LADDER))
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--rungs", default=",".join(f"{r:g}" for r in RUNGS))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--log", default=None)
    ap.add_argument("--from-log", default=None, help="summarise a log, no new fits")
    a = ap.parse_args(argv)
    trees = dict(t.split("=", 1) for t in (a.tree or [f"now={os.path.join(HERE, '..', 'src')}"]))
    effects = [e for e in a.effects.split(",") if e]
    rungs = tuple(float(r) for r in a.rungs.split(","))
    done = {}
    for path in filter(None, [a.from_log, a.log]):
        if os.path.exists(path):
            with open(path) as fh:
                for line in fh:
                    if line.strip():
                        r = json.loads(line)
                        done[(r["tree"], r["effect"], r["rung"])] = r
    if a.from_log:
        summarise(list(done.values()), list(trees), effects, a.seeds)
        return
    from _workers import one_thread_each

    one_thread_each()
    ctx = multiprocessing.get_context("spawn")
    per = max(1, a.workers // len(trees))
    pools = {t: ProcessPoolExecutor(per, mp_context=ctx, initializer=_init, initargs=(src,))
             for t, src in trees.items()}
    t0 = time.perf_counter()
    futures = [pools[t].submit(ladder, (t, e, a.seeds, rungs, a.log, done))
               for e in effects for t in trees]
    rows = []
    for f in as_completed(futures):
        rows += f.result()
    for p in pools.values():
        p.shutdown()
    print(f"{len(rows)} rungs in {time.perf_counter() - t0:.0f} s with {per} worker(s) per tree")
    summarise(rows, list(trees), effects, a.seeds)


if __name__ == "__main__":
    main()
