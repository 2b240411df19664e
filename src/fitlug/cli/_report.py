"""`fit-lug report DIR`: rebuild report.html from a fit folder (fit.json + state.npz)."""

from __future__ import annotations

import argparse
import os

from .._errors import InputError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = ("Rebuild DIR/report.html from the fit.json and state.npz that "
                          "`fit-lug` wrote into DIR (no refit).")
    parser.add_argument("folder", metavar="DIR", help="the fit folder (fits/<name>)")
    parser.add_argument("-q", "--quiet", action="store_true", help="print nothing")


def run(args) -> int:
    from ..report import write_report

    if not os.path.isdir(args.folder):
        raise InputError(args.folder, "not a folder (expected the fit folder that holds "
                                      "fit.json and state.npz)")
    path = write_report(args.folder)
    if not args.quiet:
        print(path)
    return 0
