"""A small self-contained track scene (MODEL.md §2 kinematics) to render for tests and benchmarks.

Not the simulator of the project (that is `fitlug.sim.simulate`): just enough physics to
move markers like the real rig does - body markers translating, lug markers going round the
stadium path with a constant slip - in NumPy, without JAX.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def stadium_path(u: np.ndarray, d_mm: float, r_mm: float, e_mm: float) -> np.ndarray:
    """(..., 2) path position relative to the body of belt coordinate u (MODEL.md §2 table)."""
    p = 2 * d_mm + 2 * np.pi * r_mm
    u = np.mod(u, p)
    out = np.empty(u.shape + (2,))
    re = r_mm + e_mm
    seg = [u < d_mm, u < d_mm + np.pi * r_mm, u < 2 * d_mm + np.pi * r_mm]
    phi_rear = (u - d_mm) / r_mm
    phi_front = (u - 2 * d_mm - np.pi * r_mm) / r_mm
    out[..., 0] = np.select(seg, [d_mm / 2 - u, -d_mm / 2 - re * np.sin(phi_rear),
                                  -d_mm / 2 + (u - d_mm - np.pi * r_mm)],
                            d_mm / 2 + re * np.sin(phi_front))
    out[..., 1] = np.select(seg, [np.full_like(u, -e_mm), r_mm - re * np.cos(phi_rear),
                                  np.full_like(u, 2 * r_mm + e_mm)],
                            r_mm + re * np.cos(phi_front))
    return out


def stadium_scene(n_frames: int = 100, fps: float = 100.0, *, speed_mm_s: float = 150.0,
                  slip: float = 0.0772, n_lug_markers: int = 8, n_body_markers: int = 2,
                  d_mm: float = 127.0, r_mm: float = 30.0, e_mm: float = 6.0,
                  n_lugs: int = 24, x0_mm: float = 0.0, ramp_s: float = 0.0):
    """Positions of body and lug markers of one track module driving along x.

    The body moves at `speed_mm_s` (after a smooth start of `ramp_s` seconds), the belt at
    v / (1 - slip); lug markers sit on consecutive lugs, pitch (2D + 2πR) / n_lugs, starting
    at the front of the bottom run; body markers sit between the runs.

    Returns (t (F,), markers [str], roles [str], xy_mm (F, M, 2)); lug markers first.
    """
    t = np.arange(n_frames) / fps
    if ramp_s > 0:  # smooth start: v ramps as (1 - cos) over ramp_s
        ramp = np.clip(t / ramp_s, 0, 1)
        x_body = speed_mm_s * np.where(t < ramp_s,
                                       0.5 * (t - ramp_s / np.pi * np.sin(np.pi * ramp)),
                                       t - 0.5 * ramp_s)
    else:
        x_body = speed_mm_s * t
    x_body = x_body + x0_mm
    psi = (x_body - x0_mm) / (1 - slip)  # belt travel relative to the body
    pitch = (2 * d_mm + 2 * np.pi * r_mm) / n_lugs
    sigma0 = 0.3 * pitch + pitch * np.arange(n_lug_markers)
    lug = stadium_path(sigma0[None, :] + psi[:, None], d_mm, r_mm, e_mm)
    lug[..., 0] += x_body[:, None]
    body_offsets = np.stack([np.linspace(-0.3 * d_mm, 0.3 * d_mm, n_body_markers),
                             np.full(n_body_markers, r_mm)], axis=1)
    body = body_offsets[None] + np.stack([x_body, np.zeros_like(x_body)], axis=1)[:, None]
    xy = np.concatenate([lug, body], axis=1)
    markers = [f"L{i + 1:02d}" for i in range(n_lug_markers)] + \
              [f"Q{j + 1}" for j in range(n_body_markers)]
    roles = ["lug"] * n_lug_markers + ["body"] * n_body_markers
    return t, markers, roles, xy


def hard_clip(n_frames: int = 120, image_size=(480, 320), *, seed: int = 0,
              mm_per_px: float = 0.39, cog_px: float = 9.0, qs_px: float = 10.0,
              noise_sigma: float = 4.0, gradient=(0.4, 0.2), vignetting: float = 0.15,
              exposure_s: float = 0.004, fps: float = 100.0, speed_mm_s: float = 60.0,
              bar_px: float = 10.0, bar_speed_px: float = -3.0, n_lug_markers: int = 8,
              n_body_markers: int = 2, d_mm: float | None = None, r_mm: float | None = None,
              origin_mm=None, keep_sub: bool = False, cog_contrast=()):
    """Hard footage with its truth: small markers (COG bright discs `cog_px` across, QS
    checkers `qs_px` a side; `cog_px` a sequence: one size per lug marker, in turn, and
    `cog_contrast` factors on their bright discs' contrast: dim discs), sensor noise
    `noise_sigma` grey levels, a lighting gradient and vignetting, motion blur
    (`exposure_s`), a dark vertical bar `bar_px` wide sweeping across the picture at
    `bar_speed_px` px/frame (hiding each marker a few frames), and the rig driving out of
    the picture on the right (markers leave and lug markers come round).

    The stadium is sized to the image (d_mm, r_mm default from its width and height); the
    rig starts with its rear at a fifth of the width. Returns a `HardClip` (frames in
    memory); `visible`: the marker is whole in the picture, clear of the bar and of other
    markers; with `keep_sub` the sub-frame positions too (for Cramer-Rao bounds).
    """
    from ._render import RenderOptions, default_camera, ground_to_pixels, gain_field
    from ._render import subframe_positions, render_frame, KINDS
    from ._render_video import _visible

    w, h = (int(v) for v in image_size)
    s = float(mm_per_px)
    # lug disc twice the bright disc; the options' size the largest disc's
    sizes = np.resize(np.asarray(cog_px, dtype=np.float64).reshape(-1), n_lug_markers)
    top = float(sizes.max())
    dim = tuple(float(c) for c in np.resize(np.asarray(cog_contrast, dtype=np.float64),
                                              n_lug_markers if len(cog_contrast) else 0))
    opt = RenderOptions(cog_diameter_mm=top * s, lug_diameter_mm=2.0 * top * s,
                        qs_size_mm=qs_px * s, noise_sigma=noise_sigma, gradient=tuple(gradient),
                        vignetting=vignetting, exposure_s=exposure_s,
                        marker_scale=tuple(sizes / top) if np.ptp(sizes) > 0 else (),
                        marker_contrast=dim)
    width_mm, height_mm = w * s, h * s
    r = 0.22 * height_mm if r_mm is None else float(r_mm)
    d = 0.45 * width_mm if d_mm is None else float(d_mm)
    t, names, roles, xy = stadium_scene(n_frames, fps, speed_mm_s=speed_mm_s,
                                        n_lug_markers=n_lug_markers,
                                        n_body_markers=n_body_markers, d_mm=d, r_mm=r,
                                        e_mm=0.1 * r, n_lugs=max(2 * n_lug_markers + 4, 12),
                                        ramp_s=0.1 * n_frames / fps)
    cam = default_camera(s, (w, h))
    if origin_mm is None:  # rear of the stadium at a quarter of the width, body mid-height
        origin_mm = (-(0.5 * d + r) - 0.2 * width_mm, r - 0.5 * height_mm)
    kinds = [KINDS[x] for x in roles]
    # visibility: the whole lug disc (twice the bright disc) for COG, the square for QS
    radii = np.full(len(kinds), 0.5 * qs_px * 2 ** 0.5)
    radii[:n_lug_markers] = sizes  # (lug markers first)
    sub = subframe_positions(t, xy, opt.exposure_s, opt.n_sub)
    rng = np.random.default_rng(seed)
    gain = gain_field((w, h), opt)
    frames = np.empty((t.size, h, w), np.uint8)
    truth = np.empty((t.size, len(names), 2))
    visible = np.empty((t.size, len(names)), bool)
    subs = np.empty((t.size, opt.n_sub, len(names), 2)) if keep_sub else None
    for i in range(t.size):
        sub_px = ground_to_pixels(cam, sub[i], origin_mm)
        x_bar = (w + bar_px if bar_speed_px < 0 else -bar_px) + bar_speed_px * i
        x_bar = x_bar % (w + 2 * bar_px) - bar_px
        o = opt.replace(occluders=((x_bar, -1, x_bar + bar_px, h + 1),))
        frames[i] = render_frame(sub_px, kinds, cam, o, rng, gain)
        truth[i] = sub_px.mean(axis=0)
        visible[i] = _visible(truth[i], radii, cam, o)
        if keep_sub:
            subs[i] = sub_px
    return HardClip(t, frames, truth, visible, kinds, subs, opt, cam, float(bar_px),
                    float(bar_speed_px))


@dataclass
class HardClip:
    """Frames of `hard_clip` with their truth: `t` (F,) s, `frames` (F, H, W) uint8,
    `truth` (F, M, 2) px, `visible` (F, M) bool, `kinds` ('cog'/'qs' per marker), `sub_px`
    (F, n_sub, M, 2) px or None, the `options` and `camera` drawn with (the bar apart:
    `bar_px` wide, moving `bar_speed_px` px per frame)."""

    t: np.ndarray
    frames: np.ndarray
    truth: np.ndarray
    visible: np.ndarray
    kinds: list
    sub_px: np.ndarray | None
    options: object
    camera: object
    bar_px: float
    bar_speed_px: float
