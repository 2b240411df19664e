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
            print(line)


def recording_name(csv_path: str) -> str:
    """fits/<name>: the folder name for trajectories.csv files, else the file's stem."""
    stem = os.path.splitext(os.path.basename(csv_path))[0]
    if stem == "trajectories":
        parent = os.path.basename(os.path.dirname(os.path.abspath(csv_path)))
        return parent or stem
    return stem
