"""Exact pixel coverage of discs and axis-aligned rectangles (anti-aliasing without sampling).

Pixel convention (OpenCV's): pixel (row i, column j) is the unit square centred on
(x, y) = (j, i), so its edges lie at j ± 1/2 and i ± 1/2. Coverage is the area
fraction of that square inside the shape, in [0, 1], computed in closed form.
"""

from __future__ import annotations

import numpy as np


def _column_area(x: np.ndarray, r: np.ndarray) -> np.ndarray:
    """∫_{-r}^{x} sqrt(r² - t²) dt for x in [-r, r]: half the disc area left of x."""
    h = np.sqrt(np.maximum(r * r - x * x, 0.0))
    return 0.5 * (x * h + r * r * np.arcsin(np.clip(x / r, -1.0, 1.0))) + 0.25 * np.pi * r * r


def _corner_area(x: np.ndarray, y: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Area of the disc of radius r at the origin inside the quarter plane {X < x, Y < y}."""
    xc = np.clip(x, -r, r)
    yc = np.clip(y, -r, r)
    a = np.sqrt(np.maximum(r * r - yc * yc, 0.0))  # half-chord of the disc at height y
    xa = np.clip(xc, -a, a)
    axc = _column_area(xc, r)
    # Columns with |t| < a are cut at y (length y + h); outside they are all in or all out.
    return axc + yc * (xa + a) + np.sign(yc) * (axc - _column_area(xa, r) + _column_area(-a, r))


def disc_coverage(cx, cy, r, x0, y0, width: int, height: int) -> np.ndarray:
    """Exact coverage of a block of pixels by one or many discs.

    cx, cy, r: disc centre (px) and radius (px), scalars or arrays of shape (M,).
    x0, y0: integer pixel coordinates of the block's top-left pixel, same shapes.
    Returns an array (M, height, width) (or (height, width) for scalars) of area
    fractions in [0, 1].
    """
    scalar = np.ndim(cx) == 0
    cx, cy, r, x0, y0 = (np.atleast_1d(np.asarray(v, dtype=np.float64))
                         for v in (cx, cy, r, x0, y0))
    xs = (x0 - cx)[:, None] - 0.5 + np.arange(width + 1)  # pixel edges relative to the centre
    ys = (y0 - cy)[:, None] - 0.5 + np.arange(height + 1)
    g = _corner_area(xs[:, None, :], ys[:, :, None], r[:, None, None])
    cov = g[:, 1:, 1:] - g[:, :-1, 1:] - g[:, 1:, :-1] + g[:, :-1, :-1]
    np.clip(cov, 0.0, 1.0, out=cov)
    return cov[0] if scalar else cov


def interval_overlap(lo, hi, start: float, count: int) -> np.ndarray:
    """Length of overlap of [lo, hi] with each pixel [c - 1/2, c + 1/2], c = start .. start+count-1.

    lo, hi: arrays (M,) (or scalars); returns (M, count).
    """
    lo = np.atleast_1d(np.asarray(lo, dtype=np.float64))[:, None]
    hi = np.atleast_1d(np.asarray(hi, dtype=np.float64))[:, None]
    c = np.asarray(start, dtype=np.float64).reshape(-1, 1) + np.arange(count)
    return np.clip(np.minimum(hi, c + 0.5) - np.maximum(lo, c - 0.5), 0.0, 1.0)
