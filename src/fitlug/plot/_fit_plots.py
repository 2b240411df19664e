"""Plots of a least-squares fit (a :class:`fitlug.fit.FitResult`)."""

from __future__ import annotations

import numpy as np

from ._common import axes, colours, legend, samples_of


def residuals(res, *, ax=None, axis: str = "x", markers=None, standardised: bool = False):
    """Data minus model over time, one colour per marker.

    Args:
        res: a FitResult.
        ax: matplotlib axes to draw on; None: a new figure.
        axis: "x" or "y", the image axis of the residual.
        markers: marker names to draw (default: every fitted marker).
        standardised: divide by each sample's noise sigma (dimensionless) instead of mm.

    Returns:
        The axes.

    Raises:
        ValueError: a bad axis or an unknown marker (naming the fitted ones).
    """
    if axis not in ("x", "y"):
        raise ValueError(f"axis must be 'x' or 'y', not {axis!r}")
    mk, role, t, rx, ry, sig = samples_of(res)
    fitted = list(dict.fromkeys(mk))
    markers = _markers(markers, fitted)
    r = rx if axis == "x" else ry
    if standardised:
        r = r / sig
    ax = axes(ax)
    for m, c in zip(markers, colours(len(markers))):
        sel = mk == m
        order = np.argsort(t[sel])
        ax.plot(t[sel][order], r[sel][order], ".", ms=2.5, color=c, label=m)
    ax.axhline(0.0, color="k", lw=0.6)
    ax.set_xlabel("time (s)")
    ax.set_ylabel(f"{axis} residual " + ("(data - model) / σ" if standardised
                                         else "data - model (mm)"))
    legend(ax, len(markers))
    return ax


def trajectories(res, *, ax=None, axis: str = "x", markers=None, n: int = 400):
    """The markers' tracked positions (dots) against the fitted model (lines).

    Args:
        res: a FitResult.
        ax: matplotlib axes; None: a new figure.
        axis: "x" or "y" (ground mm).
        markers: names to draw (default: every fitted marker).
        n: model points over the recording.

    Returns:
        The axes.
    """
    if axis not in ("x", "y"):
        raise ValueError(f"axis must be 'x' or 'y', not {axis!r}")
    mk, role, t, rx, ry, sig = samples_of(res)
    fitted = list(dict.fromkeys(mk))
    markers = _markers(markers, fitted)
    lo, hi = float(np.min(t)), float(np.max(t))
    tt = np.linspace(lo, hi, n)
    pr = res.predict(tt, markers=markers)
    rec = res.problem.rec
    names = list(rec.markers)
    ax = axes(ax)
    for i, (m, c) in enumerate(zip(markers, colours(len(markers)))):
        sel = (rec.marker_index == names.index(m)) & np.isfinite(rec.x)
        ax.plot(rec.t[sel], (rec.x if axis == "x" else rec.y)[sel], ".", ms=2, color=c,
                alpha=0.5)
        ax.plot(tt, (pr.x if axis == "x" else pr.y)[i], "-", lw=1.0, color=c, label=m)
    ax.set_xlabel("time (s)")
    ax.set_ylabel(f"{axis} (mm)")
    ax.plot([], [], "k.", ms=3, label="data")
    legend(ax, len(markers) + 1)
    return ax


def slip(res, *, ax=None, times=None, n: int = 400):
    """The slip s(t) = 1 - v / v_t over the recording with its 95 % band (delta method from
    the fit's covariance), and the steady slip.

    Args:
        res: a FitResult.
        ax: matplotlib axes; None: a new figure.
        times: times to draw, s (default: n points over the recording); at rest the slip
            is undefined and not drawn.

    Returns:
        The axes.
    """
    from ..fit._predict import _span

    if times is None:
        times = np.linspace(*_span(res), n)
    b = res.slip_at(times)
    lo, hi = b.ci95
    ax = axes(ax)
    ax.fill_between(b.t, lo, hi, color="#08519c", alpha=0.25, lw=0, label="95 % band")
    ax.plot(b.t, b.value, "-", color="#08519c", lw=1.3, label="slip s(t)")
    s = res.quantities.get("slip")
    if s is not None and s.value is not None:
        ax.axhline(s.value, color="k", ls="--", lw=0.8,
                   label=f"steady slip {s.value:.5g} ± {s.std:.2g}")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("slip s")
    legend(ax, 3)
    return ax


def _markers(markers, fitted):
    if markers is None:
        return fitted
    if isinstance(markers, str):
        markers = [markers]
    bad = [m for m in markers if m not in fitted]
    if bad:
        raise ValueError(f"unknown marker(s) {', '.join(map(repr, bad))}; fitted markers: "
                         f"{', '.join(fitted)}")
    return list(markers)
