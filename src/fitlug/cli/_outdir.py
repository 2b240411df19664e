"""An output folder holds one run's files: a lock, the old set cleared, a run id.

- A lock file (`.fit-lug.lock`, made with O_EXCL) while a run writes into the folder: a
  second run into a folder in use stops at once and says which run holds it. A lock left
  by a run that no longer exists (killed) on this machine is taken over.
- Before the new files are written, every file of an earlier run's set (fit.json,
  posterior.nc, state.npz, report.html) is removed, so a rerun with --no-report or
  --no-mcmc, or one interrupted while it writes, never leaves old files beside new ones.
- Every file carries the run's id (fit.json `run_id`, state.npz meta, posterior.nc attrs,
  the report's footer); `fit-lug report` refuses a fit.json and state.npz of different
  runs.
- The default folder fits/<name> of a recording is taken only when it is new or holds
  the fit of the same input file; `day1/run1/trajectories.csv` and
  `day2/run1/trajectories.csv` go to fits/run1 and fits/day2-run1.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import time
import uuid

from .._errors import InputError

LOCK = ".fit-lug.lock"
OUTPUTS = ("fit.json", "posterior.nc", "state.npz", "report.html")


def new_run_id() -> str:
    """A fresh run id: 12 hex digits."""
    return uuid.uuid4().hex[:12]


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    except OSError:
        return False
    return True


@contextlib.contextmanager
def locked(folder: str, run_id: str, what: str = "--out"):
    """Hold `folder`'s lock while the block runs (the folder is created, and removed
    again if the run leaves it empty).

    Raises:
        InputError: the folder is in use by another run (alive, or on another machine).
    """
    created = not os.path.isdir(folder)
    os.makedirs(folder, exist_ok=True)
    path = os.path.join(folder, LOCK)
    mine = json.dumps({"pid": os.getpid(), "host": socket.gethostname(), "run_id": run_id,
                       "started": time.strftime("%Y-%m-%d %H:%M:%S")})
    for _ in range(3):
        try:
            fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        except FileExistsError:
            try:
                with open(path, encoding="utf-8") as fh:
                    other = json.load(fh)
            except (OSError, ValueError):
                other = {}
            pid, host = other.get("pid"), other.get("host")
            if isinstance(pid, int) and (host != socket.gethostname() or _alive(pid)):
                raise InputError(what, f"{folder} is in use by another fit-lug run (pid "
                                       f"{pid} on {host}, started {other.get('started')}): "
                                       "wait for it to finish or choose another folder "
                                       f"(remove {path} if no run holds it)") from None
            with contextlib.suppress(FileNotFoundError):
                os.remove(path)  # a stale lock: its run is gone
            continue
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(mine)
        break
    else:
        raise InputError(what, f"{folder}: cannot take the lock {path}")
    try:
        yield
    finally:
        with contextlib.suppress(OSError):
            os.remove(path)
        if created:  # a run that wrote nothing leaves no folder behind
            with contextlib.suppress(OSError):
                os.rmdir(folder)


def clear_outputs(folder: str) -> None:
    """Remove an earlier run's files (OUTPUTS) from `folder`."""
    for name in OUTPUTS:
        with contextlib.suppress(FileNotFoundError):
            os.remove(os.path.join(folder, name))


def _input_of(folder: str) -> str | None:
    """The absolute input path of the fit in `folder`, or None (no readable fit.json)."""
    try:
        with open(os.path.join(folder, "fit.json"), encoding="utf-8") as fh:
            doc = json.load(fh)
    except (OSError, ValueError):
        return None
    path = doc.get("input_abs") or doc.get("input")
    return os.path.abspath(path) if isinstance(path, str) else None


def default_folder(csv_path: str, name: str, root: str = "fits") -> str:
    """fits/<name> unless it holds the fit of another input file; then fits/<parent>-<name>,
    then fits/<name>-2, -3, ... (the first free one or the one of this input)."""
    mine = os.path.abspath(csv_path)
    parent = os.path.basename(os.path.dirname(os.path.dirname(mine)))
    names = [name] + ([f"{parent}-{name}"] if parent else []) \
        + [f"{name}-{k}" for k in range(2, 100)]
    for candidate in names:
        folder = os.path.join(root, candidate)
        owner = _input_of(folder)
        if owner is None or owner == mine:
            if owner is None and os.path.isdir(folder) and any(
                    os.path.exists(os.path.join(folder, f)) for f in OUTPUTS):
                continue  # an earlier run's files whose input cannot be told
            return folder
    raise InputError(csv_path, f"no free output folder under {root}/ for {name}: give --out")
