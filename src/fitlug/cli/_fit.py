"""`fit-lug trajectories.csv`: fit, explain, sample the posterior, write fit.json and the report."""

from __future__ import annotations

import argparse
import os
import time

from . import _outdir
from ._common import (check_out_folder, positive_seconds, progress_enabled, recording_name, say,
                      seed_arg, stage)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("csv", metavar="TRAJECTORIES.csv", help="marker trajectories (DATA.md)")
    p.add_argument("--rig", help="rig.toml (default: one beside the CSV, else the reference rig)")
    p.add_argument("--out", help="output folder (default: fits/<recording name>/)")
    p.add_argument("--seed", type=seed_arg, default=0,
                   help="seed of every random step, 0 .. 2**32-1 (default 0)")
    p.add_argument("--no-mcmc", action="store_true", help="least squares only: no posterior")
    p.add_argument("--no-explain", action="store_true",
                   help="do not look for left-out physics (base model only)")
    p.add_argument("--no-report", action="store_true", help="write fit.json but no report.html")
    p.add_argument("--mcmc-budget", type=positive_seconds, default=60.0, metavar="S",
                   help="time budget of the sampler in seconds (default 60)")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")
    from ._import import add_source_options

    add_source_options(p)  # other trackers' files, converted on the way in


def run(args) -> int:
    from ..io import find_rig, read_rig

    t_start = time.perf_counter()
    stage(args, "reading", args.csv + _size_note(args.csv))
    rig = read_rig(args.rig) if args.rig else find_rig(args.csv)
    from ._import import recording_from_args

    rec = recording_from_args(args.csv, args, rig)
    out = args.out or _outdir.default_folder(args.csv, recording_name(args.csv))
    check_out_folder(out, "--out" if args.out else "output folder")
    run_id = _outdir.new_run_id()
    with _outdir.locked(out, run_id, "--out" if args.out else "output folder"):
        return _run(args, rec, rig, out, run_id, t_start)


def _size_note(path: str) -> str:
    """' (210 MB: about a minute)' for a large file, so a long read is not silence."""
    try:
        size = os.path.getsize(path)
    except OSError:
        return ""  # the reader names the problem
    if size < 10e6:
        return ""
    seconds = size / 1e7  # ~0.1 s a MB (csv module, one core)
    return f" ({size / 1e6:.0f} MB: about {seconds:.0f} s to read)"


def _run(args, rec, rig, out, run_id, t_start) -> int:
    from ..io import write_json

    prog = progress_enabled(args)

    stage(args, "fitting", f"{len(rec.markers)} markers; the first run compiles the model "
                           "(tens of seconds)")
    from ..fit import fit

    preload = not (args.no_report and args.no_mcmc)  # posterior.nc or the report follows
    if preload:
        from ..report import _preload

        _preload.start()  # the report's imports, while the fit runs

    res = fit(rec, rig)
    final, expl = res, None
    if not args.no_explain:
        stage(args, "explaining", f"base fit chi2/dof {res.chi2_per_dof:.3f}; looking for "
                                  "left-out physics")
        from ..explain import explain

        expl = explain(res, seed=args.seed, progress=prog)
        final = expl.final
    post = None
    if not args.no_mcmc:
        stage(args, "sampling", f"posterior (emcee), budget {args.mcmc_budget:g} s")
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
    _display_keys(doc, args)
    doc["run_id"] = run_id
    doc["input_abs"] = os.path.abspath(args.csv)
    _outdir.clear_outputs(out)  # the folder holds this run's set only
    write_json(os.path.join(out, "fit.json"), doc)
    report = None
    if preload:
        _preload.wait()
    if post is not None:
        post.save(os.path.join(out, "posterior.nc"), run_id=run_id)
    if not args.no_report:
        stage(args, "report", os.path.join(out, "report.html"))
        from ..report import save_state, write_report

        save_state(out, final, posterior=post, explanation=expl, run_id=run_id)
        report = write_report(out)
    _summary(args, doc, out, report, time.perf_counter() - t_start)
    return 0


