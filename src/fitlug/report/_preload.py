"""The report's heavy imports (matplotlib, corner, ArviZ: ~3 s on a 2-core machine) and
matplotlib's and xarray's first-use costs, in a background thread while the fit runs; JAX's
numerics release the GIL, so they overlap.

After the imports the thread draws one small throwaway figure with every kind of element
the report uses (mathtext, legend, colorbar, log axis, image, PNG encoding) and writes and
reads a tiny netCDF file through ArviZ: the first figure of a process otherwise pays for
the mathtext parser, the font look-ups and the tick machinery (about 1 s), and the first
posterior.nc for xarray's and h5py's first writes. Each step checks whether :func:`wait` is
already waiting, and stops there: the warm-up never delays the run.

The caller's thread imports scipy.linalg and scipy.stats before the thread starts (the
fit, the explanation and the posterior need them anyway): the thread then imports only
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
    import scipy.stats  # noqa: F401

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
        import arviz  # noqa: F401
    except Exception:  # noqa: BLE001 - the report imports them again and says what failed
        return
    for step in (_warm_figure, _warm_netcdf):
        if _WANTED.is_set():
            return
        try:
            step()
        except Exception:  # noqa: BLE001 - a warm-up only saves time; the report does it
            pass


def _warm_figure() -> None:
    """Draw and encode one small figure with the report's kinds of element."""
    import io

    import numpy as np

    from ._layout import tidy
    from ._plots import CBAR, new_figure

    fig, ax = new_figure(4.0, 2.0, 1, 3)
    a, b, c = ax[0]
    x = np.linspace(0.0, 1.0, 50)
    a.plot(x, x ** 2, ".", ms=1, label="$s_0$ data")
    a.plot(x, x, "-", label="$v_t = v/(1-s)$")
    a.fill_between(x, x - 0.1, x + 0.1, alpha=0.2, lw=0)
    a.axvspan(0.1, 0.2, alpha=0.2)
    a.set_title("t (s)", fontsize=9)
    a.set_xlabel("x (mm)")
    a.set_ylabel("y (µm)")
    a.legend(frameon=False, ncol=2, loc="lower left", bbox_to_anchor=(0.0, 1.0))
    a.annotate("creep", (0.5, 0.5), fontsize=8)
    a.ticklabel_format(axis="y", useOffset=False)
    im = b.imshow(np.eye(3), cmap="RdBu_r", vmin=-1, vmax=1)
    fig.colorbar(im, ax=b, label="σ", **CBAR)
    c.bar([0, 1], [1.0, 30.0])
    c.set_yscale("log")
    for size in (7, 8):
        b.text(0.5, 0.5, "s₀ .25", fontsize=size)
    tidy(fig)
    fig.savefig(io.BytesIO(), format="png", dpi=fig.dpi)


def _warm_netcdf() -> None:
    """Write and read a tiny InferenceData through h5netcdf (as posterior.nc is)."""
    import os
    import tempfile
    import warnings

    import arviz as az
    import numpy as np

    with warnings.catch_warnings(), tempfile.TemporaryDirectory() as tmp:
        warnings.simplefilter("ignore")
        path = os.path.join(tmp, "warm.nc")
        x = np.zeros((2, 4))
        az.from_dict(posterior={"a": x}, sample_stats={"lp": x},
                     attrs={"warm": 1}).to_netcdf(path, engine="h5netcdf")
        az.from_netcdf(path).posterior["a"].values  # noqa: B018 - read it back
