"""The recording brought to the contract's frame: x along travel, y up (DATA.md).

A tracker's axes need not be the contract's: a robot filmed from its other side drives
towards -x, image coordinates have y pointing down, and a camera turned by 90 degrees
swaps x and y. The data say which, from physics alone:

- the axis of travel: the body markers' net displacement lies along x (if it lies along
  y, more than three times its x part, the axes are swapped back);
- the direction: the body moves towards +x (else x is mirrored, x -> -x);
- which way is up: a lug in contact with the ground stalls (ground speed s*v, a few % of
  the body's) while a lug on the top run moves at about twice the body's speed, and the
  ground is below the wheels. The stalled lug samples lie below the fast ones when y
  points up; if they lie above, y is mirrored (y -> -y).

Mirroring is exact for the physics (the model of the mirrored recording is the mirrored
model), so both directions give the same slip, k and C_rr; without it a robot driving
towards -x gave k and C_rr negative, and y pointing down did not converge. The transform
applied is listed (fit.json `orientation`); positions in the report are in the
contract's frame.
"""

from __future__ import annotations

import numpy as np

SWAP_RATIO = 3.0  # travel along y this many times the travel along x: axes swapped
STALL = 0.3  # lug ground speed below this fraction of the body speed: stalled (contact)
FAST = 1.5  # above this fraction: the top run
MIN_SAMPLES = 20  # of each kind, to judge which way is up


def _longest_body(rec):
    valid = rec.valid
    body = rec.markers_of("body")
    if body.size == 0:
        return None
    counts = np.bincount(rec.marker_index[valid], minlength=rec.n_markers)[body]
    m = int(body[np.argmax(counts)])
    sel = valid & (rec.marker_index == m)
    return (rec.t[sel], rec.x[sel], rec.y[sel]) if sel.sum() >= 3 else None


def _y_points_down(rec, tb, xb) -> bool | None:
    """True/False when the lugs' stall says y points down/up, None when undecided."""
    valid = rec.valid
    lug = np.isin(rec.marker_index, rec.markers_of("lug")) & valid
    mi, t, x, y = rec.marker_index[lug], rec.t[lug], rec.x[lug], rec.y[lug]
    if t.size < 3 or tb.size < 3:
        return None
    same = mi[1:] == mi[:-1]  # sorted by (marker, t)
    dt = np.diff(t)
    ok = same & (dt > 0)
    v = np.abs(np.diff(x)[ok] / dt[ok])
    tm = 0.5 * (t[1:] + t[:-1])[ok]
    ym = 0.5 * (y[1:] + y[:-1])[ok]
    vb_t = 0.5 * (tb[1:] + tb[:-1])
    vb = np.abs(np.diff(xb) / np.diff(tb))
    # the body speed, smoothed over ~11 frames so that the noise does not decide
    k = min(11, vb.size)
    vb = np.convolve(vb, np.ones(k) / k, mode="same")
    body_v = np.interp(tm, vb_t, vb, left=np.nan, right=np.nan)
    moving = np.isfinite(body_v) & (body_v > 0.3 * np.nanpercentile(vb, 95))
    if not moving.any():
        return None
    ratio = v[moving] / body_v[moving]
    slow, fast = ym[moving][ratio < STALL], ym[moving][ratio > FAST]
    if slow.size < MIN_SAMPLES or fast.size < MIN_SAMPLES:
        return None
    return bool(np.median(slow) > np.median(fast))


def orient(rec):
    """`rec` in the contract's frame, and what was done: {"direction": "+x" | "-x" (of
    travel, in the file's axes after any swap), "y_axis": "up" | "down",
    "axes_swapped": bool, "applied": [..]} ("applied" empty when the file was already in
    the contract's frame). Undecidable recordings (no body motion, too few lug samples)
    are left as they are."""
    info = {"direction": "+x", "y_axis": "up", "axes_swapped": False, "applied": []}
    ref = _longest_body(rec)
    if ref is None:
        return rec, info
    tb, xb, yb = ref
    dx, dy = float(xb[-1] - xb[0]), float(yb[-1] - yb[0])
    x, y = rec.x, rec.y
    if abs(dy) > SWAP_RATIO * abs(dx) and abs(dy) > 1.0:
        x, y = y, x
        xb, yb = yb, xb
        dx, dy = dy, dx
        info["axes_swapped"] = True
        info["applied"].append("x <-> y (the body travels along the file's y axis)")
    if dx < 0 and abs(dx) > 1.0:
        x, xb = -x, -xb
        info["direction"] = "-x"
        info["applied"].append("x -> -x (the body travels towards -x)")
    if info["applied"]:
        rec = rec.with_(x=x, y=y)
    down = _y_points_down(rec, tb, xb)
    if down:
        rec = rec.with_(y=-rec.y)
        info["y_axis"] = "down"
        info["applied"].append("y -> -y (the stalled lugs, in contact with the ground, "
                               "lie above the fast ones: y points down)")
    return rec, info
