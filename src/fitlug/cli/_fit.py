"""`fit-lug trajectories.csv`: fit, explain, sample the posterior, write fit.json and the report."""

from __future__ import annotations

import argparse
import os
import time

from ._common import progress_enabled, recording_name, say


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("csv", metavar="TRAJECTORIES.csv", help="marker trajectories (DATA.md)")
    p.add_argument("--rig", help="rig.toml (default: one beside the CSV, else the reference rig)")
    p.add_argument("--out", help="output folder (default: fits/<recording name>/)")
    p.add_argument("--seed", type=int, default=0, help="seed of every random step (default 0)")
    p.add_argument("--no-mcmc", action="store_true", help="least squares only: no posterior")
    p.add_argument("--no-explain", action="store_true",
                   help="do not look for left-out physics (base model only)")
    p.add_argument("--no-report", action="store_true", help="write fit.json but no report.html")
    p.add_argument("--mcmc-budget", type=float, default=60.0, metavar="S",
                   help="time budget of the sampler in seconds (default 60)")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")


def run(args) -> int:
    from ..io import find_rig, read_rig, read_trajectories, write_json

    t_start = time.perf_counter()
    rig = read_rig(args.rig) if args.rig else find_rig(args.csv)
    rec = read_trajectories(args.csv, rig=rig)
    out = args.out or os.path.join("fits", recording_name(args.csv))
    prog = progress_enabled(args)

    from ..fit import fit

    res = fit(rec, rig)
    final, expl = res, None
    if not args.no_explain:
        from ..explain import explain

        expl = explain(res, seed=args.seed, progress=prog)
        final = expl.final
    post = None
    if not args.no_mcmc:
        from ..posterior import sample_posterior

        post = sample_posterior(final, seed=args.seed, progress=prog,
                                time_budget_s=args.mcmc_budget)

    if post is None:
        from ..posterior import least_squares_identifiability

        unident = least_squares_identifiability(final, seed=args.seed)
    else:
        unident = post.not_identifiable

    from ..report import fit_json

    doc = fit_json(final, input_path=args.csv,
                   posterior=None if post is None else post.estimates,
                   not_identifiable=unident,
                   uncertainty_method=None if post is None else post.uncertainty_method,
                   mcmc=None if post is None else post.mcmc_json(),
                   discrepancy=None if expl is None else expl.to_json())
    if post is None:
        doc["mcmc"] = None
        doc["mcmc_skipped"] = f"--no-mcmc: uncertainties are {doc['uncertainty_method']}"
    if args.no_explain:
        doc["discrepancy_skipped"] = "--no-explain"
    os.makedirs(out, exist_ok=True)
    write_json(os.path.join(out, "fit.json"), doc)
    report = None
    if post is not None:
        post.save(os.path.join(out, "posterior.nc"))
    if not args.no_report:
        from ..report import save_state, write_report

        save_state(out, final, posterior=post, explanation=expl)
        report = write_report(out)
    _summary(args, doc, out, report, time.perf_counter() - t_start)
    return 0


def _fmt(est, digits=4, reason=None):
    if not est:
        return "not identifiable" + (f": {reason}" if reason else "")
    return f"{est['value']:.{digits}g} ± {est['std']:.2g}  (95 %: {est['ci95'][0]:.{digits}g} … {est['ci95'][1]:.{digits}g})"


def _summary(args, doc, out, report, seconds):
    why = doc.get("not_identifiable") or {}
    lines = [
        f"fitlug: {doc['input']}",
        f"  slip s0            {_fmt(doc['slip'], reason=why.get('slip'))}",
        f"  lug deflection Δl' {_fmt(doc['delta_l_mm'], reason=why.get('delta_l_mm'))}" + (" mm" if doc["delta_l_mm"] else ""),
        f"  lug stiffness k    {_fmt(doc['stiffness_N_per_mm'], reason=why.get('stiffness_N_per_mm'))}" + (" N/mm" if doc["stiffness_N_per_mm"] else ""),
        f"  rolling resistance {_fmt(doc['rolling_resistance'], reason=why.get('rolling_resistance'))}",
        f"  chi2/dof           {doc['chi2_per_dof']:.3f}   (noise: body {doc['noise_mm']['body']:.4f} mm, lug {doc['noise_mm']['lug']:.4f} mm)",
    ]
    if doc.get("uncertainty_method", "").find("tempered") >= 0 or "robust" in doc.get("uncertainty_method", ""):
        lines.append(f"  uncertainty        {doc['uncertainty_method']}")
    d = doc.get("discrepancy")
    if d:
        eff = ", ".join(e["id"] for e in d.get("effects", [])) or "-"
        lines.append(f"  left-out physics   {d['verdict']}" + (f": {eff}" if d.get("effects") else ""))
    m = doc.get("mcmc")
    if m:
        lines.append(f"  posterior          {m.get('walkers')} walkers × {m.get('steps')} steps, "
                     f"ESS {_int(m.get('ess'))}, " + ("converged" if m.get("converged") else "NOT converged"))
    lines.append(f"  wrote {os.path.join(out, 'fit.json')}" + (f" and {report}" if report else "")
                 + f"  ({seconds:.1f} s)")
    say(args, *lines)


def _int(x):
    try:
        return f"{float(x):.0f}"
    except (TypeError, ValueError):
        return str(x)
