"""Semantic faults by the hundred: does each give its clean twin, or a one-line refusal?

Each case takes a clean recording (the bundled reference, or a fitlug.sim scenario drawn
at random: frame rate, duration, markers, noise), applies a seeded random combination of
the faults of issue 30 (driving towards -x, y pointing down, x and y swapped, identity
swaps, a reflection tracked as a lug, a static reflection labelled body, a sigma_mm
column with one absurd marker or holes, a second run appended, a `# units:` header,
the realism transform's field of view, misses and fragments), writes it as a tracker
would, reads it back and prepares it for the fit (fitlug.fit._prepare; nothing is
fitted). Outcomes:

- twin: the prepared recording is the clean one's (positions to 1e-9 mm, the same
  markers), with the faults listed (orientation, swaps, excluded);
- refused: a one-line InputError (expected for a second run appended);
- WRONG: anything else (a fault missed, a marker kept out that was clean, a traceback).

    PYTHONPATH=src python3 benchmarks/bench_silent.py            # 300 cases
    PYTHONPATH=src python3 benchmarks/bench_silent.py --n 2000 --first-seed 1000

Exit status 1 when any case is WRONG.
"""

from __future__ import annotations

import argparse
import collections
import os
import sys
import tempfile
import time
import warnings

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "src"))
sys.path.insert(0, os.path.join(HERE, "..", "tests"))
REF = os.path.join(HERE, "..", "data", "reference")


def _sorted(rec, mi):
    o = np.lexsort((rec.t, mi))
    fields = {k: getattr(rec, k)[o] for k in ("t", "x", "y", "frame", "sigma")
              if getattr(rec, k) is not None}
    return rec.with_(marker_index=mi[o], **fields)


def _swap(rec, a, b, t0):
    mi = rec.marker_index.copy()
    tail = rec.t >= t0
    ia, ib = tail & (mi == a), tail & (mi == b)
    mi[ia], mi[ib] = b, a
    return _sorted(rec, mi)


def _add(rec, name, role, t, x, y):
    t = np.asarray(t, float)
    k = rec.n_markers
    fps = rec.fps
    extra = {}
    if rec.frame is not None:
        extra["frame"] = np.r_[rec.frame, np.rint(t * fps).astype(np.int64)]
    if rec.sigma is not None:
        extra["sigma"] = np.r_[rec.sigma, np.full(t.size, float(np.nanmedian(rec.sigma)))]
    return rec.with_(markers=rec.markers + (name,), roles=rec.roles + (role,),
                     marker_index=np.r_[rec.marker_index, np.full(t.size, k)],
                     t=np.r_[rec.t, t], x=np.r_[rec.x, np.broadcast_to(x, t.shape)],
                     y=np.r_[rec.y, np.broadcast_to(y, t.shape)], **extra)


def _clean(rng):
    from fitlug.io import read_rig, read_trajectories
    from fitlug.sim import Scenario, rig_of, simulate

    if rng.random() < 0.4:
        return (read_trajectories(os.path.join(REF, "trajectories.csv")),
                read_rig(os.path.join(REF, "rig.toml")), "reference")
    kw = {"fps": float(rng.choice([100.0, 200.0, 500.0])),
          "lug_markers": int(rng.integers(4, 11)), "lug_spacing": int(rng.integers(1, 3)),
          "noise_lug_mm": float(rng.choice([0.0065, 0.02])),
          "noise_body_mm": float(rng.choice([0.0041, 0.015]))}
    if kw["fps"] > 100:
        kw.update(duration_s=3.0, travel_mm=350.0, rest_s=0.3, ramp_s=0.6)
    if rng.random() < 0.3:
        kw["body_markers"] = ((-60.0, 75.0), (0.0, 90.0), (60.0, 75.0))
    sc = Scenario(**kw)
    rec, _ = simulate(sc, seed=int(rng.integers(1 << 30)))
    return rec, rig_of(sc), f"sim {kw}"


