"""`fit-lug trajectories.csv`: fit, explain, sample the posterior, write fit.json and the report."""

from __future__ import annotations

import argparse
import os
import time

from . import _outdir
from ._common import (check_out_folder, positive_seconds, progress_enabled, progress_lines,
                      recording_name, say, seed_arg, stage)


GUARD_S = 900.0  # fitlug.posterior._mcmc.GUARD_S (not imported: the command starts cheap)
#: draw the report in a process of its own (fitlug.report._aside), which imports the
#: report's modules while the fit runs: set by the `fit-lug` executable
#: (fitlug.cli.executable_setup); main() called in-process (tests, library callers) draws
#: it in the calling process, its modules imported in a thread meanwhile, as before
REPORT_PROCESS = False
#: samples (marker x frame) above which the report is drawn in the fitting process all the
#: same: a second process holds its own imports (~220 MB) and copies of the state's
#: arrays, where a long recording's run lasts minutes and a second saved is nothing
REPORT_PROCESS_MAX_SAMPLES = 200_000
#: compile the later stages' programs in a thread while the solver's compiles, on a first
#: run (fitlug.cli._prewarm): set by the `fit-lug` executable, like REPORT_PROCESS (a
#: library caller's process is not given a thread that outlives the call)
PREWARM = False
#: samples above which it does not: the thread holds a second problem and the posterior's
#: dense Jacobian at the start (~80 MB here) beside the fit's own
PREWARM_MAX_SAMPLES = 50_000


def _report_process(rec) -> bool:
    """Whether the report is drawn by a process of its own (fitlug.report._aside): in the
    executable, for a recording of at most REPORT_PROCESS_MAX_SAMPLES samples, unless
    FITLUG_REPORT_PROCESS=0 (a machine short of memory: ~100 MB more at the peak)."""
    return (REPORT_PROCESS and os.environ.get("FITLUG_REPORT_PROCESS") != "0"
            and len(rec.t) <= REPORT_PROCESS_MAX_SAMPLES)


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
    p.add_argument("--mcmc-budget", type=positive_seconds, default=GUARD_S, metavar="S",
                   help="wall-time guard of the sampler in seconds (default 900), reached only "
                        "when something is wrong: the chain stops on effective samples, the "
                        "same on any machine")
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
    with _outdir.locked(out, run_id, "--out" if args.out else "output folder"), \
            progress_lines(args):
        return _run(args, rec, rig, out, run_id, t_start)


def _frames(rec) -> int:
    """The recording's frame count (distinct times), for the fitting line."""
    import numpy as np

    return int(np.unique(np.asarray(rec.t)).size) if hasattr(rec, "t") else 0


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
    prog = progress_enabled(args)

    stage(args, "fitting", f"{len(rec.markers)} markers, {_frames(rec)} frames")
    aside = None
    preload = not args.no_report
    if preload and _report_process(rec):
        from ..report._aside import ReportProcess

        aside = ReportProcess()  # imports the report's modules on the other core meanwhile
        preload = False
    elif preload:
        from ..report import _preload

        _preload.start()  # the report's imports, in a thread while the fit runs
    try:
        return _fit_and_write(args, rec, rig, out, run_id, t_start, prog, preload, aside)
    finally:
        if aside is not None:
            aside.close()


