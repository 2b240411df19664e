"""Cost of long recordings: wall time and peak memory of every stage against the frames.

For each size of the ladder (650, 2 000, 10 000, 30 000 and 100 000 frames of 14 markers:
12 lug and 2 body markers; 650 frames at 100 fps like the reference, the others at 500 fps
with the travel growing with the duration) every stage runs in a FRESH subprocess, whose
peak resident memory (ru_maxrss: JAX's buffers included, which tracemalloc does not see)
and wall time are reported:

  simulate   `fit-lug simulate` of the recording (written to a temporary folder)
  lsq        the least-squares fit (`fitlug.fit.fit`: start, fit, lug count, noise refit)
  explain    the explanation of that fit (time of `fitlug.explain.explain` alone); a clean
             recording's explanation stops at detection
  explain-effect  the same recording with a belt sag (catalog effect belt_sag, sag_d =
             EFFECT_SAG_MM) simulated in the process: the explanation's search over the
             catalog, its fits and the final fit at scale (time of explain alone)
  posterior  the posterior of the base fit (time of `sample_posterior` alone)
  whole      the default run `fit-lug fit CSV` (fit, explanation, posterior, report) as
             the executable makes it (fitlug.cli.executable_setup: the report drawn by a
             process of its own up to 200 000 samples, whose peak is added to the run's)

A stage's memory is the peak of its whole process (so explain's includes its fit). Then:
the log-log slope of time against frames per stage (least squares over the sizes >= 2 000;
target <= 1.1), the largest peak memory (target <= 2 GB, read as 2e9 B; figures print in
GiB), the warm whole run on the bundled 650-frame recording against the least-squares fit
alone (target <= 10 s) and the cold first run of a new installation (FITLUG_CACHE_DIR set
to an empty folder).

    python benchmarks/bench_scale.py --quick            # 650 and 2 000 frames, no extras
    python benchmarks/bench_scale.py                    # the full ladder (long: quiet machine)
    python benchmarks/bench_scale.py --frames 2000 10000 --stages simulate lsq

FITLUG_BENCH_RSS_TRACE=PREFIX makes every stage's process sample its resident memory and
its fitlug call stack in a thread (PREFIX.STAGE.FRAMES.txt: the peak and where it was, the
growth and the time by stack, a timeline), to find what holds the memory.

Stages of one size run one after another (each needs the simulated recording); sizes run
in parallel with --workers N (separate processes; memory figures then share the machine).

The work an explanation does depends on its detection: a recording it finds consistent
stops there, one it flags is screened against the catalog (a second round when the flag
stays after an effect is explained). By design 5 % of clean recordings are flagged (four
tests at alpha/4), and that doubles the explanation's cost whatever the size. So the
explain, explain-effect and whole stages also print their path (verdict, detection
p-values) and the detection's Ljung-Box and periodogram p-values of the recording's NOISE
ALONE (simulated data minus the same recording simulated without noise, per marker and
axis: what the residuals of a perfect fit would be). A flag that the noise alone raises is
a false alarm of that seed, not a cost of the size; compare sizes on the same path, or
choose the noise with --seed (default 2, whose noise is not flagged at any size; seeds 0 and
1 are at 100 000 frames). A warning is printed when a stage's path differs between sizes.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import json
import multiprocessing
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
SRC = os.path.join(ROOT, "src")
REFERENCE = os.path.join(ROOT, "data", "reference", "trajectories.csv")
LADDER = (650, 2000, 10000, 30000, 100000)
STAGES = ("simulate", "lsq", "explain", "explain-effect", "posterior", "whole")
EFFECT_SAG_MM = 0.3
GIB = 1024.0 ** 3
#: the issue's memory target, "2 GB", read as 2e9 bytes (the stricter reading; 2 GiB would
#: be 2.147e9); figures print in GiB and this check in bytes
TARGET_BYTES = 2e9


def scenario_for(frames: int) -> dict:
    """Scenario fields of a recording of `frames` frames of 14 markers."""
    fps = 100.0 if frames <= 650 else 500.0
    duration = frames / fps
    body = [[-60.0, 75.0], [60.0, 75.0]]
    return {"duration_s": duration, "fps": fps, "travel_mm": 108.0 * duration,
            "lug_markers": 12, "lug_spacing": 1, "body_markers": body}


# --------------------------------------------------------------------------- workers
class RssTrace:
    """Samples this process's VmRSS and the main thread's fitlug stack in a thread.

    Set FITLUG_BENCH_RSS_TRACE=PREFIX to write to PREFIX.STAGE.FRAMES.txt, at the end of a worker, the samples around the
    peak and the stacks where the resident memory grew most (JAX's buffers included, which
    tracemalloc does not see). A diagnosis aid; off by default."""

    def __init__(self, path: str, every_s: float = 0.05):
        import threading

        self.path, self.every = path, every_s
        self.samples = []  # (t, rss bytes, stack string)
        self.main = threading.main_thread().ident
        self.stop = threading.Event()
        self.t0 = time.perf_counter()
        self.th = threading.Thread(target=self._run, daemon=True)
        self.th.start()

    @staticmethod
    def rss() -> int:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) * 1024
        return 0

    def _stack(self) -> str:
        f = sys._current_frames().get(self.main)
        parts = []
        while f is not None:
            fn = f.f_code.co_filename
            if "fitlug" in fn or "bench_scale" in fn:
                parts.append(f"{os.path.basename(fn)}:{f.f_lineno}:{f.f_code.co_name}")
            f = f.f_back
        return " < ".join(parts[:8])

    def _run(self):
        while not self.stop.wait(self.every):
            try:
                st = self._stack()
            except Exception as exc:  # a frame torn down while read: keep sampling
                st = f"<{type(exc).__name__}>"
            self.samples.append((time.perf_counter() - self.t0, self.rss(), st))

    def write(self):
        self.stop.set()
        self.th.join()
        s = self.samples
        if not s:
            return
        peak_i = max(range(len(s)), key=lambda i: s[i][1])
        growth = {}
        for a, b in zip(s, s[1:]):
            if b[1] > a[1]:
                growth[b[2]] = growth.get(b[2], 0) + b[1] - a[1]
        with open(self.path, "w", encoding="utf-8") as fh:
            fh.write(f"peak {s[peak_i][1] / GIB:.3f} GiB at {s[peak_i][0]:.1f} s: {s[peak_i][2]}\n")
            fh.write("largest RSS growth by stack (MB):\n")
            for k, v in sorted(growth.items(), key=lambda kv: -kv[1])[:25]:
                fh.write(f"  {v / 2 ** 20:9.1f}  {k}\n")
            fh.write("highest RSS by stack (GiB; innermost 4 fitlug frames):\n")
            high = {}
            for _, r, st in s:
                key = " < ".join(st.split(" < ")[:4])
                high[key] = max(high.get(key, 0), r)
            for k, v in sorted(high.items(), key=lambda kv: -kv[1])[:25]:
                fh.write(f"  {v / GIB:7.3f}  {k}\n")
            fh.write("time by stack (s; innermost fitlug frames):\n")
            spent = {}
            for a, b in zip(s, s[1:]):
                for depth in (1, 3):
                    key = " < ".join(b[2].split(" < ")[:depth])
                    spent[key] = spent.get(key, 0.0) + b[0] - a[0]
            for k, v in sorted(spent.items(), key=lambda kv: -kv[1])[:30]:
                fh.write(f"  {v:8.1f}  {k}\n")
            fh.write("timeline (every ~1 s: t, GiB, stack):\n")
            last = -1.0
            for t, r, st in s:
                if t - last >= 1.0:
                    fh.write(f"  {t:7.1f} {r / GIB:6.3f}  {st}\n")
                    last = t


def noise_alone(sc, seed: int) -> dict:
    """Ljung-Box and cumulative-periodogram p-values (explain's detection,
    fitlug.explain._detect.serial_tests) of the noise of `simulate(sc, seed)` alone, per
    marker and axis."""
    import dataclasses

    from fitlug.explain._detect import serial_tests
    from fitlug.sim import simulate

    rec, _ = simulate(sc, seed=seed)
    clean, _ = simulate(dataclasses.replace(sc, noise_lug_mm=0.0, noise_body_mm=0.0), seed=seed)

    def series():
        for m in np.unique(rec.marker_index):
            sel = np.flatnonzero(rec.marker_index == m)
            sel = sel[np.argsort(rec.t[sel], kind="stable")]
            for a, c in ((rec.x, clean.x), (rec.y, clean.y)):
                yield (a - c)[sel]

    _, _, p_lb, _, _, p_cp = serial_tests(series())
    return {"noise_ljung_box_p": p_lb, "noise_periodogram_p": p_cp}


def _path(det_before, det_after, verdict, effects) -> dict:
    """What the explanation did: its verdict and the detection's p-values before/after."""
    def ps(d):
        if not d:
            return None
        return {k: round(float(d[k]), 4) for k in
                ("chi2_p", "ljung_box_p", "periodogram_p", "line_p")} | {
                    "consistent": bool(d["consistent"])}
    return {"verdict": verdict, "effects": list(effects), "detection_before": ps(det_before),
            "detection_after": ps(det_after)}


