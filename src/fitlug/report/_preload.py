"""The report's heavy imports (matplotlib, corner, ArviZ: ~3 s on a 2-core machine) in a
background thread while the fit runs; JAX's numerics release the GIL, so they overlap.

The caller's thread imports scipy.linalg and scipy.stats before the thread starts (the
fit, the explanation and the posterior need them anyway): the thread then imports only
modules the caller does not import before :func:`wait`, so the two threads never wait on
each other's import locks. Call :func:`wait` before writing posterior.nc or the report.
"""

from __future__ import annotations

import threading

_THREAD: list = []


def start() -> None:
    """Start importing the report's modules in a daemon thread (once per process)."""
    if _THREAD:
        return
    import scipy.linalg  # noqa: F401
    import scipy.stats  # noqa: F401

    t = threading.Thread(target=_run, name="fitlug-report-imports", daemon=True)
    _THREAD.append(t)
    t.start()


def wait() -> None:
    """Return once the thread started by :func:`start` (if any) is done."""
    for t in _THREAD:
        t.join()


def _run() -> None:
    try:
        import matplotlib

        matplotlib.use("Agg", force=False)
        import matplotlib.pyplot  # noqa: F401
        import corner  # noqa: F401
        import arviz  # noqa: F401
    except Exception:  # noqa: BLE001 - the report imports them again and says what failed
        pass
