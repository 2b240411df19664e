"""Render a recording (ground-frame marker positions over time) as a folder of camera frames.

`render_frames` yields frames in memory (benchmarks, tests); `render_video` writes
frame_00000.png ..., truth_px.csv (the true pixel positions), calib.json (the camera, so
that `fit-lug track DIR --fps F --calib DIR/calib.json` maps back to mm) and render.json
(the options and the origin).
"""

from __future__ import annotations

import csv
import json
import os
import sys
from dataclasses import asdict, dataclass
from typing import Iterator, Sequence

import numpy as np

from .._errors import InputError
from ..io._atomic import atomic_path, write_text_atomic
from ..io._calibration import Calibration
from ._render import (KINDS, RenderOptions, auto_origin, default_camera, gain_field,
                      ground_to_pixels, render_frame, subframe_positions)


@dataclass
class RenderedFrame:
    """One rendered frame: `image` (H, W) uint8, `truth_px` (M, 2) (NaN: not in the scene),
    `visible` (M,) bool: whole, not overlapped and not occluded (a tracker should find it)."""

    index: int
    time_s: float
    image: np.ndarray
    truth_px: np.ndarray
    visible: np.ndarray


def _check_inputs(t, markers, roles, xy_mm):
    t = np.asarray(t, dtype=np.float64)
    xy = np.asarray(xy_mm, dtype=np.float64)
    if t.ndim != 1 or t.size == 0:
        raise ValueError(f"t must be a non-empty 1-D array of times, got shape {t.shape}")
    if xy.shape != (t.size, len(markers), 2):
        raise ValueError(f"xy_mm must have shape (F, M, 2) = ({t.size}, {len(markers)}, 2), "
                         f"got {xy.shape}")
    if len(roles) != len(markers):
        raise ValueError(f"{len(markers)} markers but {len(roles)} roles")
    bad = [r for r in roles if r not in KINDS]
    if bad:
        raise ValueError(f"role must be 'body' or 'lug', got {bad[0]!r}")
    if not np.isfinite(t).all() or np.any(np.diff(t) <= 0):
        raise ValueError("t must be finite and strictly increasing")
    return t, xy


def _visible(truth: np.ndarray, radii: np.ndarray, camera: Calibration,
             opt: RenderOptions) -> np.ndarray:
    w, h = camera.image_size
    ok = np.isfinite(truth).all(axis=1)
    x, y = truth[:, 0], truth[:, 1]
    with np.errstate(invalid="ignore"):
        ok &= (x - radii > 1) & (x + radii < w - 2) & (y - radii > 1) & (y + radii < h - 2)
        for x0, y0, x1, y1 in opt.occluders:
            ok &= ~((x + radii > x0) & (x - radii < x1) & (y + radii > y0) & (y - radii < y1))
        d = np.hypot(x[:, None] - x[None, :], y[:, None] - y[None, :])
        close = d < (radii[:, None] + radii[None, :])
    np.fill_diagonal(close, False)
    return ok & ~close.any(axis=1)


def render_frames(t, markers: Sequence[str], roles: Sequence[str], xy_mm, *,
                  camera: Calibration | None = None, origin_mm=None,
                  options: RenderOptions | None = None, seed: int = 0) -> Iterator[RenderedFrame]:
    """Yield the frames of a recording, one `RenderedFrame` at a time.

    t: (F,) s; xy_mm: (F, M, 2) ground-frame positions (NaN: the marker is not there);
    roles 'lug' (drawn as COG markers) or 'body' (QS markers). camera: default
    `default_camera()`; origin_mm: ground point at the image's bottom-left corner (default:
    `auto_origin`, centring the markers). Noise is drawn from np.random.default_rng(seed).
    """
    t, xy = _check_inputs(t, markers, roles, xy_mm)
    camera = default_camera() if camera is None else camera
    opt = RenderOptions() if options is None else options
    origin = auto_origin(xy, camera) if origin_mm is None else tuple(map(float, origin_mm))
    kinds = [KINDS[r] for r in roles]
    s = camera.mm_per_px
    radii = np.array([0.5 * (opt.lug_diameter_mm if k == "cog" else opt.qs_size_mm * 2 ** 0.5) / s
                      for k in kinds])
    sub = subframe_positions(t, xy, opt.exposure_s, opt.n_sub)  # (F, n_sub, M, 2) mm
    rng = np.random.default_rng(seed)
    gain = gain_field(camera.image_size, opt)
    for i in range(t.size):
        sub_px = ground_to_pixels(camera, sub[i], origin)  # (n_sub, M, 2)
        truth = sub_px.mean(axis=0)
        image = render_frame(sub_px, kinds, camera, opt, rng, gain)
        yield RenderedFrame(i, float(t[i]), image, truth, _visible(truth, radii, camera, opt))