def _explained_path(ex) -> dict:
    def d(det):
        return det.as_dict() if det is not None else None
    return _path(d(ex.detection_before), d(ex.detection_after), ex.verdict, ex.effects)


def _worker(stage: str, folder: str, frames: int, budget: float, seed: int = 0) -> dict:
    """Run one stage in this (fresh) process; returns its timings and peak memory."""
    sys.path.insert(0, SRC)
    trace = (RssTrace(f"{os.environ['FITLUG_BENCH_RSS_TRACE']}.{stage}.{frames}.txt")
             if os.environ.get("FITLUG_BENCH_RSS_TRACE") else None)
    child_peak: list = []  # the report process's peak, bytes (the whole stage)
    t0 = time.perf_counter()
    extra = {}
    csv = os.path.join(folder, "trajectories.csv")
    rig_path = os.path.join(folder, "rig.toml")
    stage_s = None
    if stage == "simulate":
        from fitlug.cli import main

        rc = main(["simulate", folder, "-q", "--seed", str(seed), "--scenario",
                   json.dumps(scenario_for(frames))])
        assert rc == 0, rc
    elif stage == "explain-effect":
        from fitlug.explain import explain
        from fitlug.fit import fit
        from fitlug.sim import Scenario, rig_of, simulate

        sc = Scenario(**scenario_for(frames), effects={"belt_sag": {"sag_d": EFFECT_SAG_MM}})
        rec, _ = simulate(sc, seed=seed)
        t_sim = time.perf_counter()
        res = fit(rec, rig_of(sc))
        t1 = time.perf_counter()
        ex = explain(res, seed=0)
        stage_s = time.perf_counter() - t1
        extra = {**_explained_path(ex),
                 "timing": {"simulate_in_process": round(t_sim - t0, 2),
                            "fit": round(t1 - t_sim, 2),
                            **{k: round(v, 2) for k, v in ex.timing_s.items()}}}
    elif stage == "whole":
        from fitlug import cli
        from fitlug.cli import main

        if hasattr(cli, "executable_setup"):  # as the `fit-lug` executable runs it
            cli.executable_setup(["fit"])
            from _workers import report_process_peaks

            child_peak = report_process_peaks()  # the report process's own peak
        rc = main(["fit", csv, "--rig", rig_path, "--out", os.path.join(folder, "out"), "-q",
                   "--mcmc-budget", str(budget)])
        assert rc == 0, rc
    else:
        from fitlug.fit import fit
        from fitlug.io import read_rig, read_trajectories

        rig = read_rig(rig_path)
        rec = read_trajectories(csv, rig=rig)
        res = fit(rec, rig)
        t1 = time.perf_counter()
        if stage == "explain":
            from fitlug.explain import explain

            extra = _explained_path(explain(res, seed=0))
        elif stage == "posterior":
            from fitlug.posterior import sample_posterior

            post = sample_posterior(res, seed=0, time_budget_s=budget)
            extra = {"posterior": {"method": post.method.split(":")[0],
                                   "check_max_delta_chi2": round(
                                       post.check["max_delta_chi2"], 4),
                                   "converged": bool(post.converged),
                                   **{k: round(v, 2) for k, v in post.timings.items()}}}
        stage_s = time.perf_counter() - t1 if stage != "lsq" else None
    total = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024.0  # Linux: KiB
    # the whole run's report process (fitlug.report._aside), if any: its own peak (VmHWM;
    # RUSAGE_CHILDREN's ru_maxrss would be this process's size when it started the child)
    # added, an upper bound of the two processes' memory at one time
    peak += float(sum(child_peak))
    if trace is not None:
        trace.write()
    if stage == "whole":
        with open(os.path.join(folder, "out", "fit.json"), encoding="utf-8") as fh:
            d = json.load(fh).get("discrepancy") or {}
        extra = _path(d.get("detection_before"), d.get("detection_after"), d.get("verdict"),
                      [e.get("id", e) if isinstance(e, dict) else e
                       for e in d.get("effects") or []])
    if stage in ("explain", "explain-effect", "whole") and seed >= 0:
        # after the figures (not timed), and only for the ladder's simulated recordings
        # (seed < 0: the bundled one, whose wall time the extras report)
        from fitlug.sim import Scenario

        sc = Scenario(**scenario_for(frames), **(
            {"effects": {"belt_sag": {"sag_d": EFFECT_SAG_MM}}} if stage == "explain-effect"
            else {}))
        extra.update(noise_alone(sc, seed))
    return {"stage": stage, "frames": frames, "time_s": stage_s if stage_s is not None else total,
            "process_s": total, "peak_bytes": peak, **extra}