def _fit_and_write(args, rec, rig, out, run_id, t_start, prog, preload, aside) -> int:
    from .._errors import FitError
    from ..fit import fit
    from ..io import write_json

    from . import _prewarm

    # a first run: the later stages' programs compile beside the solver's (cli._prewarm)
    warm = (_prewarm.arm(rec, rig, explain=not args.no_explain)
            if PREWARM and len(rec.t) <= PREWARM_MAX_SAMPLES else None)
    try:
        res = fit(rec, rig)
    finally:
        if warm is not None:
            warm.disarm()
    final, expl = res, None
    if not args.no_explain:
        stage(args, "explaining", f"base fit chi2/dof {res.chi2_per_dof:.3f}; looking for "
                                  "left-out physics")
        from ..explain import explain

        expl = explain(res, seed=args.seed, progress=prog)
        final = expl.final
    if warm is not None:  # the posterior's programs while the report's early parts draw
        warm.posterior(final, chain=not args.no_mcmc)
    disc = None if expl is None else expl.to_json()
    state = None  # (arrays, meta) of the report's state without the posterior
    if aside is not None:
        state = _draw_early(aside, final, expl, disc, args)
    post, no_chain = None, None  # no_chain: why no posterior could be formed
    if not args.no_mcmc:
        stage(args, "sampling", "posterior (emcee), until the effective samples suffice")
        from ..posterior import _mcmc, sample_posterior

        # the executable's process never draws a report with ArviZ (it has a report
        # process, or no report): emcee without scipy.stats (posterior._mcmc.LEAN_IMPORT)
        _mcmc.LEAN_IMPORT = REPORT_PROCESS and (aside is not None or args.no_report)

        try:
            post = sample_posterior(final, seed=args.seed, progress=prog,
                                    time_budget_s=args.mcmc_budget)
        except FitError as exc:  # the fit and its explanation still stand: written
            no_chain = str(exc)
            stage(args, "sampling", f"no posterior: {no_chain}")

    if post is None:
        from ..posterior import least_squares_identifiability

        try:
            unident = least_squares_identifiability(final, seed=args.seed)
        except FitError as exc:
            # the slip law's marginal cannot be formed: no error bar of the law is a
            # promise then, the slip's included (fit.json keeps the least-squares values)
            from ..posterior._derived import REPORTED

            no_chain = no_chain or str(exc)
            unident = dict.fromkeys(REPORTED, str(exc))
    else:
        unident = post.not_identifiable

    from ..report import fit_json

    doc = fit_json(final, input_path=args.csv,
                   posterior=None if post is None else post.estimates,
                   not_identifiable=unident,
                   uncertainty_method=None if post is None else post.uncertainty_method,
                   mcmc=None if post is None else post.mcmc_json(),
                   discrepancy=disc)
    if post is None:
        doc["mcmc"] = None
        why = "--no-mcmc" if args.no_mcmc and not no_chain else no_chain
        doc["mcmc_skipped"] = f"{why}: uncertainties are {doc['uncertainty_method']}"
    if args.no_explain:
        doc["discrepancy_skipped"] = "--no-explain"
    _display_keys(doc, args)
    doc["run_id"] = run_id
    doc["input_abs"] = os.path.abspath(args.csv)
    _outdir.clear_outputs(out)  # the folder holds this run's set only
    write_json(os.path.join(out, "fit.json"), doc)
    report = None
    if preload:
        from ..report import _preload

        _preload.wait()
    if post is not None:
        post.save(os.path.join(out, "posterior.nc"), run_id=run_id)
    if not args.no_report:
        stage(args, "report", os.path.join(out, "report.html"))
        from ..report import save_state, write_report

        if state is None:
            save_state(out, final, posterior=post, explanation=expl, run_id=run_id)
        else:  # the arrays drawn early, with the posterior's added: save_state's file
            from ..report._state import add_posterior, write_state

            arrays, meta = state
            if post is not None:
                add_posterior(arrays, meta, post)
            write_state(out, arrays, meta, run_id)
        report = write_report(out) if aside is None else aside.render(out)
    _summary(args, doc, out, report, time.perf_counter() - t_start)
    return 0


def _draw_early(aside, final, expl, disc, args):
    """Hand the report's process the parts of the page that the posterior does not change
    (fitlug.report._page.EARLY), to draw while the posterior is sampled; returns the
    state's (arrays, meta) without the posterior, or None where they could not be made
    (the report is then drawn whole at the end, as without the early parts)."""
    import logging

    from ..report import fit_json
    from ..report._state import state_arrays

    try:
        arrays, meta = state_arrays(final, None, expl)
        aside.draw_early(fit_json(final, input_path=args.csv, discrepancy=disc), arrays, meta)
    except Exception as exc:  # noqa: BLE001 - an accelerator only: the end draws it all
        logging.getLogger("fitlug.report").debug("early report parts not drawn: %s", exc)
        return None
    return arrays, meta


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
    if getattr(args, "mcmc_budget", GUARD_S) != GUARD_S:
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


def _summary(args, doc, out, report, seconds):
    from ..report._summary import summary_lines

    lines = summary_lines(doc)
    lines.append(f"  wrote {os.path.join(out, 'fit.json')}" + (f" and {report}" if report else "")
                 + f"  ({seconds:.1f} s)")
    say(args, *lines)

