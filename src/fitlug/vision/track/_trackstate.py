"""One followed marker: its samples, its prediction and its running references."""

from __future__ import annotations

import math
from array import array

import numpy as np

# least-squares parabola through samples at t = -4..0: value at t = [1, t, t²] @ _P5
_T5 = np.arange(-4.0, 1.0)
_P5 = np.linalg.pinv(np.stack([np.ones(5), _T5, _T5 * _T5], axis=1))
_W5_NEXT = tuple(float(v) for v in np.array([1.0, 1.0, 1.0]) @ _P5)


class Track:
    """A followed marker: samples (frames, xs, ys, qs: quality), state (misses, alive,
    confirmed) and references for checking new samples (COG: area = flux / level, radius,
    shear = traceless second moments, slope = relative lighting slope across the disc; QS: rms residual, contrast, fit parameters)."""

    __slots__ = ("uid", "kind", "size", "frames", "xs", "ys", "qs", "misses", "alive",
                 "area", "radius", "shear", "slope", "rms", "contrast", "params",
                 "confirmed", "sizes", "n_ref")

    def __init__(self, uid, kind, size, frame, xy, contrast, params=None):
        self.uid, self.kind, self.size = uid, kind, float(size)
        # its samples' sizes until it is confirmed (a disc coming into view measures smaller)
        self.sizes = [float(size)]
        # typed arrays, not lists: 8 bytes a sample rather than ~40 (long recordings)
        self.frames = array("q", [int(frame)])
        self.xs, self.ys, self.qs = array("d", [xy[0]]), array("d", [xy[1]]), array("d", [1.0])
        self.misses, self.alive, self.confirmed = 0, True, False
        self.area = self.radius = self.shear = self.slope = self.rms = None
        self.n_ref = 0  # samples in a COG's area and radius references (see Tracker._accept)
        self.contrast = float(contrast)
        self.params = params

    def predict(self, frame: int):
        """Predicted (x, y) at `frame` and how far off it may be, px (None: speed unknown).

        A parabola through the last five samples when they are consecutive (least squares:
        less noise than through three), else constant acceleration or velocity."""
        f, xs, ys = self.frames, self.xs, self.ys
        k = frame - f[-1]
        if len(f) >= 5 and f[-1] - f[-5] == 4:
            w = _W5_NEXT if k == 1 else tuple(np.array([1.0, k, k * k]) @ _P5)
            x = w[0] * xs[-5] + w[1] * xs[-4] + w[2] * xs[-3] + w[3] * xs[-2] + w[4] * xs[-1]
            y = w[0] * ys[-5] + w[1] * ys[-4] + w[2] * ys[-3] + w[3] * ys[-2] + w[4] * ys[-1]
            ax, ay = xs[-1] - 2 * xs[-2] + xs[-3], ys[-1] - 2 * ys[-2] + ys[-3]
            return (x, y), 0.3 + 0.5 * (abs(ax) + abs(ay)) * k * k + 1.5 * (k - 1)
        if len(f) >= 3 and f[-1] - f[-3] == 2:
            vx = 1.5 * xs[-1] - 2 * xs[-2] + 0.5 * xs[-3]
            vy = 1.5 * ys[-1] - 2 * ys[-2] + 0.5 * ys[-3]
            ax, ay = xs[-1] - 2 * xs[-2] + xs[-3], ys[-1] - 2 * ys[-2] + ys[-3]
            unc = 0.3 + 0.5 * (abs(ax) + abs(ay)) * k * k + 1.5 * (k - 1)
            return (xs[-1] + k * vx + 0.5 * k * k * ax, ys[-1] + k * vy + 0.5 * k * k * ay), unc
        if len(f) >= 2:
            d = f[-1] - f[-2]
            vx, vy = (xs[-1] - xs[-2]) / d, (ys[-1] - ys[-2]) / d
            unc = 1.5 + 2.0 * (k - 1) + 0.3 * k * math.hypot(vx, vy)
            return (xs[-1] + k * vx, ys[-1] + k * vy), unc
        return (xs[-1], ys[-1]), None

    def add(self, frame, xy, q):
        self.frames.append(frame)
        self.xs.append(float(xy[0]))
        self.ys.append(float(xy[1]))
        self.qs.append(float(q))
        self.misses = 0


def ema(old, new, a=0.2):
    return new if old is None else (1 - a) * old + a * new


def score(dev, tol):
    """1 at no deviation, 0.5 at the tolerance, 0 at twice it."""
    return min(max(1.0 - 0.5 * abs(float(dev)) / tol, 0.0), 1.0)
