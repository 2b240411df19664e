"""Errors that fitlug raises for bad input, each a one-line, actionable message."""

from __future__ import annotations

import os


class FitlugError(Exception):
    """Base class of every error fitlug raises on purpose."""


class InputError(FitlugError, ValueError):
    """Bad input: names the file, the place in it and the problem, on one line.

    `InputError("data.csv", "time going backwards for marker B03", line=17)` reads
    ``data.csv:17: time going backwards for marker B03``.
    """

    def __init__(self, path: str | os.PathLike | None, problem: str, *, line: int | None = None,
                 place: str | None = None):
        self.path = None if path is None else os.fspath(path)
        self.problem = " ".join(str(problem).split())  # keep it on one line
        self.line = line
        self.place = place
        where = self.path or "<input>"
        if line is not None:
            where = f"{where}:{line}"
        if place:
            where = f"{where}: {place}"
        super().__init__(f"{where}: {self.problem}")


class FitError(FitlugError, RuntimeError):
    """A fit that failed or did not converge: never reported as a plausible number."""