def render_video(out_dir: str | os.PathLike, t, markers: Sequence[str], roles: Sequence[str],
                 xy_mm, *, mm_per_px: float = 0.39, image_size: tuple[int, int] = (1632, 1200),
                 origin_mm=None, camera: Calibration | None = None,
                 options: RenderOptions | None = None, seed: int = 0,
                 progress: bool = True) -> dict:
    """Write a simulated recording as camera frames with their true pixel positions.

    out_dir gets frame_00000.png ... (8-bit grey), truth_px.csv (frame, time_s, marker,
    role, x_px, y_px, visible; empty where a marker is not in the scene), calib.json (the
    camera; its "scale" entry carries origin_mm, the ground point at the image's
    bottom-left corner, so that mm from `fit-lug track` + origin_mm = the input's frame)
    and render.json. camera defaults to `default_camera(mm_per_px, image_size)`.

    Returns {"frames": F, "origin_mm": (x0, y0), "calib": path, "truth": path}.
    Raises ValueError for inconsistent shapes, unknown roles or bad times.
    """
    import cv2

    from ..vision.calibrate._calib_io import save_calibration

    t, xy = _check_inputs(t, markers, roles, xy_mm)
    camera = default_camera(mm_per_px, image_size) if camera is None else camera
    opt = RenderOptions() if options is None else options
    origin = auto_origin(xy, camera) if origin_mm is None else tuple(map(float, origin_mm))
    out_dir = os.fspath(out_dir)
    os.makedirs(out_dir, exist_ok=True)
    frames = render_frames(t, markers, roles, xy, camera=camera, origin_mm=origin, options=opt,
                           seed=seed)
    if progress:
        from tqdm.auto import tqdm

        frames = tqdm(frames, total=t.size, desc="render", unit="frame", file=sys.stderr,
                      disable=not sys.stderr.isatty())
    truth_path = os.path.join(out_dir, "truth_px.csv")
    with atomic_path(truth_path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as fh:
        fh.write(f"# origin_mm: {origin[0]:g},{origin[1]:g}\n# mm_per_px: {camera.mm_per_px!r}\n")
        writer = csv.writer(fh, lineterminator="\n")
        writer.writerow(["frame", "time_s", "marker", "role", "x_px", "y_px", "visible"])
        for fr in frames:
            name = os.path.join(out_dir, f"frame_{fr.index:05d}.png")
            with atomic_path(name, suffix=".png") as tmp_png:
                if not cv2.imwrite(tmp_png, fr.image, [cv2.IMWRITE_PNG_COMPRESSION, 1]):
                    raise InputError(name, "could not write the frame")
            for m, marker in enumerate(markers):
                x, y = fr.truth_px[m]
                writer.writerow([fr.index, repr(fr.time_s), marker, roles[m],
                                 repr(float(x)) if np.isfinite(x) else "",
                                 repr(float(y)) if np.isfinite(y) else "", int(fr.visible[m])])
    scale = dict(camera.scale or {})
    scale["origin_mm"] = [origin[0], origin[1]]
    cal = Calibration(camera.camera_matrix, camera.dist_coeffs, camera.image_size,
                      rms_px=camera.rms_px, mm_per_px=camera.mm_per_px, scale=scale)
    calib_path = os.path.join(out_dir, "calib.json")
    save_calibration(calib_path, cal)
    info = {"frames": int(t.size), "fps": float(1 / np.median(np.diff(t))) if t.size > 1 else None,
            "origin_mm": list(origin), "markers": list(markers), "roles": list(roles),
            "seed": seed, "options": asdict(opt)}
    write_text_atomic(os.path.join(out_dir, "render.json"), json.dumps(info, indent=2) + "\n")
    return {"frames": int(t.size), "origin_mm": origin, "calib": calib_path, "truth": truth_path}


def recording_scene(scenario, *, seed: int = 0, image_size=(1632, 1200),
                    mm_per_px: float = 0.39, window_mm: float | None = None,
                    window_at: float | None = None, lens_k1: float | None = None) -> dict:
    """What `render_recording` draws: {"t" (F,) s, "markers", "roles", "xy_mm" (F, M, 2)
    noise-free ground positions, "camera", "origin_mm" (None: centred on the markers)}.

    window_mm: the ground width the picture spans (else mm_per_px x the width); window_at:
    where the picture's centre sits along the travel (0: the markers' centre at the first
    frame, 1: at the last); lens_k1: radial distortion (focal length 1.225 x the width;
    0: none; None: `default_camera`'s). Raises ValueError for a window out of range.
    """
    from ._simulate import simulate

    rec, _ = simulate(scenario.replace(noise_lug_mm=0.0, noise_body_mm=0.0), seed)
    t = np.unique(rec.t)
    xy = np.full((t.size, rec.n_markers, 2), np.nan)
    row = np.searchsorted(t, rec.t)
    xy[row, rec.marker_index, 0] = rec.x
    xy[row, rec.marker_index, 1] = rec.y
    w, h = (int(v) for v in image_size)
    if window_mm is not None:
        if not (np.isfinite(window_mm) and window_mm > 0):
            raise ValueError(f"window_mm must be a positive number of mm, got {window_mm!r}")
        mm_per_px = float(window_mm) / w
    s = float(mm_per_px)
    if lens_k1 is None:
        camera = default_camera(s, (w, h))
    else:
        camera = default_camera(s, (w, h), focal_px=1.225 * w,
                                dist_coeffs=None if lens_k1 == 0 else
                                (float(lens_k1), 0.0, 0.0, 0.0, 0.0))
    origin = None
    if window_at is not None:
        if not (np.isfinite(window_at) and -1.0 <= window_at <= 2.0):
            raise ValueError(f"window_at must be between -1 and 2, got {window_at!r}")
        centre = np.nanmean(xy, axis=1)  # (F, 2): the markers' centre, frame by frame
        c0, c1 = centre[0], centre[-1]
        lo, hi = np.nanmin(xy[..., 1]), np.nanmax(xy[..., 1])
        cx = c0[0] + window_at * (c1[0] - c0[0])
        origin = (float(np.round(cx - 0.5 * w * s, 3)),
                  float(np.round(0.5 * (lo + hi) - 0.5 * h * s, 3)))
    return {"t": t, "markers": list(rec.markers), "roles": list(rec.roles), "xy_mm": xy,
            "camera": camera, "origin_mm": origin}


def render_recording(out_dir: str | os.PathLike, scenario, *, seed: int = 0,
                     frames: int | None = None, progress: bool = True,
                     window_mm: float | None = None, window_at: float | None = None,
                     lens_k1: float | None = None, **kwargs) -> dict:
    """Render a simulated recording (`fitlug.sim.Scenario`) as camera frames.

    The markers are drawn at their noise-free positions (the camera adds its own noise);
    lug markers as COG discs, body markers as QS checkers. frames: render only the first
    N frames. A drive-through (the robot entering, crossing and leaving a fixed picture):
    window_mm, the ground width the picture spans, mm (mm per px = window_mm / image
    width; default 0.39 mm/px); window_at, where the picture's centre sits along the
    travel: 0 where the markers' centre is at the first frame, 1 where it is at the last
    (default: the picture centred on every position the markers take); lens_k1: the radial
    distortion rendered in (focal length 1.225 x the image width; 0: none; default: the
    mild barrel of `default_camera`); see `recording_scene`. Other keyword arguments go to
    `render_video` (mm_per_px, image_size, origin_mm, camera, options). Returns what
    `render_video` returns. Raises ValueError for a window or position out of range.
    """
    if frames is not None and frames < 1:
        raise ValueError(f"frames must be at least 1, got {frames}")
    image_size = kwargs.pop("image_size", (1632, 1200))
    sc = recording_scene(scenario, seed=seed, image_size=image_size,
                         mm_per_px=kwargs.pop("mm_per_px", 0.39), window_mm=window_mm,
                         window_at=window_at, lens_k1=lens_k1)
    camera = kwargs.pop("camera", None) or sc["camera"]
    origin = kwargs.pop("origin_mm", None)
    origin = sc["origin_mm"] if origin is None else origin
    t, xy = sc["t"], sc["xy_mm"]
    if frames is not None:
        t, xy = t[:frames], xy[:frames]
    return render_video(out_dir, t, sc["markers"], sc["roles"], xy, seed=seed,
                        progress=progress, image_size=camera.image_size,
                        mm_per_px=camera.mm_per_px, origin_mm=origin, camera=camera, **kwargs)
