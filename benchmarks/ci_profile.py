"""Where the test suite's time goes (issue 43, item 6): compile against work, by file and
by test, from a run made with the profiling hook of tests/conftest.py.

    FITLUG_PROFILE_COMPILES=/tmp/prof/p FITLUG_CACHE_DIR=$(mktemp -d) pytest tests
    python benchmarks/ci_profile.py /tmp/prof/p
    python benchmarks/ci_profile.py /tmp/prof/p --tier   # the default run's share

Prints, per test file, the wall seconds summed over its tests (both workers), the seconds
XLA spent compiling (backend compile), tracing and lowering to StableHLO, and the share of
the three; then the slowest tests and the programs whose compilation cost most in all.
"""

from __future__ import annotations

import glob
import json
import sys
from collections import defaultdict

COMPILE = "/jax/core/compile/backend_compile_duration"
TRACE = "/jax/core/compile/jaxpr_trace_duration"
LOWER = "/jax/core/compile/jaxpr_to_mlir_module_duration"


def load(prefix: str) -> list[dict]:
    rows = []
    for path in sorted(glob.glob(prefix + ".*.jsonl")):
        with open(path) as fh:
            rows += [json.loads(line) for line in fh if line.strip()]
    if not rows:
        raise SystemExit(f"{prefix}.*.jsonl: no profile rows (run pytest with "
                         "FITLUG_PROFILE_COMPILES set)")
    return rows


def main(prefix: str, top: int = 25) -> None:
    rows = load(prefix)
    by_file = defaultdict(lambda: [0.0, 0.0, 0.0, 0.0, 0])
    progs = defaultdict(lambda: [0, 0.0])
    for r in rows:
        f = by_file[r["nodeid"].split("::")[0]]
        ev = r["events"]
        f[0] += r["wall"]
        f[1] += ev.get(COMPILE, 0.0)
        f[2] += ev.get(TRACE, 0.0)
        f[3] += ev.get(LOWER, 0.0)
        f[4] += 1
        for name, (n, s) in r.get("compiled", {}).items():
            progs[name][0] += n
            progs[name][1] += s
    tot = [sum(v[i] for v in by_file.values()) for i in range(5)]
    print(f"{'file':44s} {'tests':>5s} {'wall s':>8s} {'compile':>8s} {'trace':>7s} "
          f"{'lower':>7s} {'share':>6s}")
    for name, v in sorted(by_file.items(), key=lambda kv: -kv[1][0]):
        share = (v[1] + v[2] + v[3]) / v[0] if v[0] else 0.0
        print(f"{name:44s} {v[4]:5d} {v[0]:8.1f} {v[1]:8.1f} {v[2]:7.1f} {v[3]:7.1f} "
              f"{share:6.0%}")
    share = (tot[1] + tot[2] + tot[3]) / tot[0] if tot[0] else 0.0
    print(f"{'all':44s} {tot[4]:5d} {tot[0]:8.1f} {tot[1]:8.1f} {tot[2]:7.1f} {tot[3]:7.1f} "
          f"{share:6.0%}")
    print(f"\nslowest {top} tests (wall s, compile s)")
    for r in sorted(rows, key=lambda r: -r["wall"])[:top]:
        print(f"{r['wall']:8.1f} {r['events'].get(COMPILE, 0.0):8.1f}  {r['nodeid']}")
    print(f"\nprograms by compile seconds (count, seconds), top {top}")
    for name, (n, s) in sorted(progs.items(), key=lambda kv: -kv[1][1])[:top]:
        print(f"{s:8.1f} {n:6d}  {name}")


def tier(prefix: str) -> None:
    """What the default run keeps of a profiled run of the whole suite (`-m "bench or not
    bench"`): the tests not in tests/ci_tier.py's BENCH_IN_CI, by file; a test's module
    fixtures count where they were built, so the figure is a lower bound where a kept test
    now builds what a benched one did."""
    import os

    sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))
    from ci_tier import BENCH_IN_CI  # the tier's table: plain data, no imports

    keys = list(BENCH_IN_CI)
    rows = load(prefix)
    by_file = defaultdict(lambda: [0.0, 0.0])
    for r in rows:
        f = by_file[r["nodeid"].split("::")[0]]
        f[0] += r["wall"]
        if not any(r["nodeid"].startswith(k) for k in keys):
            f[1] += r["wall"]
    tot = [sum(v[i] for v in by_file.values()) for i in range(2)]
    print(f"{'file':44s} {'all s':>8s} {'kept s':>8s}")
    for name, v in sorted(by_file.items(), key=lambda kv: -kv[1][1]):
        print(f"{name:44s} {v[0]:8.1f} {v[1]:8.1f}")
    print(f"{'all (worker-seconds)':44s} {tot[0]:8.1f} {tot[1]:8.1f}")


if __name__ == "__main__":
    if len(sys.argv) < 2:
        raise SystemExit("usage: python benchmarks/ci_profile.py PREFIX [--tier]")
    if "--tier" in sys.argv[2:]:
        tier(sys.argv[1])
    else:
        main(sys.argv[1])
