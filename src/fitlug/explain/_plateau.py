"""A speed's plateau: where a motor's cruise is (explain._straight, explain._belt_clock)."""

from __future__ import annotations

import numpy as np

#: the running median (s) a speed is smoothed with before its plateau is found
SMOOTH_S = 0.2


def plateau(tg, vt, tol: float, smooth_s: float):
    """(t1, t2, v_plateau) of a speed `vt` on the even grid `tg`: the longest span where
    it holds a plateau (within `tol` of the value it holds longest, after a running median
    over `smooth_s`), or None."""
    # the running median: a fit that misfits can put short wiggles in its belt speed,
    # which must not cut the plateau
    half = max(1, int(0.5 * smooth_s / (tg[1] - tg[0])))
    pad = np.pad(vt, half, mode="edge")
    vt = np.median(np.lib.stride_tricks.sliding_window_view(pad, 2 * half + 1), axis=1)
    cand = np.quantile(vt, np.linspace(0.3, 1.0, 141))
    cand = cand[cand > 0]
    if not len(cand):
        return None
    held = [np.sum(np.abs(vt - v) < 0.6 * tol * v) for v in cand]
    v0 = float(cand[int(np.argmax(held))])
    idx = np.flatnonzero(np.abs(vt - v0) < tol * v0)
    if not len(idx):
        return None
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
    run = max(runs, key=len)
    return float(tg[run[0]]), float(tg[run[-1]]), v0
