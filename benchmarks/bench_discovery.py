"""Physics beyond the catalog (issue 28): is the right family kept? Prints a table; asserts
nothing.

    python benchmarks/bench_discovery.py [--n 20] [--mechanisms squat,flap,...]
        [--n-null N] [--catalog wheel_runout,...] [--n-catalog N] [--workers 2]
        [--log results.jsonl] [--from-log results.jsonl] [--task-timeout 1200]

Recordings come from tests/mechanisms.py (our own simulator with its own kinematics and
functional forms that differ from the families' splines and Fourier series): a drawn rig,
motion and mechanism size per seed, seen through tests/realism.py's `drive_through`
(a window of 300-637 mm that always sees a speed change, misses, occlusions, glitches,
ids split after gaps). Mechanisms (default: all of tests/mechanisms.py's): the issue's
squat, flap, cogging, bump and our slip_speed, idler_wobble, then carrier_roller,
lug_splay, keystone, frame_jitter, clock_wobble, frame_vibration and rail_bow (see
tests/mechanisms.py for their physics, sizes, family and coordinate), plus nulls (base
model) and catalog recordings (wheel_runout, belt_sag, lug_ripple, body_bounce).
Recording k of every kind uses seed `--seed0 + k`, so the kinds share rigs and motions.

Each recording goes through the default pipeline without the posterior: `fitlug.fit.fit`
then `fitlug.explain`. Per recording (one JSON line in `--log`, appended as it finishes;
a rerun with the same log skips what is there, so a run cut short resumes): the verdict,
the catalog entries named, the kept family terms (family, coordinate, partial,
chi2/dof after), chi2/dof before and after, the slip and its z = (slip - truth) / std.
"After" is the model with the kept family terms when there are any (`ex.discovery.final`),
else explain's final model (base + catalog); explain's final is logged too (`*_final`).
A recording that fails or passes `--task-timeout` seconds is a row with its error.

Per kind the table gives: n, failures, verdicts, right family kept (the truth's family
among the kept terms), right family and coordinate, a wrong family kept, median chi2/dof
after, the share with chi2/dof <= 1.3, mean and rms of the slip z and the share with
|z| <= 3. For nulls and catalog recordings "false alarm" is any family term kept (target
<= 2 %) and, for catalog recordings, "catalog" the share naming exactly the right entry.
Workers are spawned (JAX is never forked), at most 2.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import signal
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "src"))
sys.path.insert(0, os.path.join(HERE, "..", "tests"))

import mechanisms as M  # noqa: E402

MAX_WORKERS = 2

#: coordinate words -> canonical tokens (the explain side may spell them its own way)
_COORD = {"a": "a", "acceleration": "a", "psi": "psi", "belt travel": "psi", "belt": "psi",
          "t": "t", "time": "t", "xi": "xi", "x": "x", "ground x": "x", "ground": "x",
          "f": "F", "traction": "F", "v": "v", "speed": "v", "frequency": "t"}


def coord_tokens(coordinate) -> set:
    """Canonical tokens of a coordinate string such as 'xi,t', 'psi', 'a(t)', 'F, v'."""
    if coordinate is None:
        return set()
    out = set()
    for part in str(coordinate).replace(";", ",").replace("+", ",").replace(" and ", ",") \
            .split(","):
        w = part.strip().lower()
        w = w.split("(")[0].strip() or w
        w = {"ψ": "psi", "ξ": "xi"}.get(w, w)
        out.add(_COORD.get(w, w))
    return out


def _terms(ex) -> list:
    """The kept family terms of an Explanation as dicts (family, coordinate, partial, ...):
    `ex.discovered` (fit.json's `discrepancy.discovered`), else `ex.discovery.terms`."""
    try:
        terms = ex.discovered
        terms = terms() if callable(terms) else terms
    except Exception:  # noqa: BLE001 - an older explain: the search's own terms
        terms = None
    if terms is None:
        terms = getattr(getattr(ex, "discovery", None), "terms", None) or []
    keep = ("family", "coordinate", "partial", "chi2_per_dof_after", "delta_bic",
            "frequency_hz", "segment", "axis", "reading")
    out = []
    for term in terms:
        if not isinstance(term, dict):
            term = term.to_json() if hasattr(term, "to_json") else {
                k: getattr(getattr(term, "choice", term), k, getattr(term, k, None))
                for k in keep}
        out.append({k: _plain(term.get(k)) for k in keep})
    return out


def _plain(v):
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    if isinstance(v, (str, int, float, bool)) or v is None:
        return v
    return str(v)


class _Timeout(Exception):
    pass


def _alarm(signum, frame):
    raise _Timeout()


def one(task):
    """Make, fit and explain one recording: a dict (never raises)."""
    kind, seed, timeout = task
    t0 = time.perf_counter()
    out = {"kind": kind, "seed": seed}
    if timeout and hasattr(signal, "SIGALRM"):
        signal.signal(signal.SIGALRM, _alarm)
        signal.alarm(int(timeout))
    try:
        from fitlug.explain import explain
        from fitlug.fit import fit

        rec, rig, truth = M.make(kind, seed)
        out.update(family=truth["family"], coordinate=truth["coordinate"],
                   catalog=truth["catalog"], truth=truth["slip"], fps=truth["fps"],
                   truth_s0=truth["slip_linear_s0"],
                   window=truth["window"],
                   params={k: v for k, v in truth["params"].items()
                           if isinstance(v, (int, float))})
        res = fit(rec, rig)
        out["chi2_base"] = float(res.chi2_per_dof)
        ex = explain(res)
        fin = ex.final
        disc = getattr(ex, "discovery", None)
        dfin = getattr(disc, "final", None)
        out.update(verdict=ex.verdict, named=sorted(ex.effects), terms=_terms(ex),
                   chi2_before=float(ex.base.chi2_per_dof),
                   chi2_final=float(fin.chi2_per_dof), slip_final=float(fin.slip.value),
                   std_final=float(fin.slip.std), why_not=getattr(disc, "why_not", None))
        # "after": under the extended model when a family term was kept (explain's final
        # may or may not be it, depending on the verdict), else explain's final
        last = dfin if (dfin is not None and out["terms"]) else fin
        out.update(chi2_after=float(last.chi2_per_dof), slip=float(last.slip.value),
                   std=float(last.slip.std))
        out["z"] = (out["slip"] - out["truth"]) / out["std"] if out["std"] > 0 else None
    except _Timeout:
        out["error"] = f"timeout after {timeout} s"
    except Exception as exc:  # noqa: BLE001 - a benchmark counts failures
        out["error"] = f"{type(exc).__name__}: {exc}"[:300]
    finally:
        if timeout and hasattr(signal, "SIGALRM"):
            signal.alarm(0)
    out["seconds"] = round(time.perf_counter() - t0, 1)
    return out


def _num(v):
    return f"{v:.2f}" if abs(v) < 1000 else f"{v:.2e}"


def _pct(k, n):
    return f"{k}/{n}" if n else "-"


def summarise(results, kinds=None, file=sys.stdout):
    """The table (markdown) of a list of result dicts."""
    kinds = kinds or sorted({r["kind"] for r in results}, key=lambda k: (
        M.ALL.index(k) if k in M.ALL else 99, k))
    p = lambda *a: print(*a, file=file)  # noqa: E731
    p("| kind | family (coordinate) | n | fail | verdicts | right family | + coordinate "
      "| wrong family | false alarm | catalog | chi2/dof after (median) | <= 1.3 "
      "| slip z mean | rms | abs z <= 3 |")
    p("|" + "---|" * 15)
    for kind in kinds:
        rs = [r for r in results if r["kind"] == kind]
        ok = [r for r in rs if "error" not in r]
        n = len(ok)
        fam = M.FAMILIES.get(kind, (None, None))
        verdicts = {}
        for r in ok:
            verdicts[r["verdict"]] = verdicts.get(r["verdict"], 0) + 1
        vtxt = " ".join(f"{k}:{v}" for k, v in sorted(verdicts.items())) or "-"
        right = rc = wrong = fa = cat = 0
        for r in ok:
            fams = [t["family"] for t in r["terms"]]
            if fam[0] is not None:
                hit = [t for t in r["terms"] if t["family"] == fam[0]]
                right += bool(hit)
                rc += any(coord_tokens(t["coordinate"]) & coord_tokens(fam[1]) for t in hit)
                wrong += any(f != fam[0] for f in fams)
            else:
                fa += bool(fams)
                cat += r["named"] == ([kind] if kind in M.CATALOG_CASES else [])
        chi = np.array([r["chi2_after"] for r in ok])
        z = np.array([r["z"] for r in ok if r.get("z") is not None])
        is_mech = fam[0] is not None
        p(f"| {kind} | {fam[0] or '-'} ({fam[1] or '-'}) | {n} | {len(rs) - n} | {vtxt} | "
          f"{_pct(right, n) if is_mech else '-'} | {_pct(rc, n) if is_mech else '-'} | "
          f"{_pct(wrong, n) if is_mech else '-'} | {'-' if is_mech else _pct(fa, n)} | "
          f"{_pct(cat, n) if kind in M.CATALOG_CASES else '-'} | "
          f"{_num(np.median(chi))} | {_pct(int(np.sum(chi <= 1.3)), n)} | "
          f"{z.mean():+.2f} | {np.sqrt(np.mean(z ** 2)):.2f} | "
          f"{_pct(int(np.sum(np.abs(z) <= 3)), len(z))} |" if n else
          f"| {kind} | - | 0 | {len(rs)} |" + " - |" * 11)
    errs = [r for r in results if "error" in r]
    for r in errs[:12]:
        p(f"\nfailure {r['kind']} seed {r['seed']}: {r['error']}")


def _read_log(path):
    if not path or not os.path.exists(path):
        return []
    out = []
    with open(path) as fh:
        for line in fh:
            line = line.strip()
            if line:
                try:
                    out.append(json.loads(line))
                except json.JSONDecodeError:  # a line cut by a kill: that task reruns
                    pass
    return out


def _stop_workers_on_term(ex) -> None:
    """On SIGTERM (kill, pkill) stop the spawned workers too: they are processes of their
    own and would go on fitting after the parent is gone."""
    def stop(signum, frame):
        for proc in list(getattr(ex, "_processes", {}).values()):
            proc.terminate()
        raise SystemExit(128 + signum)
    signal.signal(signal.SIGTERM, stop)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=20, help="recordings per mechanism")
    ap.add_argument("--mechanisms", default=",".join(M.MECHANISMS))
    ap.add_argument("--n-null", type=int, default=None, help="null recordings (default --n)")
    ap.add_argument("--catalog", default=",".join(M.CATALOG_CASES))
    ap.add_argument("--n-catalog", type=int, default=None,
                    help="recordings per catalog entry (default --n // 4, at least 1)")
    ap.add_argument("--workers", type=int, default=2, help=f"at most {MAX_WORKERS}")
    ap.add_argument("--seed0", type=int, default=1000)
    ap.add_argument("--task-timeout", type=int, default=1200,
                    help="seconds per recording before it counts as a failure")
    ap.add_argument("--log", default=None, help="JSON lines, appended; reused to resume")
    ap.add_argument("--from-log", default=None, help="summarise a log, no new fits")
    ap.add_argument("--summary", default=None, help="also write the table to this file")
    a = ap.parse_args(argv)
    if a.from_log:
        results = _read_log(a.from_log)
        print(f"{len(results)} recordings from {a.from_log}")
        summarise(results)
        return
    mechs = [m for m in a.mechanisms.split(",") if m]
    cats = [c for c in a.catalog.split(",") if c]
    for k in mechs + cats:
        if k not in M.ALL:
            ap.error(f"unknown kind {k!r}; known: {', '.join(M.ALL)}")
    n_null = a.n if a.n_null is None else a.n_null
    n_cat = max(1, a.n // 4) if a.n_catalog is None else a.n_catalog
    tasks = [(k, a.seed0 + i) for k in mechs for i in range(a.n)]
    tasks += [("null", a.seed0 + i) for i in range(n_null)]
    tasks += [(c, a.seed0 + i) for c in cats for i in range(n_cat)]
    tasks.sort(key=lambda t: (t[1], t[0]))  # a run cut short has a bit of every kind
    done = _read_log(a.log)
    have = {(r["kind"], r["seed"]) for r in done}
    todo = [(k, s, a.task_timeout) for k, s in tasks if (k, s) not in have]
    print(f"{len(tasks)} recordings, {len(tasks) - len(todo)} already in the log",
          flush=True)
    log = open(a.log, "a") if a.log else None
    results = [r for r in done if (r["kind"], r["seed"]) in set(tasks)]

    def keep(r):
        print(f"  {r['kind']:13s} seed {r['seed']}: {r.get('verdict', r.get('error'))} "
              f"terms {[t['family'] for t in r.get('terms', [])]} "
              f"chi2 {r.get('chi2_after', float('nan')):.2f} ({r['seconds']:.0f} s)",
              flush=True)
        if log is not None:
            log.write(json.dumps(r) + "\n")
            log.flush()
        results.append(r)

    t0 = time.perf_counter()
    workers = max(1, min(a.workers, MAX_WORKERS))
    if workers > 1 and len(todo) > 1:
        from _workers import one_thread_each

        one_thread_each()
        ctx = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(workers, mp_context=ctx) as ex:
            _stop_workers_on_term(ex)
            futures = {ex.submit(one, t): t for t in todo}
            for f in as_completed(futures):
                try:
                    keep(f.result())
                except Exception as exc:  # noqa: BLE001 - a dead worker is a row too
                    k, s, _ = futures[f]
                    keep({"kind": k, "seed": s, "error": f"worker: {exc}"[:300],
                          "seconds": 0.0})
    else:
        for t in todo:
            keep(one(t))
    if log is not None:
        log.close()
    print(f"{len(todo)} recordings in {time.perf_counter() - t0:.0f} s with {workers} "
          f"worker(s)\n")
    summarise(results)
    if a.summary:
        with open(a.summary, "w") as fh:
            summarise(results, file=fh)


if __name__ == "__main__":
    main()
