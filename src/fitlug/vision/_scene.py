"""A small self-contained track scene (MODEL.md §2 kinematics) to render for tests and benchmarks.

Not the simulator of the project (that is `fitlug.sim`): just enough physics to move
markers like the real rig does - body markers translating, lug markers going round the
stadium path with a constant slip - without importing JAX.
"""

from __future__ import annotations

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
