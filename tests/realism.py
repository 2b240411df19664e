"""What a real tracker does to a clean recording: the project's own realism transform.

`realistic(rec, seed=...)` takes a Recording (from `tests/independent_sim.py` or
`fitlug.sim`) and returns what a camera and a tracker would have delivered:

- field of view: a window of `fov_mm` (637 mm: 1632 px x 0.3905 mm/px) in ground x,
  centred on the recording's x range unless `fov_center_mm` is given; samples outside
  it are not seen (markers, body markers included, enter and leave the picture);
- misses: each sample lost with probability `miss` (1 %);
- occlusions: per marker, events at `occlusion_rate` per second, each hiding 5-30 frames;
- glitches (`glitches=True`): a fraction 0.1-0.2 % of the valid samples moved by
  0.5-1 mm in a random direction (the list is returned in `info["glitches"]`);
- split ids: after a gap longer than `split_gap_frames` frames the tracker re-acquires
  the marker under a new id ('trk17', numbers drawn at random: no pattern); every
  fragment gets such a new id, the first included, so names say nothing.

`drive_through(rec, seed=...)` is the commonest recording of all: the camera is triggered,
the robot drives in, crosses a window narrower than its travel and drives out. It draws
what a user could film - a window of 300-637 mm placed anywhere along the travel (the
robot outside the picture at the start, the end or both; only the cruise, only a ramp),
markers lost within a few mm of the picture's edge (a marker is found only once it is
fully inside) - and puts every fault of `realistic` on top.

`tracker_error(rec, seed=...)` (issue 42) puts what a sub-pixel centroid tracker adds to a
noise-free recording: pixel locking (a bias periodic in the marker's image position, period
one pixel in x and in y, with a random phase and a random second harmonic), a slow
per-marker drift (lighting, focus: a smooth random function of time) and white read noise.
The image scale (mm/px), the amplitudes and the drift's time scale are drawn per recording
in ranges wider than the issue's (nothing tuned).

Everything random comes from `seed`. `info["fragments"]` maps each new id to its
original marker and role; `write_realistic(dir, rec, rig, wide=True)` writes the wide
export form (DATA.md: time_s, <id>_x_mm, <id>_y_mm) and a rig.toml that lists the roles.
"""

from __future__ import annotations

import dataclasses
import os

import numpy as np

from fitlug.io import Recording, write_rig, write_trajectories
from fitlug.io._atomic import write_text_atomic

FOV_MM = 637.0  # 1632 px x 0.3905 mm/px


def _fps(rec):
    try:
        return float(rec.meta.get("fps"))
    except (TypeError, ValueError):
        d = np.diff(np.unique(rec.t))
        return 1.0 / float(np.median(d))