def run_stage(stage: str, folder: str, frames: int, budget: float, env=None,
              timeout: float = 3600.0, seed: int = 0) -> dict:
    """One stage in a fresh interpreter (never forked from a process with JAX loaded)."""
    cmd = [sys.executable, os.path.abspath(__file__), "--worker", stage, folder, str(frames),
           str(budget), str(seed)]
    e = dict(os.environ if env is None else env)
    e["PYTHONPATH"] = SRC + os.pathsep + e.get("PYTHONPATH", "")
    t0 = time.perf_counter()
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, env=e, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {"stage": stage, "frames": frames, "error": f"timeout {timeout:.0f} s"}
    wall = time.perf_counter() - t0
    for line in reversed(p.stdout.splitlines()):
        if line.startswith("{"):
            out = json.loads(line)
            out["wall_s"] = wall
            return out
    tail = (p.stderr or p.stdout).strip().splitlines()[-1:] or ["no output"]
    return {"stage": stage, "frames": frames, "error": f"rc {p.returncode}: {tail[0][:120]}"}


def run_size(frames: int, stages, budget: float, keep: str | None, seed: int = 0) -> list:
    folder = tempfile.mkdtemp(prefix=f"bench_scale_{frames}_", dir=keep)
    out = []
    try:
        todo = list(stages)
        if any(st != "explain-effect" for st in todo) and "simulate" not in todo:
            todo.insert(0, "simulate")  # the recording is needed
        for st in todo:
            r = run_stage(st, folder, frames, budget, seed=seed)
            r["measured"] = st in stages
            out.append(r)
            print(f"  ... {frames} frames {st}: " + json.dumps(
                {k: v for k, v in r.items() if k != "measured"}), file=sys.stderr, flush=True)
            if st == "simulate" and "error" in r:
                break
    finally:
        if keep is None:
            shutil.rmtree(folder, ignore_errors=True)
    return [r for r in out if r.pop("measured")]


