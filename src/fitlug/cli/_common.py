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


def stage(args, name: str, detail: str = "") -> None:
    """One line as a stage starts (reading, fitting, explaining, sampling, report), so a
    long compile or fit never leaves the terminal silent."""
    if not getattr(args, "quiet", False):
        print(f"[{name}] {detail}".rstrip(), flush=True)


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