def realistic(rec: Recording, *, seed: int = 0, fov_mm: float | None = FOV_MM,
              fov_center_mm: float | None = None, miss: float = 0.01,
              occlusion_rate: float = 0.1, occlusion_frames=(5, 30), glitches: bool = True,
              glitch_fraction=(0.001, 0.002), glitch_mm=(0.5, 1.0),
              split_gap_frames: int | None = 10, rename: bool = True):
    """(Recording, info): `rec` as a real camera + tracker would deliver it.

    Gaps of one frame (misses) stay as NaN rows; longer gaps and the time outside the
    field of view have no rows. info: {"fragments": {new_id: (orig_id, role, t0, t1)},
    "glitches": [(new_id, t, dx, dy)], "fov": (lo, hi)}.
    """
    rng = np.random.default_rng(seed)
    fps = _fps(rec)
    frames_all = np.unique(rec.t)
    valid = np.isfinite(rec.x) & np.isfinite(rec.y)
    if fov_mm is not None:
        if fov_center_mm is None:
            xv = rec.x[valid]
            fov_center_mm = 0.5 * (float(xv.min()) + float(xv.max()))
        lo, hi = fov_center_mm - fov_mm / 2, fov_center_mm + fov_mm / 2
    else:
        lo, hi = -np.inf, np.inf
    x = rec.x.copy()
    y = rec.y.copy()
    seen = valid & (x >= lo) & (x <= hi)
    seen &= rng.random(len(x)) >= miss
    duration = float(frames_all[-1] - frames_all[0])
    for m in range(rec.n_markers):
        rows = np.flatnonzero(rec.marker_index == m)
        rows = rows[np.argsort(rec.t[rows], kind="stable")]
        n_ev = rng.poisson(occlusion_rate * duration)
        for _ in range(n_ev):
            k0 = int(rng.integers(0, len(rows)))
            ln = int(rng.integers(occlusion_frames[0], occlusion_frames[1] + 1))
            seen[rows[k0:k0 + ln]] = False
    glitch_list = []
    if glitches:
        cand = np.flatnonzero(seen)
        frac = rng.uniform(*glitch_fraction)
        ng = max(1, int(round(frac * len(cand))))
        pick = rng.choice(cand, ng, replace=False)
        size = rng.uniform(*glitch_mm, ng)
        ang = rng.uniform(0, 2 * np.pi, ng)
        dx, dy = size * np.cos(ang), size * np.sin(ang)
        x[pick] += dx
        y[pick] += dy
        glitch_list = list(zip(pick.tolist(), dx.tolist(), dy.tolist()))
    # fragments: a new id after a gap longer than split_gap_frames
    frag_of_row = np.full(len(x), -1)
    frags = []  # (orig marker index, role)
    for m in range(rec.n_markers):
        rows = np.flatnonzero(rec.marker_index == m)
        rows = rows[np.argsort(rec.t[rows], kind="stable")]
        k = np.flatnonzero(seen[rows])
        if len(k) == 0:
            continue
        cur = None
        last = None
        for kk in k:
            gap = (rec.t[rows[kk]] - rec.t[rows[last]]) * fps - 1 if last is not None else 0
            if cur is None or (split_gap_frames is not None and gap > split_gap_frames + 0.5):
                frags.append((m, rec.roles[m]))
                cur = len(frags) - 1
            frag_of_row[rows[kk]] = cur
            last = kk
        # misses inside a fragment: NaN rows (a frame seen empty); longer gaps: no rows
        fr = frag_of_row[rows]
        prev = np.maximum.accumulate(np.where(fr >= 0, np.arange(len(rows)), -1))
        nxt = np.minimum.accumulate(np.where(fr >= 0, np.arange(len(rows)),
                                             len(rows))[::-1])[::-1]
        inner = (fr < 0) & (prev >= 0) & (nxt < len(rows))
        inner[inner] = fr[prev[inner]] == fr[np.minimum(nxt[inner], len(rows) - 1)]
        frag_of_row[rows[inner]] = fr[prev[inner]]
    if rename:
        numbers = rng.choice(np.arange(1, 20 * max(len(frags), 1)), len(frags), replace=False)
        names = [f"trk{int(k)}" for k in numbers]
    else:
        count = {}
        names = []
        for m, _ in frags:
            c = count.get(m, 0)
            count[m] = c + 1
            names.append(rec.markers[m] if c == 0 else f"{rec.markers[m]}.{c}")
    keep = np.flatnonzero(frag_of_row >= 0)
    order = np.lexsort((rec.t[keep], frag_of_row[keep]))
    keep = keep[order]
    fi = frag_of_row[keep]
    xo = np.where(seen[keep], x[keep], np.nan)
    yo = np.where(seen[keep], y[keep], np.nan)
    extra = {}
    for f in ("frame", "x_px", "y_px", "quality"):
        v = getattr(rec, f)
        if v is not None:
            extra[f] = v[keep]
    if rec.sigma is not None:
        extra["sigma"] = rec.sigma[keep]
    out = Recording(markers=tuple(names), roles=tuple(r for _, r in frags), t=rec.t[keep],
                    marker_index=fi.astype(np.int64), x=xo, y=yo, meta=dict(rec.meta),
                    **extra)
    info = {"fragments": {}, "glitches": [], "fov": (lo, hi)}
    for j, (m, role) in enumerate(frags):
        tj = rec.t[keep][(fi == j) & np.isfinite(xo)]
        info["fragments"][names[j]] = (rec.markers[m], role, float(tj.min()), float(tj.max()))
    for r, dx, dy in glitch_list:
        info["glitches"].append((names[frag_of_row[r]], float(rec.t[r]), dx, dy))
    return out, info


