"""A marker knocked on its lug: one marker shifted at some instant, and staying there.

A marker that shifts and stays shifted is not a glitch but a located mismatch (MODEL.md):
no catalog physics moves one marker against the others, so such a recording ends
'unexplained'. The misfit sits in one marker from one instant on; the by-marker sandwich
sizes the slip's error right on average, but the error of one shift is bounded, not
Gaussian (bench_coverage's knocked row: rms z 0.92, largest |z| 1.55, the interval ~40
times the least-squares one, holding the truth in 50 of 50).

A term is a step: one marker and the first frame of the shift, both found where a step of
that marker's residuals (x and y together, from that frame to the marker's last sample,
at least MIN_SIDE valid samples on either side) removes the most chi^2 (suffix sums over
the frame grid, every marker and frame at once); its columns the step in x and in y.
:func:`fitlug.explain._nuisance.search` fits, tests (against the largest of the markers x
frames steps of the noise alone) and takes it out. Image coordinates: the shift the
tracker sees; a shift in the lug's own frame turns with the lug round the wheels, which a
constant step does not hold (the search then leaves the robust errors).
"""

from __future__ import annotations

import numpy as np

from ._image_motion import frames

MIN_SIDE = 10  # valid samples of the marker on either side of the step, per axis
MAX_STEPS = 2


def _grid(geo, r):
    """(markers, sums (M, 2, n) of w r and of w^2 per marker, axis and frame, counts of
    valid samples, frame of every sample, number of frames)."""
    k, n = frames(geo)
    valid = geo.valid
    mk = np.unique(geo.marker[valid])
    pos = np.searchsorted(mk, geo.marker)
    w = np.where(valid, geo.weight, 0.0)
    shape = (len(mk), 2, n)
    flat = (np.where(valid, pos, 0) * 2 + geo.axis) * n + k
    size = len(mk) * 2 * n
    s = np.bincount(flat[valid], (w * r)[valid], size).reshape(shape)
    W = np.bincount(flat[valid], (w * w)[valid], size).reshape(shape)
    c = np.bincount(flat[valid], None, size).reshape(shape)
    return mk, s, W, c, k, n


def find_step(geo, r, exclude=()):
    """((marker, first frame), number of candidates) of the strongest step, or None."""
    mk, s, W, c, _, n = _grid(geo, r)
    if not len(mk):
        return None
    suf = lambda a: np.cumsum(a[..., ::-1], axis=-1)[..., ::-1]  # noqa: E731 - sum from frame on
    S, WW, after = suf(s), suf(W), suf(c)
    before = c.sum(-1, keepdims=True) - after
    ok = np.all((after >= MIN_SIDE) & (before >= MIN_SIDE), axis=1)  # (M, n), both axes
    gain = np.sum(np.where(WW > 0, S * S / np.where(WW > 0, WW, 1.0), 0.0), axis=1)
    for m_ex, _ in exclude:
        ok[mk == m_ex] = False
    if not np.any(ok):
        return None
    gain = np.where(ok, gain, -np.inf)
    i, j = np.unravel_index(int(np.argmax(gain)), gain.shape)
    return (int(mk[i]), int(j)), int(ok.sum())


class MarkerShift:
    """The nuisance kind of :func:`fitlug.explain._nuisance.search`: steps of one marker."""

    name = "marker shift"
    per_term = 2
    max_terms = MAX_STEPS

    @staticmethod
    def find(geo, r, exclude):
        return find_step(geo, r, exclude)

    @staticmethod
    def columns(geo, terms):
        k, _ = frames(geo)
        w = np.where(geo.valid, geo.weight, 0.0)
        cols = []
        for m, j in terms:
            on = (geo.marker == m) & (k >= j)
            cols += [on * (geo.axis == a) * w for a in (0, 1)]
        return np.stack(cols, axis=1)

    @staticmethod
    def describe(terms, coef, geo=None):
        return [{"marker": str(geo.markers[m]) if geo is not None else int(m),
                 "from_time_s": float(geo.t_lo + j / geo.fps) if geo is not None else None,
                 "shift_um": [1000.0 * float(coef[2 * i]), 1000.0 * float(coef[2 * i + 1])]}
                for i, (m, j) in enumerate(terms)]

    @staticmethod
    def label(terms, geo=None):
        names = ", ".join(str(geo.markers[m]) if geo is not None else str(m)
                          for m, _ in terms)
        return (f"a shift of marker {names}",
                f"marker {names} shifted at one instant and stayed there (knocked on its "
                "lug, or re-glued: no catalog physics)")


__all__ = ["MarkerShift", "find_step"]