def _command_line(args) -> str:
    """The fit's command line, rebuilt from the parsed options (not sys.argv, which is the
    caller's when fitlug.cli.main is called from Python)."""
    import shlex

    parts = ["fit-lug", args.csv]
    for opt, key in (("--rig", "rig"), ("--out", "out")):
        if getattr(args, key, None):
            parts += [opt, str(getattr(args, key))]
    if getattr(args, "seed", 0):
        parts += ["--seed", str(args.seed)]
    if getattr(args, "mcmc_budget", 60.0) != 60.0:
        parts += ["--mcmc-budget", f"{args.mcmc_budget:g}"]
    for opt in ("format", "fps", "mm_per_px", "calib", "body", "length_unit", "y_origin",
                "likelihood"):  # other trackers' files (cli/_import.py)
        if getattr(args, opt, None) is not None:
            parts += ["--" + opt.replace("_", "-"), f"{getattr(args, opt)}"]
    for flag in ("no_mcmc", "no_explain", "no_report"):
        if getattr(args, flag, False):
            parts.append("--" + flag.replace("_", "-"))
    return " ".join(shlex.quote(p) for p in parts)


def _display_keys(doc, args) -> None:
    """Display-only keys for the report's header: the command line and the date (UTC)."""
    import datetime

    doc.setdefault("command", _command_line(args))
    doc.setdefault("date_utc", datetime.datetime.now(datetime.timezone.utc)
                   .strftime("%Y-%m-%d %H:%M UTC"))


def _fmt(est, unit="", reason=None):
    from ..report._format import interval, pm

    if not est or est.get("value") is None:
        return "not identifiable" + (f": {reason}" if reason else "")
    ci = est.get("ci95") or [None, None]
    u = f" {unit}" if unit else ""
    return (f"{pm(est['value'], est.get('std'))}{u}   ({interval(ci[0], ci[1], est.get('std'))})")


def _summary(args, doc, out, report, seconds):
    from ..report._format import pm, sig, sigma_apart

    why = dict(doc.get("not_identifiable") or {})
    why.setdefault("stiffness_N_per_mm", "needs [vehicle] mass_kg in rig.toml")
    lines = [
        f"fitlug: {doc['input']}   (± is 1 sigma: {doc.get('uncertainty_method', '')})",
        f"  slip s0            {_fmt(doc['slip'], reason=why.get('slip'))}",
        f"  lug deflection Δl' {_fmt(doc['delta_l_mm'], 'mm', why.get('delta_l_mm'))}",
        f"  lug stiffness k    "
        f"{_fmt(doc['stiffness_N_per_mm'], 'N/mm', why.get('stiffness_N_per_mm'))}",
        f"  rolling resistance {_fmt(doc['rolling_resistance'], reason=why.get('rolling_resistance'))}",
        f"  chi2/dof           {doc['chi2_per_dof']:.3f}   (noise: body "
        f"{1000 * doc['noise_mm']['body']:.2f} µm, lug {1000 * doc['noise_mm']['lug']:.2f} µm)",
    ]
    applied = (doc.get("orientation") or {}).get("applied") or []
    if applied:
        lines.append("  axes               " + "; ".join(applied))
    for sw in doc.get("swaps") or []:
        lines.append(f"  identity swap      {' and '.join(sw['markers'])} from "
                     f"{sw['t_s']:g} s: repaired")
    for ex in doc.get("excluded") or []:
        lines.append(f"  kept out           {ex['marker']} ({ex['role']}, {ex['n_samples']} "
                     f"samples): {ex['reason']}")
    d = doc.get("discrepancy")
    if d:
        eff = d.get("effects") or []
        lines.append(f"  left-out physics   {d['verdict']}"
                     + (": " + ", ".join(e["id"] for e in eff) if eff else ""))
        for e in eff:
            std = e.get("params_std") or {}
            ps = ", ".join(f"{k} = " + (pm(v, std.get(k)) if v is not None else "n/a")
                           for k, v in (e.get("params") or {}).items())
            lines.append(f"    {e['id']}: {ps}")
        b, s = d.get("slip_before") or {}, doc.get("slip") or {}
        if eff and b.get("value") is not None and s.get("value"):
            lines.append(f"    slip without {'it' if len(eff) == 1 else 'them'} {pm(b['value'], b.get('std'))}: "
                         f"{sig(100 * (b['value'] - s['value']) / s['value'], 2)} %, "
                         f"{sigma_apart(b['value'], s.get('std'), s['value'])} the final value")
        for t in d.get("discovered") or []:
            lines.append(f"    {t['family']} ({t['coordinate']}){' partial' if t.get('partial') else ''}: "
                         f"chi2/dof {t['chi2_per_dof_before']:.3g} -> {t['chi2_per_dof_after']:.3g}, "
                         f"delta BIC {t['delta_bic']:.3g}: {t['reading']}")
        if d.get("verdict") == "unexplained":
            from ..report._section_discrepancy import handling_sentence, located_sentence

            import html

            lines.append("    " + html.unescape(located_sentence(d)))
            lines.append("    " + handling_sentence(d))
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
