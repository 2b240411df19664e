"""A cheap look at the whole frame for markers no track follows (issue 26).

A marker can come into view anywhere: across an edge of the picture, round a wheel, from
behind an occluder or a side plate, or in a recording whose first frames show nothing. A
full detection on the whole frame costs ~10 ms (1632x1200); this look costs ~0.1 ms: every
fourth pixel of every fourth row, its background (a grey-level opening) taken away - a
top-hat - and the pixels left brighter than a threshold listed. Every marker has a bright
part (a COG's disc, a QS checker's light quarters) that shows there at full contrast: a
disc 8 px across or a checker's quarter 5 px a side holds one of the pixels looked at. The spots near markers already followed are
masked out; what remains is checked at full resolution by the caller (a region detection).
"""

from __future__ import annotations

import numpy as np

SHRINK = 4  # quarter size: a pixel covers 4 x 4 of the frame


def bright_spots(frame: np.ndarray, threshold: float, masked=(), max_spots: int = 4,
                 spot_px: float = 24.0, size_px: float = 32.0) -> np.ndarray:
    """Centres (K, 2) px (full-frame) of the brightest spots that stand out of the frame's
    local background by more than `threshold` grey levels, strongest first, at most
    `max_spots`, each at least `spot_px` from the others.

    The local background: the sampled frame opened (a grey-level erosion then dilation)
    with a square `size_px` a side, more than the bright part of a marker (a COG's disc, a
    QS checker's light quarter): it keeps what is larger - gradients, vignetting, dark bars
    and their surroundings - and loses the spots. masked: boxes (x0, y0, x1, y1) px where
    nothing is to be reported (markers followed, places checked a moment ago). Frames
    smaller than 64 px a side give no spots.
    """
    import cv2

    h, w = frame.shape
    if h < 16 * SHRINK or w < 16 * SHRINK:
        return np.zeros((0, 2))
    # every fourth pixel of every fourth row (a copy of 1/16 of the frame: three times
    # cheaper than averaging 4 x 4 blocks, which reads the whole frame); a disc 8 px across
    # has a pixel at full brightness among them, a checker 10 px a side one in each quarter
    q = np.ascontiguousarray(frame[SHRINK // 2::SHRINK, SHRINK // 2::SHRINK])
    if q.dtype != np.uint8:
        q = q.astype(np.float32)
    k = int(np.clip(np.ceil(size_px / SHRINK) + 1, 3, 15))
    top = cv2.morphologyEx(q, cv2.MORPH_TOPHAT, np.ones((k, k), np.uint8))
    for x0, y0, x1, y1 in masked:
        a, b = max(int(x0) // SHRINK, 0), max(int(y0) // SHRINK, 0)
        c, d = int(x1) // SHRINK + 1, int(y1) // SHRINK + 1
        if c > 0 and d > 0:
            top[b:d, a:c] = 0
    thr = threshold if top.dtype != np.uint8 else min(int(threshold), 254)
    if cv2.minMaxLoc(top)[1] <= thr:  # (the usual case: nothing new; listing costs more)
        return np.zeros((0, 2))
    over = top > thr
    pts = cv2.findNonZero(over.view(np.uint8))
    if pts is None:
        return np.zeros((0, 2))
    pts = pts.reshape(-1, 2)
    vals = top[pts[:, 1], pts[:, 0]]
    order = np.argsort(vals, kind="stable")[::-1]
    pts = pts[order].astype(np.float64)
    near = spot_px / SHRINK
    # a bright line across the spot's window (a strip of background between a dark bar
    # and the picture's edge, or between two dark things) is no marker: a marker's bright
    # part is at most k - 1 samples across
    m = k
    qh, qw = over.shape
    out = []
    while pts.shape[0] and len(out) < max_spots:
        p = pts[0]
        x, y = int(p[0]), int(p[1])
        col = over[max(y - m, 0):y + m + 1, x]
        row = over[y, max(x - m, 0):x + m + 1]
        if col.sum() < min(2 * m, col.size) and row.sum() < min(2 * m, row.size):
            out.append(p)
        pts = pts[np.abs(pts - p).max(axis=1) > near]
    return np.asarray(out).reshape(-1, 2) * SHRINK + 0.5 * (SHRINK - 1)