# --------------------------------------------------------------------------- extras
def reference_runs(budget: float) -> dict:
    """Warm whole run and least squares on the bundled recording; cold first whole run."""
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = os.path.join(tmp, "ref")
        os.makedirs(folder)
        for name in ("trajectories.csv", "rig.toml"):
            shutil.copy(os.path.join(ROOT, "data", "reference", name), folder)
        for st in ("lsq", "whole"):
            run_stage(st, folder, 650, budget, seed=-1)  # fill the compile cache
            out[st + "_warm"] = run_stage(st, folder, 650, budget, seed=-1)
        env = dict(os.environ)
        env["FITLUG_CACHE_DIR"] = os.path.join(tmp, "empty_cache")
        out["whole_cold"] = run_stage("whole", folder, 650, budget, env=env, seed=-1)
    return out


def slope(frames, times) -> float:
    f, t = np.asarray(frames, float), np.asarray(times, float)
    ok = np.isfinite(t) & (t > 0)
    if ok.sum() < 2:
        return float("nan")
    return float(np.polyfit(np.log(f[ok]), np.log(t[ok]), 1)[0])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, nargs="+", default=None,
                    help=f"sizes (default {' '.join(map(str, LADDER))})")
    ap.add_argument("--stages", nargs="+", default=list(STAGES), choices=STAGES)
    ap.add_argument("--quick", action="store_true",
                    help="650 and 2 000 frames, posterior budget 10 s, no reference extras")
    ap.add_argument("--no-extras", action="store_true",
                    help="skip the warm/cold runs on the bundled recording")
    ap.add_argument("--bundled", action="store_true",
                    help="only the warm/cold runs on the bundled recording (no ladder)")
    ap.add_argument("--budget", type=float, default=60.0,
                    help="posterior time budget, s (default 60, the CLI's)")
    ap.add_argument("--workers", type=int, default=1, help="sizes run in parallel")
    ap.add_argument("--keep", metavar="DIR", help="keep the simulated recordings under DIR")
    ap.add_argument("--json", metavar="PATH", help="also write the raw figures as JSON")
    ap.add_argument("--seed", type=int, default=2,
                    help="noise seed of the simulated recordings (default 2: the first seed "
                         "whose noise alone the detection does not flag at any size of the "
                         "ladder; seeds 0 and 1 are false alarms at 100 000 frames, "
                         "benchmarks/results/2026-11-26)")
    a = ap.parse_args(argv)
    if a.seed < 0:
        ap.error("--seed must be >= 0")
    sizes = [] if a.bundled else a.frames or ([650, 2000] if a.quick else list(LADDER))
    budget = 10.0 if a.quick and a.budget == 60.0 else a.budget
    extras = a.bundled or not (a.quick or a.no_extras)

    rows = []
    if not sizes:
        pass
    elif a.workers > 1:
        ctx = multiprocessing.get_context("spawn")
        with cf.ProcessPoolExecutor(a.workers, mp_context=ctx) as ex:
            for res in ex.map(run_size, sizes, [a.stages] * len(sizes),
                              [budget] * len(sizes), [a.keep] * len(sizes),
                              [a.seed] * len(sizes)):
                rows += res
    else:
        for n in sizes:
            res = run_size(n, a.stages, budget, a.keep, a.seed)
            rows += res
            for r in res:
                print(f"  {n:>7d} frames  {r['stage']:<9s} " + (
                    r["error"] if "error" in r else
                    f"{r['time_s']:8.2f} s  {r['peak_bytes'] / GIB:6.2f} GiB"
                    + (f"  {r['verdict']} {r['effects']} {r['timing']}" if "timing" in r
                       else "") + (f"  {r['posterior']}" if "posterior" in r else "")),
                      flush=True)

    if sizes:
        _ladder_table(rows, sizes, a.stages)
        _paths_table(rows)

    ext = {}
    if extras:
        ext = reference_runs(a.budget)
        w, l_, c = ext["whole_warm"], ext["lsq_warm"], ext["whole_cold"]
        print()

        def fmt(r):  # a fresh command's wall time (interpreter start included) and peak
            return (r["error"] if "error" in r
                    else f"{r['wall_s']:6.2f} s ({r['peak_bytes'] / GIB:.2f} GiB peak)")
        print(f"  bundled 650-frame recording: whole default run warm {fmt(w)} (target <= 10 s; "
              f"second of two runs); least squares alone warm {fmt(l_)}; whole run cold "
              f"(empty compile cache) {fmt(c)}")
    if a.json:
        with open(a.json, "w", encoding="utf-8") as fh:
            json.dump({"rows": rows, "extras": ext}, fh, indent=1)
    return 0


