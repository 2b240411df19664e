"""fitlug against the contact-dynamics engine's recordings (fitlug.sim.engine, MuJoCo).

Per recording in data/engine/<case>/ (or freshly simulated with --simulate): the library
as `fit-lug --no-mcmc` calls it (`fitlug.fit.fit`, then `fitlug.explain.explain`), and per
case the engine's slip (truth.json), the fitted slip +- its std (explain's final model),
z = (fit - engine) / std, std / s, chi2/dof before (base) and after (final), the verdict,
where the headline slip comes from ('model'; 'straight runs' where the model does not
describe the path and the slip is read off the top run and the body: explain._straight),
the catalog entries named and the family terms kept, and the seconds. Asserts nothing.

    python benchmarks/bench_engine.py [CASE ...] [--data data/engine] [--simulate]
        [--timeout 1800] [--log results.jsonl] [--workers N]

Per case also the CPU seconds of the fit and explanation (the process's own, each case in
its own spawned worker when --workers > 1, one XLA and one BLAS thread each) and, where the
headline is read off the straight runs, how ('belt clock': the lug markers' passages;
'top run': the top run's visits) and the lugs on the belt the passages counted.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "src"))


class _Timeout(Exception):
    pass


class _NotRead(Exception):
    """The explanation reads no slip (its reason in the row)."""


def _alarm(signum, frame):
    raise _Timeout()


def _kept_terms(ex) -> list[str]:
    try:
        terms = ex.discovered
        terms = terms() if callable(terms) else terms
    except Exception:  # noqa: BLE001 - an explain without discovery
        terms = None
    if terms is None:
        terms = getattr(getattr(ex, "discovery", None), "terms", None) or []
    out = []
    for t in terms:
        d = t if isinstance(t, dict) else (t.to_json() if hasattr(t, "to_json") else {})
        out.append(f"{d.get('family')}({d.get('coordinate')})")
    return out


def one(folder: str, timeout: float) -> dict:
    """Fit and explain one engine recording: a dict (never raises)."""
    from fitlug.explain import explain
    from fitlug.fit import fit
    from fitlug.io import read_rig, read_trajectories

    t0 = time.perf_counter()
    c0 = time.process_time()
    truth = json.load(open(os.path.join(folder, "truth.json")))
    out = {"case": os.path.basename(folder.rstrip("/")), "engine_slip": truth["slip"]}
    if timeout and hasattr(signal, "SIGALRM"):
        signal.signal(signal.SIGALRM, _alarm)
        signal.alarm(int(timeout))
    try:
        rig = read_rig(os.path.join(folder, "rig.toml"))
        rec = read_trajectories(os.path.join(folder, "trajectories.csv"), rig=rig)
        res = fit(rec, rig)
        out["chi2_before"] = float(res.chi2_per_dof)
        out["slip_base"] = float(res.slip.value)
        out["std_base"] = float(res.slip.std)
        ex = explain(res, seed=0)
        fin = ex.final
        if fin.slip.value is None:  # no slip read (explain._straight.far_from_data)
            out.update(verdict=ex.verdict, not_read=fin.slip.reason,
                       chi2_after=float(fin.chi2_per_dof))
            raise _NotRead()
        out.update(verdict=ex.verdict,
                   named=sorted(ex.effects) + [f"{st.effect} (base: marker on the lug)"
                                               for st in getattr(ex, "base_steps", [])],
                   kept=_kept_terms(ex),
                   chi2_after=float(fin.chi2_per_dof), slip=float(fin.slip.value),
                   std=float(fin.slip.std),
                   headline=(getattr(fin, "robust", None) or {}).get("headline") or "model")
        st = (getattr(fin, "robust", None) or {}).get("straight_runs") or {}
        other = st.get("top_run") or st.get("top_run_disagrees") or \
            st.get("belt_clock_rejected") or st.get("belt_clock") or {}
        out.update(straight_method=st.get("method"), lugs_on_belt=st.get("lugs_on_belt"),
                   window_s=st.get("window_s"), cruise_s=st.get("cruise_s"),
                   v_body=st.get("v_body_mm_s"), v_belt=st.get("v_belt_mm_s"),
                   v_body_window=st.get("v_body_window_mm_s"),
                   # the other reading beside the one taken (explain._straight.choose)
                   other_slip=other.get("slip"), other_std=other.get("std"),
                   top_run_disagrees="top_run_disagrees" in st,
                   belt_clock_rejected="belt_clock_rejected" in st)
        out["z"] = (out["slip"] - out["engine_slip"]) / out["std"] if out["std"] > 0 else None
    except _NotRead:
        out["error"] = f"no slip read: {out['not_read']}"[:300]
    except _Timeout:
        out["error"] = f"timeout after {timeout:g} s"
    except Exception as exc:  # noqa: BLE001 - a benchmark reports failures
        out["error"] = f"{type(exc).__name__}: {exc}"[:300]
    finally:
        if timeout and hasattr(signal, "SIGALRM"):
            signal.alarm(0)
    out["seconds"] = round(time.perf_counter() - t0, 1)
    out["cpu_seconds"] = round(time.process_time() - c0, 1)
    return out


def _row(r: dict) -> str:
    if "error" in r and "slip" not in r:
        base = (f" base {r['slip_base']:.4f}+-{r['std_base']:.4f} chi2 {r['chi2_before']:.2f}"
                if "slip_base" in r else "")
        return f"{r['case']:18s} {r['engine_slip']:.4f}{base}  {r['error']}  {r['seconds']:.0f} s"
    named = ",".join(r["named"] + r["kept"]) or "-"
    return (f"{r['case']:18s} {r['engine_slip']:.4f} {r['slip']:.4f}+-{r['std']:.4f} "
            f"{r['z']:7.1f} {r['std'] / r['slip']:6.3f} {r['chi2_before']:8.2f} "
            f"{r['chi2_after']:8.2f} {r['verdict']:12s} {r.get('headline', '-'):14s} "
            f"{r.get('straight_method') or '':10s} {named}  {r['seconds']:.0f} s "
            f"({r.get('cpu_seconds', 0):.0f} s CPU)")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cases", nargs="*")
    ap.add_argument("--data", default=os.path.join(HERE, "..", "data", "engine"))
    ap.add_argument("--simulate", action="store_true",
                    help="simulate the cases first (into --data)")
    ap.add_argument("--timeout", type=float, default=1800.0, help="seconds per case")
    ap.add_argument("--log", help="append one JSON line per case")
    ap.add_argument("--workers", type=int, default=1,
                    help="cases side by side in spawned workers")
    args = ap.parse_args(argv)
    if args.simulate:
        from fitlug.sim.engine import CASES, simulate_engine

        for name in args.cases or list(CASES):
            simulate_engine(CASES[name], os.path.join(args.data, name),
                            seed=1 + list(CASES).index(name))
    names = args.cases or sorted(d for d in os.listdir(args.data)
                                 if os.path.exists(os.path.join(args.data, d, "truth.json")))
    print(f"{'case':18s} {'engine':6s} {'fit +- std':15s} {'z':>7s} {'std/s':>6s} "
          f"{'chi2 bef':>8s} {'chi2 aft':>8s} {'verdict':12s} {'headline':14s} "
          f"{'how':10s} named  seconds",
          flush=True)
    folders = [os.path.join(args.data, name) for name in names]
    if args.workers > 1:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor, as_completed

        from _workers import one_thread_each

        one_thread_each()
        with ProcessPoolExecutor(args.workers,
                                 mp_context=multiprocessing.get_context("spawn")) as pool:
            futs = [pool.submit(one, f, args.timeout) for f in folders]
            results = (fu.result() for fu in as_completed(futs))
            _report(results, args.log)
    else:
        _report((one(f, args.timeout) for f in folders), args.log)
    return 0


def _report(results, log) -> None:
    for r in results:
        print(_row(r), flush=True)
        if log:
            with open(log, "a") as f:
                f.write(json.dumps(r, default=str) + "\n")


if __name__ == "__main__":
    sys.exit(main())
