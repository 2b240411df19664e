"""What a family offers the search (:class:`Family`) and what a fitted term reports
(:class:`Choice`): MODEL.md §5's families, each at one place of the model with a free
function of one natural coordinate."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, ClassVar

import numpy as np

from ._solve import Fitted

BAND_DRAWS = 400  # coefficient draws for the 95 % band of a shape


@dataclass
class Choice:
    """One family term fitted at its best size (number of terms, frequency)."""

    family: str
    coordinate: str
    fitted: Fitted
    markers: list
    axis: str | None
    segment: str | None
    frequency_hz: float | None
    #: value of the shape at coordinate values for coefficient vector c: f(x, c) -> (n,)
    shape_fn: Callable
    shape_x: np.ndarray
    shape_unit: str
    coordinate_unit: str
    describe: Callable  # c -> (params dict, reading sentence)
    label: str = ""
    ambiguity: str = ""  # what recording would tell this reading from another
    rows: np.ndarray | None = None  # the residual rows the term acts on (bool, (S,))
    row_coord: np.ndarray | None = None  # their coordinate for the before/after figure
    row_coord_name: str = ""
    exact: Callable | None = None  # (flat, c) -> residuals of the exact (nonlinear) term
    #: Context -> the term's columns B evaluated at that context's fit (for relinearising
    #: a term whose place moves with the fit's parameters: a lug's segment and u, the
    #: ground x); None where the columns are kept as first built
    columns: Callable | None = None
    extra: dict = field(default_factory=dict)
    #: (free, vt) -> this choice with the exact term's own parameters (`exact.n_free`)
    #: refitted to `free` (a speed modulation's frequency), read under the final fit's
    #: cruise belt speed vt (mm/s); None where it has none
    retuned: Callable | None = None

    def binned(self, r_before, r_after, w, n_bins: int = 40) -> dict | None:
        """Mean residual (mm) of the term's rows in bins of `row_coord`, before and after
        the term (the report's before/after panel)."""
        if self.rows is None or not self.rows.any():
            return None
        sel = self.rows & (w > 0)
        x = self.row_coord[sel]
        edges = np.linspace(np.min(x), np.max(x), n_bins + 1)
        k = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, n_bins - 1)
        cnt = np.bincount(k, minlength=n_bins)
        out = {"coordinate": (0.5 * (edges[1:] + edges[:-1])).tolist(),
               "coordinate_name": self.row_coord_name, "unit": "mm", "count": cnt.tolist()}
        for name, r in (("before", r_before), ("after", r_after)):
            mm = r[sel] / w[sel]
            m = np.bincount(k, weights=mm, minlength=n_bins) / np.maximum(cnt, 1)
            out[name] = [float(v) if c > 0 else None for v, c in zip(m, cnt)]
        return out

    def shape(self, c=None, cov=None, seed: int = 0) -> dict:
        """DATA.md's shape: the function against its coordinate with its 95 % band (the
        2.5 and 97.5 percentiles of the shape over draws of the coefficients)."""
        c = self.fitted.c if c is None else c
        cov = self.fitted.cov if cov is None else cov
        x = self.shape_x
        val = self.shape_fn(x, c)
        rng = np.random.default_rng(seed)
        w, V = np.linalg.eigh(0.5 * (cov + cov.T))  # semi-definite (a gauge direction)
        L = V * np.sqrt(np.maximum(w, 0.0))
        draws = c[None, :] + rng.standard_normal((BAND_DRAWS, len(c))) @ L.T
        vals = np.array([self.shape_fn(x, d) for d in draws])
        lo, hi = np.percentile(vals, [2.5, 97.5], axis=0)
        return {"coordinate": x.tolist(), "value": np.asarray(val).tolist(),
                "lo": lo.tolist(), "hi": hi.tolist(), "unit": self.shape_unit,
                "coordinate_unit": self.coordinate_unit, "coordinate_name": self.coordinate}


class Family:
    """One family of MODEL.md §5: where it acts and how its term is fitted."""

    #: MODEL.md §5's name
    name: ClassVar[str]

    @classmethod
    def applies(cls, part: dict) -> bool:
        """Whether a located part (DATA.md `located`) points at this family's place."""
        raise NotImplementedError

    @classmethod
    def fit(cls, ctx, proj, parts) -> Choice | None:
        """The family's term at its best size by the criterion, or None when it cannot act
        on this recording (nothing to fit at its place)."""
        raise NotImplementedError


class Everywhere(Family):
    """A family that acts on every sample (the image, the clock): any located part points
    at it, and it needs the samples of the whole recording."""

    MIN_SAMPLES: ClassVar[int] = 100

    @classmethod
    def applies(cls, part):
        return part.get("axis") in ("x", "y")

    @classmethod
    def enough(cls, ctx) -> bool:
        return int(ctx.valid.sum()) >= cls.MIN_SAMPLES


def bspline(x, lo: float, hi: float, n_int: int) -> np.ndarray:
    """(len(x), n_int + 3) cubic B-spline basis on [lo, hi] in n_int equal intervals (x
    clipped to it)."""
    return bspline_on(x, np.linspace(lo, hi, n_int + 1))


def bspline_on(x, breaks) -> np.ndarray:
    """(len(x), len(breaks) + 2) cubic B-spline basis on increasing `breaks` (x clipped to
    their span)."""
    breaks = np.asarray(breaks, float)
    lo, hi = float(breaks[0]), float(breaks[-1])
    knots = np.r_[[lo] * 3, breaks, [hi] * 3]
    xc = np.clip(np.asarray(x, float), lo, hi)
    from scipy.interpolate import BSpline  # ~0.15 s to import: only where a family is fit

    return BSpline.design_matrix(xc, knots, 3).toarray()


def best_size(proj, builds, rank: bool = False) -> tuple | None:
    """The (size, Fitted) of least Delta BIC among `builds` = [(size, columns, n_extra)]
    (`rank`: see :meth:`Projector.fit`)."""
    best = None
    for size, B, n_extra in builds:
        if B is None or not np.any(B):
            continue
        f = proj.fit(B, n_extra, rank=rank)
        if best is None or f.delta_bic < best[1].delta_bic:
            best = (size, f)
    return best


def names(ctx, sel) -> list:
    """The marker names of the rows `sel`."""
    return [ctx.markers[i] for i in np.unique(ctx.marker[sel & ctx.valid])]