def _paths_table(rows) -> None:
    """The explanations' paths: verdict, detection flags, and the noise alone's p-values."""
    got = [r for r in rows if "verdict" in r and "error" not in r]
    if not got:
        return
    print()
    print("  explanation paths (detection p-values; a flag is p < alpha/4 = 0.0125):")
    for r in got:
        def flags(d):
            if not d:
                return "-"
            return ("consistent" if d["consistent"] else "FLAGGED") + " (LB {:.4f}, CP {:.4f}, "\
                "line {:.4f}, chi2 {:.4f})".format(d["ljung_box_p"], d["periodogram_p"],
                                                   d["line_p"], d["chi2_p"])
        print(f"  {r['frames']:>7d} {r['stage']:<14s} verdict {r['verdict']} {r['effects']}; "
              f"before: {flags(r.get('detection_before'))}; after: "
              f"{flags(r.get('detection_after'))}; the noise alone: LB "
              f"{r.get('noise_ljung_box_p', float('nan')):.4f}, CP "
              f"{r.get('noise_periodogram_p', float('nan')):.4f}")
    for stage in sorted({r["stage"] for r in got}):
        paths = {}
        for r in got:
            if r["stage"] == stage:
                key = (r["verdict"], tuple(r["effects"]),
                       (r.get("detection_after") or {}).get("consistent"))
                paths.setdefault(key, []).append(str(r["frames"]))
        if len(paths) > 1:
            groups = " against ".join(", ".join(v) for v in paths.values())
            print(f"  WARNING: {stage}'s explanation took different paths at different sizes "
                  f"({groups} frames): its slope compares different work "
                  f"(a flagged noise draw: see the noise-alone p-values; try another --seed)")


