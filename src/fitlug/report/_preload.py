"""The report's heavy imports (matplotlib, corner, ArviZ: ~3 s on a 2-core machine) and
ArviZ's first netCDF read, in a background thread while the fit runs; JAX's numerics
release the GIL, so they overlap. (The `fit-lug` executable does the same steps in a
process of its own, :mod:`fitlug.report._aside`: :func:`import_modules`, :func:`warm_netcdf`.)

After the imports the thread writes a tiny netCDF file as posterior.nc is written
(:func:`fitlug.io.write_samples_netcdf`) and reads it through ArviZ as the report's
diagnostics table reads posterior.nc: the first file of a process otherwise pays for
h5py's first file and xarray's first read. A throwaway figure drawn here as well did not
make the report's figures cheaper, and its pure-Python work held the GIL against the
fit's own Python and slowed it by more than it saved (measured in the whole run, on the
bundled recording): the thread does not draw. Each step checks whether :func:`wait` is
already waiting, and stops there.

The caller's thread imports scipy.linalg and scipy.special before the thread starts (the
fit, the explanation and the posterior need them anyway; scipy.stats, 1 s, only the
report's ArviZ does, in the thread): the thread then imports only
modules the caller does not import before :func:`wait`, so the two threads never wait on
each other's import locks. Call :func:`wait` before writing posterior.nc or the report.
"""

from __future__ import annotations

import threading

_THREAD: list = []
_WANTED = threading.Event()  # set by wait(): the warm-up stops at its next step


def start() -> None:
    """Start importing the report's modules in a daemon thread (once per process)."""
    if _THREAD:
        return
    import scipy.linalg  # noqa: F401
    import scipy.special  # noqa: F401

    t = threading.Thread(target=_run, name="fitlug-report-imports", daemon=True)
    _THREAD.append(t)
    t.start()


def wait() -> None:
    """Return once the thread started by :func:`start` (if any) is done; a warm-up still
    under way stops after its current step."""
    _WANTED.set()
    for t in _THREAD:
        t.join()


def import_modules() -> None:
    """Import matplotlib (on Agg), corner and ArviZ, the report's heavy modules; raises
    what an import raises."""
    import warnings

    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot  # noqa: F401
    import corner  # noqa: F401

    # ArviZ's FutureWarning about its refactor, on every import: one targeted filter
    # (not catch_warnings, which would swap the process's filters under the main thread)
    warnings.filterwarnings("ignore", message="ArviZ is undergoing a major refactor",
                            category=FutureWarning)
    import arviz  # noqa: F401


def _run() -> None:
    try:
        import_modules()
    except Exception:  # noqa: BLE001 - the report imports them again and says what failed
        return
    for step in (warm_netcdf,):
        if _WANTED.is_set():
            return
        try:
            step()
        except Exception:  # noqa: BLE001 - a warm-up only saves time; the report does it
            pass


def warm_netcdf() -> None:
    """Write a tiny file as posterior.nc is written and read it back through ArviZ, as the
    report's diagnostics table reads posterior.nc."""
    import os
    import tempfile

    import arviz as az
    import numpy as np

    from ..io import write_samples_netcdf

    # no warnings.catch_warnings here: it swaps the process-wide filters under the main
    # thread's feet (nothing below warns: a posterior of 2 chains x 4 draws, no summary)
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "warm.nc")
        x = np.zeros((2, 4))
        write_samples_netcdf(path, {"posterior": {"a": x}, "sample_stats": {"lp": x}})
        az.from_netcdf(path).posterior["a"].values  # noqa: B018 - read it back
