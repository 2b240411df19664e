"""The `fit-lug` command: a thin layer over the library.

``fit-lug trajectories.csv [...]`` fits a recording (the default sub-command);
``fit-lug SUBCOMMAND ...`` runs one of the others. Each sub-command lives in its own
module ``fitlug.cli._<name>`` with ``add_arguments(parser)`` and ``run(args) -> int``,
imported only when it is used so that start-up stays cheap.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from .._version import __version__

# name -> (module, one-line help)
SUBCOMMANDS = {
    "fit": ("_fit", "fit a recording (trajectories.csv) and write fit.json and the report"),
    "simulate": ("_simulate", "write a simulated recording (and optionally its video)"),
    "report": ("_report", "rebuild report.html from a fit folder"),
    "track": ("_track", "track the markers in a video, frame folder or .cine file"),
    "calibrate": ("_calibrate", "calibrate the camera from board images -> calib.json"),
    "campaign": ("_campaign", "fit a campaign of recordings: the track's traction-slip law"),
    "noise": ("_noise", "measurement noise per marker type from a stationary recording"),
    "import": ("_import", "convert another tracker's export (Tracker, DLTdv, Kinovea, "
                          "DeepLabCut, trackpy) to trajectories.csv"),
}


def _build_parser(name: str) -> argparse.ArgumentParser:
    module, help_ = SUBCOMMANDS[name]
    prog = "fit-lug" if name == "fit" else f"fit-lug {name}"
    parser = argparse.ArgumentParser(prog=prog, description=help_)
    parser.add_argument("--version", action="version", version=f"fitlug {__version__}")
    mod = importlib.import_module(f"{__name__}.{module}")
    mod.add_arguments(parser)
    return parser, mod


def _top_help() -> str:
    lines = [
        "usage: fit-lug TRAJECTORIES.csv [--rig RIG] [--out DIR] [options]",
        "       fit-lug SUBCOMMAND [options]",
        "",
        "Measure and explain the slippage of a rubber track from marker trajectories.",
        "",
        "sub-commands:",
    ]
    for name, (_, help_) in SUBCOMMANDS.items():
        lines.append(f"  {name:<10} {help_}")
    lines += ["", "`fit-lug SUBCOMMAND --help` (or `fit-lug fit --help`) for the options of each.",
              "options: -h/--help, --version"]
    return "\n".join(lines)


def _one_line_warning(message, category, filename, lineno, line=None) -> str:
    text = " ".join(str(message).split())
    kind = "" if category is UserWarning else f"{category.__name__}: "
    return f"fit-lug: warning: {kind}{text}\n"


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """fitlug's own warnings on stderr, one line each; a third-party library's (raised in
    its own code: ArviZ's refactor notice, numpy's 'invalid value') to the log, the
    logger ``fitlug.third_party`` at DEBUG, not the terminal (FITLUG_WARNINGS=all shows
    them too)."""
    import os

    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    ours = os.path.abspath(str(filename)).startswith(here + os.sep)
    if not ours and os.environ.get("FITLUG_WARNINGS") != "all":
        import logging

        logging.getLogger("fitlug.third_party").debug(
            "%s:%s: %s: %s", filename, lineno, category.__name__, message)
        return
    (file or sys.stderr).write(_one_line_warning(message, category, filename, lineno))


def _one_blas_thread() -> None:
    """numpy's OpenBLAS on one thread (unless the caller chose): its matrices here are
    small (~100 wide), and its idle threads spin while they wait: on the 2-core machine
    with other work (load 15-20), warm runs of the bundled recording took 12.9, 13.6 and
    16.9 s CPU with one thread against 18.0 and 15.5 s with the default, the same digits
    (issue 43; noisy figures: a modest gain, not a proven one). Only before numpy is
    imported (the command imports it later)."""
    import os

    if "numpy" not in sys.modules:
        for var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ.setdefault(var, "1")


def main(argv: list[str] | None = None) -> int:
    """Entry point of `fit-lug`; returns the process exit status."""
    from .._errors import FitlugError

    argv = list(sys.argv[1:] if argv is None else argv)
    _one_blas_thread()
    if not argv or argv[0] in ("-h", "--help"):
        print(_top_help())
        return 0 if argv else 2
    if argv[0] == "--version":
        print(f"fitlug {__version__}")
        return 0
    if argv[0] in SUBCOMMANDS:
        name, rest = argv[0], argv[1:]
    else:
        name, rest = "fit", argv
    parser, mod = _build_parser(name)
    args = parser.parse_args(rest)
    import warnings
    try:
        with warnings.catch_warnings():
            # a warning is one line too ("fit-lug: warning: file:line: ..."), not two
            warnings.formatwarning = _one_line_warning
            warnings.showwarning = _show_warning
            return int(mod.run(args) or 0)
    except FitlugError as exc:
        print(f"fit-lug: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("fit-lug: interrupted", file=sys.stderr)
        return 130


def entry() -> None:
    """The `fit-lug` executable (and ``python -m fitlug.cli``): :func:`executable_setup`,
    :func:`main`, then the process ends without the interpreter's teardown (see
    :func:`exit_now`)."""
    executable_setup(sys.argv[1:2])
    exit_now(main())


def executable_setup(first_args: list) -> None:
    """What the `fit-lug` executable does before :func:`main` and main() called in-process
    does not: every sub-command but campaign runs without dask (:func:`_without_dask`);
    a fit's report is drawn by a process of its own that imports the report's modules
    while the fit runs (:mod:`fitlug.report._aside`), and on a first run the later
    stages' programs compile in a thread beside the solver's (:mod:`fitlug.cli._prewarm`).
    (first_args: the command line's first argument, in a list.)"""
    if list(first_args[:1]) != ["campaign"]:
        _without_dask()
    from . import _fit

    _fit.REPORT_PROCESS = True
    _fit.PREWARM = True


def _without_dask() -> None:
    """Mark dask unimportable in a `fit-lug` process that never uses it (every sub-command
    but campaign). xarray (ArviZ's: the report's R-hat and ESS table reads posterior.nc)
    imports dask.array on its first netCDF read (and dask.distributed on a write) only to
    ask whether an array is a dask one: ~0.4 s CPU of a warm run of the bundled recording
    (issue 43); the report process (fitlug.report._aside) does the same. With
    dask None in sys.modules before xarray is imported, xarray behaves as where dask is not
    installed, and writes and reads the same files. For the executable only (a process
    about to do one thing): never done by :func:`main`, which tests and library callers
    call in-process."""
    for name in ("dask", "distributed"):
        sys.modules.setdefault(name, None)


def exit_now(status: int) -> None:
    """End the process with `status` once its own work is done: other threads joined,
    the atexit handlers run (logging's flush, coverage's save...), stdout and stderr
    flushed; then os._exit, skipping the interpreter's teardown of every module, array
    and compiled program, which after a default run of the bundled recording cost ~1 s
    CPU of the ~13 (issue 43) and writes nothing. For a process that is about to end
    only: never called by :func:`main`, which library callers and tests call in-process."""
    import atexit
    import os
    import threading

    for t in threading.enumerate():
        if t is not threading.current_thread() and not t.daemon:
            t.join()
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:  # noqa: BLE001 - a closed pipe: nothing more can be said
            status = status or 120  # what the interpreter's own exit returns then
    os._exit(status)


if __name__ == "__main__":  # pragma: no cover
    entry()
