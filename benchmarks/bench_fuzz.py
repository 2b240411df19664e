"""Fuzz every input parser by the ten thousand: counts of ok / InputError / uncaught by type.

The cases are those of tests/test_fuzz.py (seeded mutations of the bundled recording in
long and wide form, of rig.toml, of a calib.json and of real .cine files; parse only,
nothing is fitted), so any uncaught case is rebuilt there by `case(kind, seed)`. The
mutations include issue 30's faults: a trailer or note line, one absurd value (1e300),
time-stamp jitter, a UTF-8 BOM and a gzip-compressed file.

    PYTHONPATH=src python3 benchmarks/bench_fuzz.py                 # 10 000 cases per parser
    PYTHONPATH=src python3 benchmarks/bench_fuzz.py --quick         # 500 per parser
    PYTHONPATH=src python3 benchmarks/bench_fuzz.py --n 50000 --workers 16 --kinds rig,cine

Exit status 1 when any case raised something other than fitlug.InputError.
"""

from __future__ import annotations

import argparse
import collections
import concurrent.futures
import multiprocessing
import os
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "src"))
sys.path.insert(0, os.path.join(HERE, "..", "tests"))

KINDS = ("trajectories", "rig", "calib", "cine")


def _chunk(kind: str, seeds: range) -> tuple[collections.Counter, dict]:
    import test_fuzz

    counts: collections.Counter = collections.Counter()
    examples: dict[str, list[str]] = {}
    with tempfile.TemporaryDirectory(prefix="bench_fuzz_") as folder:
        for seed in seeds:
            outcome, detail = test_fuzz.run_case(kind, seed, folder)
            counts[outcome] += 1
            if detail and len(examples.setdefault(outcome, [])) < 3:
                examples[outcome].append(detail)
    return counts, examples


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=10_000, help="cases per parser (default 10000)")
    ap.add_argument("--quick", action="store_true", help="500 cases per parser")
    ap.add_argument("--workers", type=int, default=1, help="processes (default 1)")
    ap.add_argument("--kinds", default=",".join(KINDS),
                    help=f"parsers, comma-separated (default {','.join(KINDS)})")
    ap.add_argument("--first-seed", type=int, default=0, help="seed of the first case")
    args = ap.parse_args(argv)
    n = 500 if args.quick else args.n
    kinds = [k.strip() for k in args.kinds.split(",") if k.strip()]
    unknown = set(kinds) - set(KINDS)
    if unknown:
        ap.error(f"unknown parser(s) {sorted(unknown)}; known: {', '.join(KINDS)}")
    import test_fuzz

    if "cine" in kinds and not os.path.isdir(test_fuzz.CINE_DIR):
        print(f"cine: skipped ({test_fuzz.CINE_DIR} not present)")
        kinds.remove("cine")
    size = max(50, n // (8 * max(args.workers, 1)))
    uncaught_total = 0
    print(f"{n} cases per parser, {args.workers} worker(s); parse only")
    print(f"{'parser':<14}{'cases':>8}{'ok':>8}{'InputError':>12}{'uncaught':>10}{'s':>8}"
          f"{'cases/s':>9}")
    pool = None
    if args.workers > 1:
        pool = concurrent.futures.ProcessPoolExecutor(
            args.workers, mp_context=multiprocessing.get_context("spawn"))
    try:
        for kind in kinds:
            t0 = time.perf_counter()
            chunks = [range(s, min(s + size, args.first_seed + n))
                      for s in range(args.first_seed, args.first_seed + n, size)]
            if pool is None:
                results = [_chunk(kind, c) for c in chunks]
            else:
                results = list(pool.map(_chunk, [kind] * len(chunks), chunks))
            seconds = time.perf_counter() - t0
            counts: collections.Counter = collections.Counter()
            examples: dict[str, list[str]] = {}
            for c, e in results:
                counts.update(c)
                for k, v in e.items():
                    examples.setdefault(k, []).extend(v)
            uncaught = {k: v for k, v in counts.items() if k not in ("ok", "InputError")}
            uncaught_total += sum(uncaught.values())
            total = sum(counts.values())
            print(f"{kind:<14}{total:>8}{counts['ok']:>8}{counts['InputError']:>12}"
                  f"{sum(uncaught.values()):>10}{seconds:>8.1f}{total / seconds:>9.0f}")
            for name, count in sorted(uncaught.items(), key=lambda kv: -kv[1]):
                print(f"    uncaught {name}: {count}")
                for example in examples.get(name, [])[:3]:
                    print(f"      {example}")
    finally:
        if pool is not None:
            pool.shutdown()
    print(f"uncaught in total: {uncaught_total}")
    return 1 if uncaught_total else 0


if __name__ == "__main__":
    sys.exit(main())
