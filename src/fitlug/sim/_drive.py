"""Drive-through footage with its truth (issue 26): the camera is started before the robot
arrives, the robot drives into a fixed window, crosses it and drives out.

`drive_clip` renders such a recording in memory (like `_scene.hard_clip`): a window
`window_mm` wide (mm per px = window_mm / image width) placed anywhere along the travel
(`window_at`, `window_y_mm`), a speed profile with a rest, a smooth ramp up, a cruise and
an optional braking, the robot driving either way (`direction`), frame rates of choice,
lens distortion rendered in (`lens_k1`), static posts in front of the camera and a side
plate carried by the robot that hides the top run of the track (lug markers then come into
view mid-picture as they turn round the front wheel). Not the project's simulator
(`fitlug.sim`): the stadium kinematics of `_scene` with a constant slip.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ._scene import stadium_path


def _profile(t, *, rest_s, ramp_s, cruise_s, brake_s, speed):
    """Body travel (mm) at times t: at rest for rest_s, a (1 - cos) ramp to `speed` over
    ramp_s, a cruise of cruise_s, a (1 - cos) ramp down over brake_s, at rest after."""
    tau = np.asarray(t, dtype=np.float64) - rest_s
    x = np.zeros_like(tau)
    a = np.clip(tau, 0.0, ramp_s)
    if ramp_s > 0:
        x += 0.5 * speed * (a - ramp_s / np.pi * np.sin(np.pi * a / ramp_s))
    x += speed * np.clip(tau - ramp_s, 0.0, cruise_s)
    b = np.clip(tau - ramp_s - cruise_s, 0.0, brake_s)
    if brake_s > 0:
        x += 0.5 * speed * (b + brake_s / np.pi * np.sin(np.pi * b / brake_s))
    return x


@dataclass
class DriveClip:
    """Frames of `drive_clip` with their truth: `t` (F,) s, `frames` (F, H, W) uint8, `truth`
    (F, M, 2) px (the centre of what was drawn), `inside` (F, M) the whole marker (COG: its
    lug disc; QS: its square's circumcircle) lies in the picture, `visible` (F, M) inside
    and clear of occluders and of other markers (a tracker owes a sample there), `kinds`,
    `roles`, `markers`, `xy_mm` (F, M, 2) ground positions, the `camera` drawn with (its
    distortion included), `origin_mm` (ground point at the image's bottom-left corner),
    `options`, `occluders` (F, K, 4) px rectangles per frame and `info` (the settings)."""

    t: np.ndarray
    frames: np.ndarray
    truth: np.ndarray
    inside: np.ndarray
    visible: np.ndarray
    kinds: list
    roles: list
    markers: list
    xy_mm: np.ndarray
    camera: object
    origin_mm: tuple
    options: object
    occluders: np.ndarray
    info: dict = field(default_factory=dict)


def drive_scene(*, fps=100.0, speed_mm_s=200.0, direction=1, rest_s=0.2, ramp_s=0.4,
                brake_s=0.0, rest_end_s=0.2, travel_mm=600.0, slip=0.0772, n_lug_markers=8,
                n_body_markers=2, d_mm=127.0, r_mm=30.0, e_mm=6.0, n_lugs=24):
    """Marker positions of one track module driving `travel_mm` along x (`direction` +1 or
    -1) with the profile of `_profile` (cruise time from the travel). Returns (t (F,),
    markers, roles, xy_mm (F, M, 2), x_body (F,)); the body starts at x = 0, its axle
    height is r_mm, lug markers first."""
    if speed_mm_s <= 0 or travel_mm <= 0 or fps <= 0:
        raise ValueError("speed_mm_s, travel_mm and fps must be > 0")
    cruise_s = travel_mm / speed_mm_s - 0.5 * (ramp_s + brake_s)
    if cruise_s < 0:
        raise ValueError(f"travel_mm {travel_mm:g} is shorter than the ramps cover")
    total = rest_s + ramp_s + cruise_s + brake_s + rest_end_s
    t = np.arange(int(np.ceil(total * fps)) + 1) / fps
    x_body = direction * _profile(t, rest_s=rest_s, ramp_s=ramp_s, cruise_s=cruise_s,
                                  brake_s=brake_s, speed=speed_mm_s)
    psi = x_body / (1 - slip)  # belt travel relative to the body
    pitch = (2 * d_mm + 2 * np.pi * r_mm) / n_lugs
    sigma0 = 0.3 * pitch + pitch * np.arange(n_lug_markers)
    lug = stadium_path(sigma0[None, :] + psi[:, None], d_mm, r_mm, e_mm)
    lug[..., 0] += x_body[:, None]
    offs = np.stack([np.linspace(-0.3 * d_mm, 0.3 * d_mm, n_body_markers),
                     np.full(n_body_markers, r_mm)], axis=1)
    body = offs[None] + np.stack([x_body, np.zeros_like(x_body)], axis=1)[:, None]
    xy = np.concatenate([lug, body], axis=1)
    markers = [f"L{i + 1:02d}" for i in range(n_lug_markers)] + \
              [f"Q{j + 1}" for j in range(n_body_markers)]
    roles = ["lug"] * n_lug_markers + ["body"] * n_body_markers
    return t, markers, roles, xy, x_body


def drive_clip(image_size=(480, 360), *, window_mm=300.0, window_at=0.5, window_y_mm=None,
               fps=100.0, speed_mm_s=200.0, direction=1, rest_s=0.2, ramp_s=0.4,
               brake_s=0.0, rest_end_s=0.2, travel_mm=None, lead_mm=30.0, lens_k1=0.0,
               noise_sigma=2.0, gradient=(0.3, 0.15), vignetting=0.1, exposure_s=0.002,
               posts=(), plate=False, n_lug_markers=8, n_body_markers=2, d_mm=127.0,
               r_mm=30.0, e_mm=6.0, n_lugs=24, slip=0.0772, cog_mm=6.0, lug_mm=12.0,
               qs_mm=10.0, seed=0) -> DriveClip:
    """Render a drive-through recording in memory.

    image_size: (width, height) px; window_mm: ground width the picture spans, mm (the
    reference rig 637, zoomed in 300-400); window_at: where the picture's centre sits along
    the travel (0: the start position of the body, 1: its end position); window_y_mm: the
    ground height of the picture's centre (default the axle height: the whole track in
    view; lower or higher cuts the track, and lug markers come into view across the
    bottom or top edge as they turn round a wheel); travel_mm: body travel (default: the
    window plus the track's length plus 2 x lead_mm, so that with window_at 0.5 nothing is
    in view for a while at the start and at the end); speeds mm/s, times s; direction -1:
    the robot drives towards -x (it enters on the right); lens_k1: radial distortion
    coefficient rendered in (focal length 1.25 x the image width; 0: none); posts: static
    occluders, (x, width) px, full height; plate: a side plate moving with the robot hides
    the top run (lug markers come into view below it at the front wheel); sizes of the
    markers in mm (COG bright disc, its lug disc, QS square side). Everything random comes
    from `seed`. Raises ValueError for impossible settings.
    """
    from ..io._calibration import Calibration
    from ._render import (KINDS, RenderOptions, gain_field, ground_to_pixels, render_frame,
                          subframe_positions)
    from ._render_video import _visible

    w, h = (int(v) for v in image_size)
    if not 10.0 <= window_mm <= 1e4 or w < 32 or h < 32:
        raise ValueError(f"window_mm must be 10..1e4 mm and the image >= 32 px a side, got "
                         f"{window_mm} mm and {w}x{h}")
    s = float(window_mm) / w
    half_len = 0.5 * d_mm + r_mm + e_mm + 0.5 * lug_mm
    if travel_mm is None:
        travel_mm = window_mm + 2 * half_len + 2 * lead_mm
    t, markers, roles, xy, x_body = drive_scene(
        fps=fps, speed_mm_s=speed_mm_s, direction=direction, rest_s=rest_s, ramp_s=ramp_s,
        brake_s=brake_s, rest_end_s=rest_end_s, travel_mm=travel_mm, slip=slip,
        n_lug_markers=n_lug_markers, n_body_markers=n_body_markers, d_mm=d_mm, r_mm=r_mm,
        e_mm=e_mm, n_lugs=n_lugs)
    if lens_k1:
        f = 1.25 * w
        k = np.array([[f, 0.0, (w - 1) / 2], [0.0, f, (h - 1) / 2], [0.0, 0.0, 1.0]])
        cam = Calibration(k, np.array([lens_k1, 0.0, 0.0, 0.0, 0.0]), (w, h), rms_px=0.0,
                          mm_per_px=s, scale={"method": "rendered"})
    else:
        cam = Calibration.from_scale(s, (w, h))
    centre_x = direction * window_at * travel_mm
    centre_y = r_mm if window_y_mm is None else float(window_y_mm)
    origin = (float(centre_x - 0.5 * w * s), float(centre_y - 0.5 * h * s))
    opt = RenderOptions(cog_diameter_mm=cog_mm, lug_diameter_mm=lug_mm, qs_size_mm=qs_mm,
                        noise_sigma=noise_sigma, gradient=tuple(gradient),
                        vignetting=vignetting, exposure_s=exposure_s)
    kinds = [KINDS[r] for r in roles]
    radii = np.array([0.5 * (lug_mm if k == "cog" else qs_mm * 2 ** 0.5) / s for k in kinds])
    sub = subframe_positions(t, xy, opt.exposure_s, opt.n_sub)
    rng = np.random.default_rng(seed)
    gain = gain_field((w, h), opt)
    static = [(float(x), -1.0, float(x) + float(wd), h + 1.0) for x, wd in posts]
    # the side plate, body frame (mm): over the whole length, from 1.45 r up past the top run
    reach = 0.5 * d_mm + r_mm + e_mm + lug_mm
    plate_mm = np.array([[-reach, 1.45 * r_mm], [reach, 2 * r_mm + e_mm + lug_mm]])
    n_occ = len(static) + (1 if plate else 0)
    frames = np.empty((t.size, h, w), np.uint8)
    truth = np.empty((t.size, len(markers), 2))
    inside = np.empty((t.size, len(markers)), bool)
    visible = np.empty((t.size, len(markers)), bool)
    occ = np.empty((t.size, n_occ, 4))
    for i in range(t.size):
        rects = list(static)
        if plate:
            corners = np.array([[plate_mm[a, 0], plate_mm[b, 1]] for a in (0, 1) for b in (0, 1)])
            corners[:, 0] += x_body[i]
            px = ground_to_pixels(cam, corners, origin)
            rects.append((px[:, 0].min(), px[:, 1].min(), px[:, 0].max(), px[:, 1].max()))
        o = opt.replace(occluders=tuple(rects))
        sub_px = ground_to_pixels(cam, sub[i], origin)
        frames[i] = render_frame(sub_px, kinds, cam, o, rng, gain)
        truth[i] = sub_px.mean(axis=0)
        visible[i] = _visible(truth[i], radii, cam, o)
        inside[i] = _inside(truth[i], radii, w, h)
        occ[i] = np.asarray(rects, dtype=np.float64).reshape(n_occ, 4)
    info = {"window_mm": float(window_mm), "mm_per_px": s, "fps": float(fps),
            "travel_mm": float(travel_mm), "direction": int(direction), "lens_k1": float(lens_k1),
            "speed_mm_s": float(speed_mm_s), "posts": list(posts), "plate": bool(plate),
            "slip": float(slip), "seed": int(seed)}
    return DriveClip(t, frames, truth, inside, visible, kinds, list(roles), list(markers), xy,
                     cam, origin, opt, occ, info)


def _inside(truth, radii, w, h):
    """The whole marker lies in the picture (as `_visible` counts it, ignoring the others)."""
    x, y = truth[:, 0], truth[:, 1]
    with np.errstate(invalid="ignore"):
        return (x - radii > 1) & (x + radii < w - 2) & (y - radii > 1) & (y + radii < h - 2)