def drive_scenario(seed: int, *, rig: bool = True) -> dict:
    """Keyword arguments of tests/independent_sim.make for a drive-through recording:
    100-250 fps, 5-8 s, rests of 0.2-1 s, ramps of 0.8-1.6 s, cruise at 120-260 mm/s
    (0.5-1.6 m of travel, longer than any window of 300-637 mm); with `rig`, another
    track and robot too: n 6-10, L 100-160 mm, wheels R 18-35 mm, pitch 15-22 mm and a
    belt of 18-26 lugs (straight runs 60-200 mm), marker offset e 1.5-4 mm, 6-10 lug
    markers on consecutive lugs, two body markers anywhere along the body, mass 2-12 kg,
    k 0.1-0.4 N/mm, C_rr 0.03-0.15 (steady slip 0.01-0.2)."""
    rng = np.random.default_rng([seed, 7])
    fps = float(rng.choice([100.0, 120.0, 200.0, 250.0]))
    dur = float(rng.uniform(5.0, 8.0))
    ramp = float(rng.uniform(0.8, 1.6))
    rest0, rest1 = (float(v) for v in rng.uniform(0.2, 1.0, 2))
    out = {"fps": fps, "duration": dur, "t_acc": (rest0, rest0 + ramp),
           "t_dec": (dur - rest1 - ramp, dur - rest1), "v_max": float(rng.uniform(120, 260))}
    if not rig:
        return out
    while True:
        R = float(rng.uniform(18, 35))
        pitch = float(rng.uniform(15, 22))
        N = int(rng.integers(18, 27))
        D = (N * pitch - 2 * np.pi * R) / 2
        n, L = int(rng.choice([6, 8, 10])), float(rng.uniform(100, 160))
        m, k, C_rr = (float(rng.uniform(2, 12)), float(rng.uniform(0.1, 0.4)),
                      float(rng.uniform(0.03, 0.15)))
        slip = 2 * m * C_rr * 9.81 / (k * n * L)
        if 60 <= D <= 200 and 0.01 <= slip <= 0.2:
            break
    half = D / 2 + R
    body = ((float(rng.uniform(-half, 0)), float(rng.uniform(2.2 * R, 3.2 * R))),
            (float(rng.uniform(0, half)), float(rng.uniform(2.2 * R, 3.2 * R))))
    out.update(m=m, k=k, C_rr=C_rr, n=n, L=L, R=R, pitch=pitch, N=N,
               e=float(rng.uniform(1.5, 4.0)), x_off=float(rng.uniform(-5, 5)),
               y_off=float(rng.uniform(2, 8)), n_lug=int(rng.integers(6, min(11, N // 2 + 1))),
               body=body)
    return out


def drive_through(rec: Recording, *, seed: int = 0, window_mm=(300.0, 637.0),
                  edge_mm=(0.0, 8.0), faults: bool = True, need_motion: bool = False,
                  window=None, **kw):
    """(Recording, info): `rec` seen through a window narrower than the robot's travel.

    The window's width is drawn uniformly in `window_mm`; its centre anywhere such that
    at least 30 % of the window's width of travel is seen by both marker kinds (lug and
    body markers each seen over >= 0.5 s), so the robot enters, leaves, or both, in any
    phase of its motion. A marker is lost `edge` mm before it reaches the picture's edge
    (a tracker finds a marker only once it is fully inside; `edge` drawn in `edge_mm`).
    With `faults`, every fault of :func:`realistic` (misses, occlusions, glitches, ids
    split after gaps) is added on top; `kw` go to :func:`realistic`.
    `need_motion`: the window must see a speed change (k and C_rr identifiable).
    `window`: (lo, hi) in ground x instead of a drawn one (the edge loss is still drawn).
    info adds "window": (lo, hi) in ground x and "edge_mm".
    """
    rng = np.random.default_rng([seed, 26])
    valid = np.isfinite(rec.x) & np.isfinite(rec.y)
    xv = rec.x[valid]
    lug = np.isin(rec.marker_index, [m for m, r in enumerate(rec.roles) if r == "lug"])
    fps = _fps(rec)
    for _ in range(200):
        width = float(rng.uniform(*window_mm))
        edge = float(rng.uniform(*edge_mm))
        centre = float(rng.uniform(xv.min() + 0.2 * width, xv.max() - 0.2 * width))
        if window is not None:
            width, centre = window[1] - window[0], 0.5 * (window[0] + window[1])
        lo, hi = centre - width / 2 + edge, centre + width / 2 - edge
        inside = valid & (rec.x >= lo) & (rec.x <= hi)
        t_lug = np.unique(rec.t[inside & lug])
        t_body = np.unique(rec.t[inside & ~lug])
        if len(t_lug) < 0.5 * fps or len(t_body) < 0.5 * fps:
            continue
        if need_motion and not _sees_speed_change(rec, inside, fps):
            continue
        break
    else:
        raise ValueError("drive_through: no window sees both marker kinds")
    opts = dict(miss=0.01, occlusion_rate=0.1, glitches=True, split_gap_frames=10,
                rename=True) if faults else dict(miss=0.0, occlusion_rate=0.0,
                                                 glitches=False, split_gap_frames=None,
                                                 rename=False)
    opts.update(kw)
    out, info = realistic(rec, seed=seed, fov_mm=hi - lo, fov_center_mm=0.5 * (lo + hi),
                          **opts)
    info["window"] = (centre - width / 2, centre + width / 2)
    info["edge_mm"] = edge
    return out, info


def _sees_speed_change(rec, inside, fps) -> bool:
    """Whether the body markers seen inside the window speed up or slow down by > 30 %."""
    body = [m for m, r in enumerate(rec.roles) if r == "body"]
    for m in body:
        sel = inside & (rec.marker_index == m)
        t, x = rec.t[sel], rec.x[sel]
        if len(t) < 10:
            continue
        o = np.argsort(t)
        v = np.gradient(x[o], t[o])
        k = max(1, int(0.1 * fps))
        vs = np.convolve(v, np.ones(k) / k, mode="valid")
        if len(vs) and np.ptp(vs) > 0.3 * max(np.max(np.abs(vs)), 1e-9):
            return True
    return False


def tracker_error(rec: Recording, *, seed: int = 0, mm_per_px=(0.2, 0.45),
                  lock_px=(0.004, 0.012), drift_um=(1.0, 3.0), drift_s=(0.3, 1.5),
                  read_um=(1.5, 6.0), px_columns: bool = False):
    """(Recording, info): `rec` (noise-free positions, mm) with a centroid tracker's error.

    - pixel locking: the marker's image position x_px = (x - x_origin) / scale (y_px from
      y, downwards), the origin at a random sub-pixel place; per axis a bias
      a1 sin(2 pi u + p1) + a2 sin(4 pi u + p2) px of the fractional position u, with
      a1 drawn in `lock_px` and a2 up to half of it (a centroid pulled towards pixel
      centres; the harmonic and phases differ between recordings, the same tracker for
      every marker). A marker at rest on the ground keeps its bias: an offset per contact.
    - drift: per marker and axis, Gaussian-filtered white noise of time scale drawn in
      `drift_s` (s), scaled to a standard deviation drawn in `drift_um` (um);
    - read noise: white, per marker a standard deviation drawn in `read_um` (um).
    Each range is (lo, hi) drawn uniformly per recording (scale, locking, drift time) or
    per marker (drift, read noise); a number fixes it. `px_columns`: also deliver x_px and
    y_px (as a tracker's export with pixel columns). info: the drawn values.
    """
    rng = np.random.default_rng([seed, 42])

    def draw(v, size=None):
        return rng.uniform(*v, size) if isinstance(v, tuple) else (
            np.full(size, float(v)) if size is not None else float(v))

    scale = draw(mm_per_px)
    a1 = np.array([draw(lock_px), draw(lock_px)])
    a2 = a1 * rng.uniform(0.0, 0.5, 2)
    ph = rng.uniform(0, 2 * np.pi, (2, 2))
    tau = draw(drift_s)
    valid = np.isfinite(rec.x) & np.isfinite(rec.y)
    x0 = float(np.min(rec.x[valid])) - 50.0 + rng.uniform(0, scale)
    y0 = float(np.max(rec.y[valid])) + 50.0 + rng.uniform(0, scale)
    xpx = (rec.x - x0) / scale
    ypx = (y0 - rec.y) / scale

    def lock(u, ax):
        return (a1[ax] * np.sin(2 * np.pi * u + ph[ax, 0])
                + a2[ax] * np.sin(4 * np.pi * u + ph[ax, 1]))

    dx = lock(xpx, 0) * scale
    dy = -lock(ypx, 1) * scale
    fps = _fps(rec)
    d_um = draw(drift_um, rec.n_markers)
    r_um = draw(read_um, rec.n_markers)
    times = np.unique(rec.t)
    sig = max(tau * fps, 1.0)
    kern = np.exp(-0.5 * (np.arange(-int(4 * sig), int(4 * sig) + 1) / sig) ** 2)
    for m in range(rec.n_markers):
        sel = rec.marker_index == m
        k = np.searchsorted(times, rec.t[sel])
        for arr in (dx, dy):
            w = np.convolve(rng.standard_normal(len(times) + len(kern) - 1), kern, "valid")
            w *= 1e-3 * d_um[m] / max(float(np.std(w)), 1e-12)
            arr[sel] += w[k] + 1e-3 * r_um[m] * rng.standard_normal(int(sel.sum()))
    extra = {}
    if px_columns:
        extra = {"x_px": xpx + dx / scale, "y_px": ypx - dy / scale}
    out = dataclasses.replace(rec, x=rec.x + dx, y=rec.y + dy, sigma=None, **extra)
    info = {"mm_per_px": scale, "lock_px": a1.tolist(), "lock2_px": a2.tolist(),
            "drift_s": tau, "drift_um": d_um.tolist(), "read_um": r_um.tolist(),
            "lock_um": (1e3 * a1 * scale).tolist()}
    return out, info


def shift_time(rec: Recording, offset_s: float) -> Recording:
    """The same recording with every time stamp moved by offset_s (a camera's clock)."""
    return dataclasses.replace(rec, t=rec.t + offset_s)


def write_wide(path, rec: Recording) -> None:
    """The wide export of motion-analysis programs: time_s, <id>_x_mm, <id>_y_mm, ..."""
    times = np.unique(rec.t)
    cols = [np.array([repr(float(t)) for t in times])]
    header = ["time_s"]
    idx = np.searchsorted(times, rec.t)
    for m, name in enumerate(rec.markers):
        for arr, ax in ((rec.x, "x"), (rec.y, "y")):
            col = np.full(len(times), np.nan)
            sel = rec.marker_index == m
            col[idx[sel]] = arr[sel]
            cols.append(np.array(["" if not np.isfinite(v) else repr(float(v)) for v in col]))
            header.append(f"{name}_{ax}_mm")
    lines = [f"# {k}: {v}" for k, v in rec.meta.items()]
    lines.append(",".join(header))
    for row in zip(*cols):
        lines.append(",".join(row))
    write_text_atomic(path, "\n".join(lines) + "\n")


def write_realistic(out_dir, rec: Recording, rig, *, wide: bool = True) -> str:
    """Write trajectories.csv (wide export form if `wide`) and rig.toml (with the roles)."""
    os.makedirs(out_dir, exist_ok=True)
    body = tuple(m for m, r in zip(rec.markers, rec.roles) if r == "body")
    lug = tuple(m for m, r in zip(rec.markers, rec.roles) if r == "lug")
    write_rig(os.path.join(out_dir, "rig.toml"),
              dataclasses.replace(rig, body_markers=body, lug_markers=lug))
    path = os.path.join(out_dir, "trajectories.csv")
    if wide:
        write_wide(path, rec)
    else:
        write_trajectories(path, rec)
    return path
