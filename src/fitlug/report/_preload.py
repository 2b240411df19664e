"""The report's heavy imports (matplotlib, corner, ArviZ: ~3 s on a 2-core machine) and
xarray's first netCDF write, in a background thread while the fit runs; JAX's numerics
release the GIL, so they overlap.

After the imports the thread writes and reads a tiny netCDF file through ArviZ: the first
posterior.nc of a process otherwise pays for xarray's first write (it imports
dask.distributed to ask whether a cluster is in use) and h5py's first file, 0.6-0.8 s.
A throwaway figure drawn here as well did not make the report's figures cheaper, and its
pure-Python work held the GIL against the fit's own Python and slowed it by more than it
saved (measured in the whole run, on the bundled recording): the thread does not draw.
Each step checks whether :func:`wait` is already waiting, and stops there.

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


def _run() -> None:
    try:
        import matplotlib

        matplotlib.use("Agg", force=False)
        import matplotlib.pyplot  # noqa: F401
        import corner  # noqa: F401
        import warnings

        # ArviZ's FutureWarning about its refactor, on every import: one targeted filter
        # (not catch_warnings, which would swap the process's filters under the main thread)
        warnings.filterwarnings("ignore", message="ArviZ is undergoing a major refactor",
                                category=FutureWarning)
        import arviz  # noqa: F401
    except Exception:  # noqa: BLE001 - the report imports them again and says what failed
        return
    for step in (_warm_netcdf,):
        if _WANTED.is_set():
            return
        try:
            step()
        except Exception:  # noqa: BLE001 - a warm-up only saves time; the report does it
            pass


def _warm_netcdf() -> None:
    """Write and read a tiny InferenceData through h5netcdf (as posterior.nc is)."""
    import os
    import tempfile

    import arviz as az
    import numpy as np

    # no warnings.catch_warnings here: it swaps the process-wide filters under the main
    # thread's feet (nothing below warns: a posterior of 2 chains x 4 draws, no summary)
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "warm.nc")
        x = np.zeros((2, 4))
        az.from_dict(posterior={"a": x}, sample_stats={"lp": x},
                     attrs={"warm": 1}).to_netcdf(path, engine="h5netcdf")
        az.from_netcdf(path).posterior["a"].values  # noqa: B018 - read it back