def case(seed: int):
    """(clean recording, rig, faulty recording, faults applied, expect 'twin'|'refused')."""
    rng = np.random.default_rng(seed)
    clean, rig, what = _clean(rng)
    if rng.random() < 0.3:  # what a real camera and tracker deliver (tests/realism.py)
        from realism import realistic

        clean, _ = realistic(clean, seed=int(rng.integers(1 << 30)),
                             fov_mm=[None, 637.0, 450.0][int(rng.integers(3))])
        what += " + realism"
    rec, faults = clean, []
    bodies = [m for m, r in enumerate(rec.roles) if r == "body"]
    times = np.unique(rec.t)
    valid = rec.valid
    n_swaps = int(rng.integers(0, 3))
    for _ in range(n_swaps):
        k = int(rng.integers(len(times) // 10, 9 * len(times) // 10))
        role = "lug" if rng.random() < 0.8 else "body"
        # two markers of the role seen in the frame before and at the swap
        seen = [m for m, r in enumerate(rec.roles) if r == role
                and all(np.any(valid & (rec.marker_index == m) & (rec.t == times[j]))
                        for j in (k - 2, k - 1, k, k + 1))]
        if len(seen) < 2:
            continue
        a, b = rng.choice(seen, 2, replace=False)
        rec = _swap(rec, int(a), int(b), float(times[k]))
        valid = rec.valid
        faults.append(f"swap {rec.markers[a]}/{rec.markers[b]}@{times[k]:g}")
    longest = max(bodies, key=lambda m: int(np.sum(clean.marker_index == m)))
    b0 = (clean.marker_index == longest) & clean.valid
    tb, xb = clean.t[b0], clean.x[b0]
    k0 = int(rng.integers(len(times) // 5, 3 * len(times) // 5))
    if rng.random() < 0.4:  # a reflection tracked as a lug, above the track
        t = times[k0:k0 + int(rng.integers(3, 8))]
        X = float(np.interp(t[0], tb, xb))
        rec = _add(rec, "B99", "lug", t, X + rng.uniform(-150, 150), rng.uniform(90, 200))
        faults.append("lug reflection")
    if rng.random() < 0.4:  # a static reflection labelled body
        t = times[k0:k0 + int(rng.integers(3, 120))]
        X = float(np.interp(t[0], tb, xb))
        rec = _add(rec, "C99", "body", t, X + rng.uniform(-100, 100), rng.uniform(0, 100))
        faults.append("static body reflection")
    if rng.random() < 0.5:
        rec = rec.with_(x=-rec.x)
        faults.append("towards -x")
    if rng.random() < 0.4:
        rec = rec.with_(y=-rec.y)
        faults.append("y down")
    if rng.random() < 0.2:
        rec = rec.with_(x=rec.y, y=rec.x)
        faults.append("x, y swapped")
    expect = "twin"
    if rng.random() < 0.1:
        T = float(rec.t.max() - rec.t.min()) + float(times[1] - times[0])
        rec = _sorted(rec.with_(t=np.r_[rec.t, rec.t + T],
                                marker_index=np.r_[rec.marker_index, rec.marker_index],
                                x=np.r_[rec.x, rec.x], y=np.r_[rec.y, rec.y],
                                frame=None if rec.frame is None else np.r_[
                                    rec.frame, rec.frame + int(rec.frame.max()) + 1],
                                sigma=None if rec.sigma is None else np.r_[rec.sigma, rec.sigma]),
                      np.r_[rec.marker_index, rec.marker_index])
        faults.append("second run appended")
        expect = "refused"
    return clean, rig, rec, faults, expect, what


def run_case(seed: int, folder: str) -> tuple[str, str]:
    from fitlug._errors import InputError
    from fitlug.fit._prepare import prepare
    from fitlug.io import read_trajectories, write_trajectories

    clean, rig, rec, faults, expect, what = case(seed)
    path = os.path.join(folder, f"case{seed}.csv")
    write_trajectories(path, rec)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        want, _ = prepare(clean, rig)
        try:
            got, found = prepare(read_trajectories(path), rig)
        except InputError as exc:
            ok = expect == "refused" and "\n" not in str(exc)
            return ("refused" if ok else "WRONG"), f"{seed} {faults}: {exc}"
        except Exception as exc:  # noqa: BLE001 - counted, with the case to rebuild it
            return "WRONG", f"{seed} {faults}: {type(exc).__name__}: {exc}"
    if expect == "refused":
        return "WRONG", f"{seed} {faults}: not refused ({what})"
    same = (got.markers == want.markers and got.roles == want.roles
            and np.array_equal(got.marker_index, want.marker_index)
            and np.allclose(got.x, want.x, atol=1e-9, equal_nan=True)
            and np.allclose(got.y, want.y, atol=1e-9, equal_nan=True))
    if not same:
        return "WRONG", (f"{seed} {faults}: not the clean twin; swaps {found['swaps']}, "
                         f"excluded {[e['marker'] for e in found['excluded']]} ({what})")
    return "twin", ""


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=300, help="cases (default 300)")
    ap.add_argument("--first-seed", type=int, default=0)
    args = ap.parse_args(argv)
    counts: collections.Counter = collections.Counter()
    examples: dict = {}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bench_silent_") as folder:
        for seed in range(args.first_seed, args.first_seed + args.n):
            outcome, detail = run_case(seed, folder)
            counts[outcome] += 1
            if outcome == "WRONG" and len(examples.setdefault(outcome, [])) < 10:
                examples[outcome].append(detail)
    dt = time.perf_counter() - t0
    print(f"{args.n} cases in {dt:.1f} s: " + ", ".join(f"{k} {v}" for k, v in
                                                          sorted(counts.items())))
    for detail in examples.get("WRONG", []):
        print("  WRONG", detail)
    return 1 if counts["WRONG"] else 0


if __name__ == "__main__":
    sys.exit(main())
