"""Measurement noise of the tracker on a recording of a stationary robot.

Every marker should stay put, so the spread of its positions about its own mean is the
noise of the whole chain (camera, lighting, detection). The reference rig used 100 frames.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ..._errors import InputError
from ...io._calibration import Calibration
from ._pipeline import track
from ._track import TrackerConfig, TrackResult


@dataclass
class NoiseResult:
    """Noise per marker and per role. `per_marker`: one dict per marker (marker, role,
    kind, n, std_x_px, std_y_px, std_px, and the same in mm when a calibration was given);
    `per_role`: {role: {markers, n, std_x_px, std_y_px, std_px[, ..._mm]}} pooled over the
    role's markers. std_px is the per-axis noise, sqrt((σx² + σy²) / 2): the "one standard
    deviation per role" of MODEL.md."""

    per_marker: list
    per_role: dict
    frames: int


def _pooled(devs):
    """sqrt of the pooled variance of lists of deviation arrays (each about its own mean)."""
    ss = sum(float(np.sum(d * d)) for d in devs)
    dof = sum(max(d.size - 1, 0) for d in devs)
    return float(np.sqrt(ss / dof)) if dof > 0 else float("nan")


#: a marker whose spread about its mean exceeds this many times its frame-to-frame noise
#: (from second differences, which cancel a steady motion) is moving, not noisy
MOVING_RATIO = 10.0


def _check_still(marker, pts: np.ndarray) -> None:
    """Refuse a marker that moves: its spread would be reported as noise (a moving robot
    gave 13.5 mm "noise")."""
    if pts.shape[0] < 5:
        return
    spread = float(np.sqrt(np.mean((pts - pts.mean(axis=0)) ** 2)))
    d2 = np.diff(pts, n=2, axis=0)
    noise = float(np.sqrt(np.mean(d2 ** 2) / 6.0))  # white noise: var(d2) = 6 sigma^2
    if spread > MOVING_RATIO * max(noise, 1e-3) and spread > 0.5:
        raise InputError(None, f"marker {marker} moves during the recording: its positions "
                               f"spread {spread:.3g} px about their mean against a "
                               f"frame-to-frame noise of {noise:.3g} px; `fit-lug noise` "
                               "needs a recording of a stationary robot")


def noise_from_tracks(result: TrackResult, calibration: Calibration | None = None,
                      min_samples: int = 10) -> NoiseResult:
    """Noise of tracked stationary markers (see `NoiseResult`); markers with fewer than
    `min_samples` samples are left out. Raises InputError when no marker has enough, and
    when a marker moves (its spread is then motion, not noise)."""
    n_frames = int(result.xy_px.shape[0])
    if n_frames < min_samples:
        raise InputError(None, f"too few frames: {n_frames} tracked, the noise needs at "
                               f"least {min_samples}")
    per_marker, by_role = [], {}
    mm = None
    if calibration is not None:
        f, m = result.xy_px.shape[:2]
        mm = calibration.pixels_to_mm(result.xy_px.reshape(-1, 2)).reshape(f, m, 2)
    for k, marker in enumerate(result.markers):
        ok = np.isfinite(result.xy_px[:, k, 0])
        n = int(ok.sum())
        if n < min_samples:
            continue
        _check_still(marker, result.xy_px[ok, k])
        row = {"marker": marker, "role": result.roles[k], "kind": result.kinds[k], "n": n}
        units = [("px", result.xy_px[ok, k])] + ([("mm", mm[ok, k])] if mm is not None else [])
        devs = {}
        for unit, pts in units:
            d = pts - pts.mean(axis=0)
            devs[unit] = d
            row[f"std_x_{unit}"] = _pooled([d[:, 0]])
            row[f"std_y_{unit}"] = _pooled([d[:, 1]])
            row[f"std_{unit}"] = _pooled([d[:, 0], d[:, 1]])
        per_marker.append(row)
        by_role.setdefault(result.roles[k], []).append((marker, devs))
    if not per_marker:
        raise InputError(None, f"no marker was found in at least {min_samples} frames: "
                         "cannot measure the noise")
    per_role = {}
    for role, items in by_role.items():
        entry = {"markers": [m for m, _ in items],
                 "n": int(sum(d["px"].shape[0] for _, d in items))}
        for unit in items[0][1]:
            entry[f"std_x_{unit}"] = _pooled([d[unit][:, 0] for _, d in items])
            entry[f"std_y_{unit}"] = _pooled([d[unit][:, 1] for _, d in items])
            entry[f"std_{unit}"] = _pooled([d[unit][:, i] for _, d in items for i in (0, 1)])
        per_role[role] = entry
    return NoiseResult(per_marker, per_role, int(result.frames.size))


def measure_noise(source, *, fps: float | None = None, frames: int | None = 100,
                  calibration: Calibration | None = None, config: TrackerConfig | None = None,
                  progress: bool = False) -> NoiseResult:
    """Noise per marker type of a recording of a stationary robot, px (and mm with a
    calibration). frames: use the first N frames (None: all). See `NoiseResult`."""
    if isinstance(source, np.ndarray):  # time plays no part here: any frame rate will do
        source = source if frames is None else source[:int(frames)]
        result = track(source, fps=fps or 1.0, config=config, progress=progress)
    else:
        if fps is None and os.path.isdir(os.fspath(source)):
            fps = 1.0
        result = track(source, fps=fps, config=config, progress=progress,
                       frames=None if frames is None else slice(0, int(frames)))
    return noise_from_tracks(result, calibration)


def format_noise(noise: NoiseResult) -> str:
    """A plain-text table of a NoiseResult (roles, then markers)."""
    has_mm = "std_mm" in next(iter(noise.per_role.values()))
    head = f"{'':<8}{'markers':>8}{'samples':>9}{'σx px':>10}{'σy px':>10}{'σ px':>10}"
    if has_mm:
        head += f"{'σx mm':>10}{'σy mm':>10}{'σ mm':>10}"
    lines = [f"noise over {noise.frames} frames (σ: per axis, sqrt((σx² + σy²)/2))", head]

    def cells(row):
        text = f"{row['std_x_px']:>10.4f}{row['std_y_px']:>10.4f}{row['std_px']:>10.4f}"
        if has_mm:
            text += f"{row['std_x_mm']:>10.5f}{row['std_y_mm']:>10.5f}{row['std_mm']:>10.5f}"
        return text

    for role, row in noise.per_role.items():
        lines.append(f"{role:<8}{len(row['markers']):>8}{row['n']:>9}" + cells(row))
    lines.append("")
    for row in noise.per_marker:
        lines.append(f"{row['marker']:<8}{row['kind']:>8}{row['n']:>9}" + cells(row))
    return "\n".join(lines)