def _ladder_table(rows, sizes, stages) -> None:
    """The ladder's table, slopes and peaks."""
    print()
    print(f"{'frames':>8s}  " + "  ".join(f"{s:>18s}" for s in stages))
    print(f"{'':>8s}  " + "  ".join(f"{'time s  peak GiB':>18s}" for _ in stages))
    table = {(r["frames"], r["stage"]): r for r in rows}
    for n in sizes:
        cells = []
        for s in stages:
            r = table.get((n, s))
            if r is None or "error" in r:
                cells.append(f"{'failed' if r else '-':>18s}")
            else:
                cells.append(f"{r['time_s']:9.2f}  {r['peak_bytes'] / GIB:7.2f}")
        print(f"{n:>8d}  " + "  ".join(cells))
    print()
    worst = 0.0
    for s in stages:
        pts = [(n, table[(n, s)]["time_s"]) for n in sizes
               if (n, s) in table and "error" not in table[(n, s)]]
        big = [(n, t) for n, t in pts if n >= 2000]
        sl = slope(*zip(*big)) if len(big) >= 2 else float("nan")
        mem = max((table[(n, s)]["peak_bytes"] for n in sizes
                   if (n, s) in table and "error" not in table[(n, s)]), default=float("nan"))
        worst = max(worst, mem) if np.isfinite(mem) else worst
        print(f"  {s:<9s} log-log slope of time vs frames (>= 2000 frames): {sl:5.2f}  "
              f"(target <= 1.1)   largest peak {mem / GIB:5.2f} GiB")
    print(f"  largest peak memory of any stage: {worst / GIB:.2f} GiB = {worst / 1e9:.3f}e9 B "
          f"(target <= 2 GB = 2e9 B: {'met' if worst <= TARGET_BYTES else 'MISSED'})")
    for r in rows:
        if "error" in r:
            print(f"  FAILED {r['frames']} frames {r['stage']}: {r['error']}")


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--worker":
        _, _, stage, folder, frames, budget, seed = sys.argv
        print(json.dumps(_worker(stage, folder, int(frames), float(budget), int(seed))))
    else:
        sys.exit(main())
