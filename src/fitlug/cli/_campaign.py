"""`fit-lug campaign SOURCES...`: every recording fitted in full, then the track's slip law."""

from __future__ import annotations

import argparse
import os

from ._common import positive_seconds, progress_enabled, say, seed_arg


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("sources", nargs="+", metavar="SOURCE",
                   help="trajectories CSVs (rig.toml beside each), folders, glob patterns")
    p.add_argument("--out", help="output folder (default: fits/<first source's name>/)")
    p.add_argument("--scheduler", metavar="tcp://HOST:8786",
                   help="address of a running Dask scheduler (default: a local cluster)")
    p.add_argument("--workers", type=int, default=None,
                   help="local Dask worker processes (default: CPU cores, at most 4); "
                        "0: fit in this process without Dask")
    p.add_argument("--seed", type=seed_arg, default=0,
                   help="seed of every random step, 0 .. 2**32-1 (default 0)")
    p.add_argument("--no-mcmc", action="store_true",
                   help="no per-recording posterior (least-squares errors)")
    p.add_argument("--no-explain", action="store_true",
                   help="do not look for left-out physics in each recording")
    p.add_argument("--no-report", action="store_true", help="no per-recording report.html")
    p.add_argument("--no-resume", action="store_true",
                   help="refit every recording even when its inputs are unchanged")
    p.add_argument("--mcmc-budget", type=positive_seconds, default=900.0, metavar="S",
                   help="wall-time guard of each recording's sampler in seconds (default "
                        "900); the chain stops on effective samples, the same on any machine")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")


def _default_out(sources) -> str:
    first = os.path.normpath(sources[0])
    if any(c in first for c in "*?["):
        first = os.path.dirname(first.split("*")[0].split("?")[0].split("[")[0]) or "campaign"
    if os.path.isfile(first):
        first = os.path.dirname(os.path.abspath(first))
    return os.path.join("fits", os.path.basename(os.path.abspath(first)) or "campaign")


def run(args) -> int:
    from ..campaign import campaign

    out = args.out or _default_out(args.sources)
    workers = args.workers
    if workers is None:
        workers = min(os.cpu_count() or 1, 4)
    res = campaign(args.sources, out=out, scheduler=args.scheduler, workers=workers,
                   seed=args.seed, explain=not args.no_explain, mcmc=not args.no_mcmc,
                   report=not args.no_report, resume=not args.no_resume,
                   mcmc_budget=args.mcmc_budget, progress=progress_enabled(args))
    k = res.stiffness
    lines = [f"fitlug campaign: {len(res.recordings)} recordings -> {out}",
             f"  law                {res.law} (delta BIC sliding - linear = {res.delta_bic:.1f})",
             f"  lug stiffness k    {k['value']:.5g} ± {k['std']:.2g} N/mm "
             f"(95 %: {k['ci95'][0]:.5g} … {k['ci95'][1]:.5g})"]
    for g, e in res.rolling_resistance.items():
        lines.append(f"  C_rr [{g}]".ljust(21) + f"{e['value']:.5g} ± {e['std']:.2g}")
    for g, e in (res.F_max or {}).items():
        lines.append(f"  F_max [{g}]".ljust(21) + f"{e['value']:.5g} N "
                     f"(95 %: {e['ci95'][0]:.4g} … {e['ci95'][1]:.4g})")
    n_un = sum(r.status == "unchanged" for r in res.recordings)
    if n_un:
        lines.append(f"  unchanged          {n_un} recording(s) not refitted (resume)")
    for r in res.flagged:
        lines.append(f"  FLAGGED {r.name}: {r.reason}")
    for r in res.failed:
        lines.append(f"  FAILED  {r.name}: {r.error}")
    lines.append(f"  wrote {os.path.join(out, 'campaign.json')} and "
                 f"{os.path.join(out, 'campaign.html')}")
    say(args, *lines)
    if res.failed:  # the law stands on the others, but a failure is never an exit 0
        import sys

        names = ", ".join(r.name for r in res.failed)
        print(f"fit-lug: error: campaign: {len(res.failed)} of {len(res.recordings)} "
              f"recording(s) failed ({names}): the law is from the others; see "
              f"{os.path.join(out, 'campaign.json')} (failed) for each error",
              file=sys.stderr)
        return 1
    return 0
