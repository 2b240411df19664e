"""Small helpers shared by the sub-commands."""

from __future__ import annotations

import os
import sys


def progress_enabled(args) -> bool:
    """Progress bars only on a terminal and without --quiet."""
    return not getattr(args, "quiet", False) and sys.stderr.isatty()


def say(args, *lines: str) -> None:
    if not getattr(args, "quiet", False):
        for line in lines:
            print(line, flush=True)


PROGRESS_EVERY_S = 3.0  # at most one progress line this often (a stage's last one always)
_STAGE = {"name": "", "t0": 0.0, "printed": 0.0, "compiled": set()}


def stage(args, name: str, detail: str = "") -> None:
    """One line as a stage starts (reading, fitting, explaining, sampling, report), so a
    long compile or fit never leaves the terminal silent."""
    import time

    now = time.perf_counter()
    _STAGE.update(name=name, t0=now, printed=now)
    if not getattr(args, "quiet", False):
        print(f"[{name}] {detail}".rstrip(), flush=True)


class _Lines:
    """fitlug.progress's records as '[stage] what (12.3 s)' lines on stdout, at most one
    every PROGRESS_EVERY_S seconds (a stage's last record always), and one line the first
    time a stage compiles a program for real (fitlug._progress.watch_compiles)."""

    def __init__(self):
        import logging

        class Handler(logging.Handler):
            def emit(inner, record):  # noqa: N805 - the handler's self; the outer is ours
                self.line(getattr(record, "stage", "") or _STAGE["name"],
                          record.getMessage(), bool(getattr(record, "last", False)))

        self.handler = Handler(level=logging.INFO)

    def line(self, name, message, last):
        import time

        now = time.perf_counter()
        if not last and now - _STAGE["printed"] < PROGRESS_EVERY_S:
            return
        _STAGE["printed"] = now
        print(f"[{name}] {message} ({now - _STAGE['t0']:.1f} s)", flush=True)

    def compiled(self, fun_name, seconds):
        name = _STAGE["name"]
        if name in _STAGE["compiled"]:
            return
        _STAGE["compiled"].add(name)
        print(f"[{name}] compiling for this recording's shapes (new to this machine's "
              "cache: a first run takes tens of seconds more)", flush=True)


class progress_lines:
    """Context manager of the command's progress lines (nothing with --quiet): stage
    counts from fitlug.progress, the compile notice only when a compile happens."""

    def __init__(self, args):
        self.on = not getattr(args, "quiet", False)

    def __enter__(self):
        if self.on:
            import logging

            from .._progress import LOG, watch_compiles

            _STAGE["compiled"] = set()
            self.lines = _Lines()
            self.level = LOG.level
            LOG.addHandler(self.lines.handler)
            LOG.setLevel(logging.INFO)
            watch_compiles(self.lines.compiled)
        return self

    def __exit__(self, *exc):
        if self.on:
            from .._progress import LOG, unwatch_compiles

            unwatch_compiles(self.lines.compiled)
            LOG.removeHandler(self.lines.handler)
            LOG.setLevel(self.level)
        return False


def progress_bar(total=None, desc: str = "", unit: str = "it", enabled: bool = True):
    """A tqdm bar on stderr that ends cleanly: it stays on screen at its final count
    (leave=True) and is disabled off a terminal."""
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit=unit, file=sys.stderr, leave=True,
                disable=not (enabled and sys.stderr.isatty()), dynamic_ncols=True)


def recording_name(csv_path: str) -> str:
    """fits/<name>: the folder name for trajectories.csv files, else the file's stem."""
    stem = os.path.splitext(os.path.basename(csv_path))[0]
    if stem == "trajectories":
        parent = os.path.basename(os.path.dirname(os.path.abspath(csv_path)))
        return parent or stem
    return stem


def check_out_folder(folder: str, option: str = "--out") -> None:
    """Refuse, before any work, an output folder that cannot be one: an existing file, a
    path through a file, or a folder (or its first existing parent) that is not writable.
    Raises InputError naming the option and the path."""
    from .._errors import InputError

    path = os.path.abspath(folder)
    if os.path.exists(path) and not os.path.isdir(path):
        raise InputError(option, f"{folder} is an existing file, not a folder")
    parent = path
    while not os.path.exists(parent):
        parent = os.path.dirname(parent)
    if not os.path.isdir(parent):
        raise InputError(option, f"{folder} cannot be created: {parent} is a file")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(option, f"{folder} cannot be written: {parent} is not writable")


SEED_MAX = 2 ** 32 - 1  # numpy's default_rng takes more, emcee's legacy RandomState not


def seed_arg(text: str) -> int:
    """argparse type of --seed: an integer 0 .. 2**32-1, refused at parsing (before any
    fit) with a one-line error otherwise."""
    import argparse

    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if not 0 <= value <= SEED_MAX:
        raise argparse.ArgumentTypeError(f"{text} is out of range: a seed is 0 .. {SEED_MAX}")
    return value


def positive_seconds(text: str) -> float:
    """argparse type of a time budget: a finite number of seconds > 0."""
    import argparse
    import math

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text} must be a finite number of seconds > 0")
    return value


def positive_int(minimum: int = 1, what: str = "a count"):
    """argparse type: an integer >= minimum."""
    import argparse

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"{text}: {what} must be at least {minimum}")
        return value

    return parse
