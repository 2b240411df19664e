"""Recordings of physics outside the catalog (issue 28), with a real tracker's faults.

`make(mechanism, seed)` draws a rig, a motion and a mechanism of physically plausible size,
simulates the recording and puts it through `tests/realism.drive_through` (a window
narrower than the travel, misses, occlusions, glitches, ids split after gaps). It returns
`(recording, rig, truth)`; `truth` holds the mechanism's family and natural coordinate
(MODEL.md §5 names), its parameters, and the true slip, k and C_rr.

How the recordings are made (our own simulator, but not the fitting side's forms):

- the rig and the motion are drawn as `realism.drive_scenario` draws them (n 6-10,
  L 100-160 mm, R 18-35 mm, pitch 15-22 mm, 18-26 lugs, 6-10 markers on consecutive lugs,
  100-250 fps, 5-8 s, cruise 120-260 mm/s, ramps 0.8-1.6 s of a cos, smoothstep or
  quintic shape), with one, two (most often) or three body markers anywhere on the body,
  a towed load of 1-10 N in 30 % of the draws, noise 4-9 µm (lug) and 3-6 µm (body);
- the kinematics are integrated here (numpy RK4, 16 steps per frame, the belt travel's
  implicit rate by fixed-point iteration as MODEL.md §3's conventions read), so a
  mechanism that changes the motion (`cogging`, `slip_speed`) acts on X, a, F, s and psi
  together; the positions then come from `fitlug.model.positions` (the stadium path);
- a mechanism that moves markers only is added to the noise-free positions in numpy.

Mechanisms (family and coordinate as MODEL.md §5 names them):

- `squat` (body motion; coordinate: acceleration a): the suspension squats, body y -=
  (A + B c_x) a_s tanh(a / a_s); A 0.02-0.1 mm per m/s^2, pitch length A/B 100-400 mm
  of either sign, saturation a_s 0.3-1 m/s^2;
- `flap` (segment vibration; xi and a free frequency): the slack top run flaps in its
  first mode, top-run lug y += A sin(pi xi) sin(2 pi f t + phi); A 0.05-0.3 mm,
  f 10-30 Hz (and < 0.4 fps);
- `cogging` (speed modulation; belt travel psi): the motor cogs, periodic in the motor's
  angle (gear ratio x wheel angle psi / R): v -> v (1 + eps (sin th + h2 sin(2 th +
  phi2))), th = r psi / R + phi, r periods per wheel turn, not near a whole number nor
  near a multiple of the lugs per wheel turn; eps 0.2-2 %, h2 0-0.3, 5 Hz to 0.4 fps;
- `bump` (ground profile; ground x): a cosine bump of height 0.2-1 mm and width
  20-80 mm at a ground x in view where a marked lug lies; bottom-run lugs rise by it, each wheel rides over it
  (its centre lifted by the highest point of the bump under a circle of radius R + e)
  and the body follows the two wheels (heave and pitch);
- `slip_speed` (slip law; traction F and speed v): slip grows with speed (drag of the
  lug tips), s = s_lin (1 + c v), c v_cruise 0.1-0.4;
- `idler_wobble` (body motion; psi at the wheel's period): the rear (idler) wheel is
  eccentric, its axle height varies by w sin(psi / R + phi), w 0.02-0.15 mm, so the
  body heaves and pitches about the front wheel once per wheel turn;
- `carrier_roller` (path shape; xi on the top run): a support roller under the top run at
  xi_r 0.3-0.7 lifts it by h 0.1-0.6 mm; the belt runs straight from each wheel to the
  roller (a tent, not belt_sag's parabola);
- `lug_splay` (path shape; place along the arcs): the lugs splay outward as the belt bends
  round a wheel, the markers on each arc 0.05-0.4 mm farther out (each wheel its own,
  ramping in over the first 0-30 % of the arc);
- `keystone` (image map; image position q): the camera does not face the track squarely
  (yawed and pitched 0.1-1 degree at 0.6-1.5 m), a projective warp q -> c + (q - c) /
  (1 + p.(q - c)) about the window's centre c, on every marker;
- `frame_jitter` (time map; t): the frames are stamped on a clock that jitters (a
  host-timestamped camera), the true time of frame k is t_k + tau_k, tau_k Gaussian with
  sd 0.03-0.25 ms (a third of the draws: every other frame late by that much instead);
- `frame_vibration` (body motion; t): the frame vibrates at a fixed frequency (a motor or
  the rig's resonance), body y += (A + B c_x) sin(2 pi f t + phi); A 0.01-0.06 mm, pitch
  length A/B 100-400 mm of either sign, f 4-30 Hz (and < 0.3 fps), away from the
  lug-passing and wheel frequencies at cruise;
- `rail_bow` (body motion; the body's ground position X): the body rides a carriage on a
  guide rail that is not straight, rail height h sin(2 pi x / lambda + phi), h 0.05-0.3
  mm, lambda 0.6-1.5 m; the carriage's two rollers 100-300 mm apart about the body's X
  carry it (heave and pitch), the lugs untouched;
- `speed_hunt` (speed modulation; t): the motor's speed controller hunts at a fixed
  frequency, v -> v (1 + eps sin(2 pi f t + phi)), eps 0.3-3 %, f 2-20 Hz (and < 0.3 fps)
  away from the lug-passing and wheel frequencies at cruise; X, a, the slip and psi all
  follow the modulated speed;
- `ground_step` (ground profile; ground x): what a lab floor has rather than a smooth
  bump: a board (a plank h high, 30-150 mm wide) or the edge of a mat (the ground h higher
  from x_b on), h 0.2-1 mm, the edges rounded over 0.5 mm; lugs and wheels ride it as
  `bump`'s;
- `clock_wobble` (time map; t): the camera's frame clock wobbles, tau(t) = A sin(2 pi f t
  + phi), A 0.1-0.6 ms, f 3-25 Hz (and < 0.3 fps): to the data nearly a speed modulation
  in time, but the robot's motion (and its slip) is untouched.

Also `null` (the base model) and catalog recordings (`wheel_runout`, `belt_sag`,
`lug_ripple`, `body_bounce`) from `fitlug.sim.simulate` with the same rigs and faults.

Readings of the conventions: like the catalog's `body_bounce`, body motion moves the body
markers only (the top run and the arcs are not lifted with the frame); the true slip
reported is the steady slip at the cruise speed (for `slip_speed`: s0 (1 + c v_cruise));
`squat`'s acceleration is the motor profile's a(t).

`write(out_dir, mechanism, seed)` writes the recording as a user hands it over
(trajectories.csv in the wide export form, rig.toml with the roles) with truth.json beside
it; from a shell: `python tests/mechanisms.py flap 3 /tmp/flap3 [size]`.

`size` sets the mechanism's headline amplitude (in the units above: A mm per m/s²
for squat, A mm for flap, eps for cogging, height mm for bump, c v_cruise for slip_speed,
w mm for idler_wobble; the catalog's eps, d or A) instead of drawing it.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from fitlug.sim import Scenario, rig_of, simulate, speed_profile, truth_params

import realism

#: mechanism -> (family, natural coordinate) in MODEL.md §5's words
FAMILIES = {
    "squat": ("body motion", "a"),
    "flap": ("segment vibration", "xi,t"),
    "cogging": ("speed modulation", "psi"),
    "bump": ("ground profile", "x"),
    "slip_speed": ("slip law", "F,v"),
    "idler_wobble": ("body motion", "psi"),
    "carrier_roller": ("path shape", "xi"),
    "lug_splay": ("path shape", "xi"),
    "keystone": ("image map", "q"),
    "frame_jitter": ("time map", "t"),
    "clock_wobble": ("time map", "t"),
    "frame_vibration": ("body motion", "t"),
    "rail_bow": ("body motion", "X"),
    "speed_hunt": ("speed modulation", "t"),
    "ground_step": ("ground profile", "x"),
}
#: catalog recordings this generator also makes (no family term may be kept on them)
CATALOG_CASES = ("wheel_runout", "belt_sag", "lug_ripple", "body_bounce")
MECHANISMS = tuple(FAMILIES)
#: mechanisms added after the others: last in ALL, so that every earlier kind keeps its
#: random stream (make's rng is seeded by the kind's place in ALL)
LATER = ("rail_bow", "speed_hunt", "ground_step")
ALL = tuple(m for m in MECHANISMS if m not in LATER) + ("null",) + CATALOG_CASES + LATER
STEPS_PER_FRAME = 16


def scenario(seed: int) -> Scenario:
    """A drawn rig and motion (see the module docstring), as a Scenario without effects."""
    d = realism.drive_scenario(seed)
    rng = np.random.default_rng([seed, 28])
    rest = 0.5 * (d["t_acc"][0] + d["duration"] - d["t_dec"][1])
    ramp = d["t_acc"][1] - d["t_acc"][0]
    cruise = d["duration"] - 2 * rest - 2 * ramp
    body = [tuple(c) for c in d["body"]]
    n_body = int(rng.choice([1, 2, 2, 2, 3]))  # one marker (no pitch), two, or three
    if n_body == 1:
        body = body[:1]
    elif n_body == 3:
        half = (d["N"] * d["pitch"] - 2 * np.pi * d["R"]) / 4 + d["R"]
        body.append((float(rng.uniform(-half, half)), float(rng.uniform(1.5, 3.2) * d["R"])))
    F0 = d["m"] * d["C_rr"] * 9.81
    pull = float(rng.uniform(1, 10)) if rng.random() < 0.3 else 0.0  # a towed load
    if 2 * (F0 + pull) / (d["k"] * d["n"] * d["L"]) > 0.25:
        pull = 0.0
    slip = 2 * (F0 + pull) / (d["k"] * d["n"] * d["L"])
    return Scenario(
        duration_s=d["duration"], fps=d["fps"], travel_mm=d["v_max"] * (cruise + ramp),
        rest_s=rest, ramp_s=ramp, ramp=str(rng.choice(["cos", "smoothstep", "quintic"])),
        n_contact=d["n"], L_mm=d["L"], lug_pitch_mm=d["pitch"], n_belt=d["N"],
        mass_kg=d["m"], drawbar_pull_N=pull, slip=slip, rolling_resistance=d["C_rr"],
        R_mm=d["R"], e_mm=d["e"], x_off_mm=d["x_off"], y_off_mm=d["y_off"],
        lug_markers=d["n_lug"], lug_spacing=1,
        sigma_start_mm=float(rng.uniform(0, d["N"] * d["pitch"])),
        body_markers=tuple(body),
        noise_lug_mm=float(rng.uniform(0.004, 0.009)),
        noise_body_mm=float(rng.uniform(0.003, 0.006)))


# ---------------------------------------------------------------- kinematics (numpy)

def _kinematics(sc: Scenario, speed_mod=None, slip_of=None, time_mod=None):
    """(t_frames, X, psi, a) at the frame times: RK4 on STEPS_PER_FRAME steps per frame.

    speed_mod(psi) -> (m, dm/dpsi) and time_mod(t) -> (m, dm/dt): v = v0 (1 + m), the two
    m added; slip_of(s_lin, v) -> s replaces the linear law s_lin = s0 + beta a. a is the
    body's acceleration (mm/s^2)."""
    h = 1.0 / (sc.fps * STEPS_PER_FRAME)
    nf = int(round(sc.duration_s * sc.fps))
    prof = dict(v_cruise=sc.v_cruise, duration=sc.duration_s, rest=sc.rest_s,
                ramp=sc.ramp_s, shape=sc.ramp)

    def rates(v0, a0, psi, t=0.0):
        m, dm = speed_mod(psi) if speed_mod is not None else (0.0, 0.0)
        mt, dmt = time_mod(t) if time_mod is not None else (0.0, 0.0)
        m = m + mt
        v = v0 * (1 + m)
        law = (lambda a: sc.slip + sc.beta * a) if slip_of is None else \
            (lambda a: slip_of(sc.slip + sc.beta * a, v))
        dpsi = v / (1 - law(a0 * (1 + m) + v0 * dmt))
        for _ in range(6):  # a depends on dpsi/dt through m(psi)
            a = a0 * (1 + m) + v0 * (dm * dpsi + dmt)
            dpsi = v / (1 - law(a))
        return v, dpsi, a0 * (1 + m) + v0 * (dm * dpsi + dmt)

    n = (nf - 1) * STEPS_PER_FRAME
    tg = np.arange(n + 1) * h
    if speed_mod is None and time_mod is None:  # Simpson on nodes and midpoints
        vn, dn, A = rates(*speed_profile(tg, **prof), None)
        vm, dm_, _ = rates(*speed_profile(tg[:-1] + h / 2, **prof), None)
        X = np.r_[0.0, np.cumsum(h / 6 * (vn[:-1] + 4 * vm + vn[1:]))]
        P = np.r_[0.0, np.cumsum(h / 6 * (dn[:-1] + 4 * dm_ + dn[1:]))]
    else:
        X = np.zeros(n + 1)
        P = np.zeros(n + 1)
        A = np.zeros(n + 1)
        v0n, a0n = (a.tolist() for a in speed_profile(tg, **prof))
        v0m, a0m = (a.tolist() for a in speed_profile(tg[:-1] + h / 2, **prof))
        x = p = 0.0
        for k in range(n):
            t0 = k * h
            v1, d1, A[k] = rates(v0n[k], a0n[k], p, t0)
            v2, d2, _ = rates(v0m[k], a0m[k], p + h / 2 * d1, t0 + h / 2)
            v3, d3, _ = rates(v0m[k], a0m[k], p + h / 2 * d2, t0 + h / 2)
            v4, d4, _ = rates(v0n[k + 1], a0n[k + 1], p + h * d3, t0 + h)
            x += h / 6 * (v1 + 2 * v2 + 2 * v3 + v4)
            p += h / 6 * (d1 + 2 * d2 + 2 * d3 + d4)
            X[k + 1], P[k + 1] = x, p
        A[n] = rates(v0n[n], a0n[n], p, n * h)[2]
    idx = np.arange(nf) * STEPS_PER_FRAME
    return np.arange(nf) / sc.fps, X[idx], P[idx], A[idx]


def _clean(sc: Scenario, speed_mod=None, slip_of=None, tau=None, time_mod=None):
    """Noise-free positions of every marker at every frame, plus what the marker-only
    mechanisms need: dict with the layout's sample arrays. `tau` (per frame, s): the frame's
    true time is its stamp + tau (X and psi moved to it to second order)."""
    from fitlug.model import make_layout
    from fitlug.model._model import ctx_of, positions
    from fitlug.model._path import stadium

    t, X, psi, a = _kinematics(sc, speed_mod, slip_of, time_mod)
    if tau is not None:  # X and psi at the true times (Taylor to tau^2: tau < 1 ms)
        v, vt = np.gradient(X, t), np.gradient(psi, t)
        X = X + v * tau + 0.5 * np.gradient(v, t) * tau ** 2
        psi = psi + vt * tau + 0.5 * np.gradient(vt, t) * tau ** 2
    nl, nb = sc.lug_markers, len(sc.body_markers)
    f_l, i_l = np.repeat(np.arange(len(t)), nl), np.tile(np.arange(nl), len(t))
    f_b, j_b = np.repeat(np.arange(len(t)), nb), np.tile(np.arange(nb), len(t))
    breaks = np.arange(-0.05, sc.duration_s + 0.1 + 1e-9, 0.01)
    lay = make_layout(breaks=breaks, t_lo=-0.05, t_hi=sc.duration_s + 0.1, fps=sc.fps,
                      lug_t=t[f_l], lug_i=i_l, body_t=t[f_b], body_j=j_b, n_lug=nl,
                      n_body=nb, n_belt=sc.n_belt, n_contact=sc.n_contact, L=sc.L_mm)
    p = truth_params(sc, lay, breaks)
    lx, ly, bx, by = (np.array(v) for v in positions(p, lay, X[f_l], psi[f_l], X[f_b],
                                                        psi[f_b]))
    ctx = ctx_of(p, lay)
    sig = np.asarray(p["sigma0"])[i_l] + psi[f_l]
    _, _, seg = stadium(sig, ctx)
    u = np.mod(sig, float(ctx.P))
    return dict(t=t, X=X, psi=psi, a=a, f_l=f_l, i_l=i_l, f_b=f_b, j_b=j_b, lx=lx, ly=ly,
                bx=bx, by=by, seg=np.asarray(seg), u=u, D=float(ctx.D), R=float(ctx.R),
                cx=np.asarray(p["cx"]))


def _recording(sc: Scenario, c: dict, seed: int):
    """A Recording (long form, like fitlug.sim.simulate) from the clean positions + noise."""
    from fitlug.io import Recording

    rng = np.random.default_rng([seed, 2801])
    nl, nb = sc.lug_markers, len(sc.body_markers)
    lx = c["lx"] + rng.normal(0, sc.noise_lug_mm, c["lx"].shape)
    ly = c["ly"] + rng.normal(0, sc.noise_lug_mm, c["ly"].shape)
    bx = c["bx"] + rng.normal(0, sc.noise_body_mm, c["bx"].shape)
    by = c["by"] + rng.normal(0, sc.noise_body_mm, c["by"].shape)
    t = c["t"]
    ol = np.lexsort((c["f_l"], c["i_l"]))
    ob = np.lexsort((c["f_b"], c["j_b"]))
    mi = np.r_[c["i_l"][ol], nl + c["j_b"][ob]].astype(np.int64)
    return Recording(
        markers=tuple([f"B{i + 1:02d}" for i in range(nl)] + [f"C{j + 1}" for j in range(nb)]),
        roles=tuple(["lug"] * nl + ["body"] * nb), t=np.r_[t[c["f_l"]][ol], t[c["f_b"]][ob]],
        marker_index=mi, x=np.r_[lx[ol], bx[ob]], y=np.r_[ly[ol], by[ob]],
        frame=np.r_[c["f_l"][ol], c["f_b"][ob]].astype(np.int64),
        meta={"fps": f"{sc.fps:g}", "source": "tests/mechanisms.py", "units": "mm"})


# ---------------------------------------------------------------- the mechanisms

def _uniform(rng, lo, hi, size):
    return float(rng.uniform(lo, hi)) if size is None else float(size)


def _squat(sc, c, rng, size):
    A = _uniform(rng, 0.02, 0.1, size)  # mm per m/s^2
    lp = float(rng.uniform(100, 400)) * float(rng.choice([-1.0, 1.0]))
    a_s = float(rng.uniform(0.3, 1.0))  # m/s^2
    a_b = c["a"][c["f_b"]] / 1000.0
    cx = c["cx"][c["j_b"]]
    c["by"] = c["by"] - A * (1 + cx / lp) * a_s * np.tanh(a_b / a_s)
    return {"A_mm_per_m_s2": A, "B_per_mm": A / lp, "pitch_length_mm": lp,
            "a_sat_m_s2": a_s, "form": "(A + B c_x) a_s tanh(a / a_s), downward"}


def _flap(sc, c, rng, size):
    A = _uniform(rng, 0.05, 0.3, size)
    f = float(rng.uniform(10.0, min(30.0, 0.4 * sc.fps)))
    phi = float(rng.uniform(0, 2 * np.pi))
    top = c["seg"] == 2
    D, R = c["D"], c["R"]
    xi = np.clip((c["u"] - D - np.pi * R) / D, 0, 1)
    tl = c["t"][c["f_l"]]
    c["ly"] = c["ly"] + np.where(top, A * np.sin(np.pi * xi) * np.sin(2 * np.pi * f * tl + phi),
                                 0.0)
    return {"A_mm": A, "f_Hz": f, "phi_rad": phi, "mode": "sin(pi xi)"}


def _cogging_draw(sc, rng, size):
    eps = _uniform(rng, 0.002, 0.02, size)
    lugs_per_turn = 2 * np.pi * sc.R_mm / sc.pitch
    f_wheel = sc.v_cruise / (1 - sc.slip) / (2 * np.pi * sc.R_mm)
    lo, hi = 5.0 / f_wheel, min(60.0, 0.4 * sc.fps) / f_wheel  # cogging 5 Hz .. 0.4 fps
    for _ in range(1000):
        r = float(rng.uniform(lo, hi))
        off_int = abs(r - round(r)) > 0.15
        q = r / lugs_per_turn
        if off_int and abs(q - round(q)) > 0.1 and abs(2 * q - round(2 * q)) > 0.1:
            break
    return {"epsilon": eps, "periods_per_wheel_turn": r,
            "period_mm": 2 * np.pi * sc.R_mm / r, "phi_rad": float(rng.uniform(0, 2 * np.pi)),
            "h2": float(rng.uniform(0, 0.3)), "phi2_rad": float(rng.uniform(0, 2 * np.pi)),
            "f_cruise_Hz": r * f_wheel}


def _cogging_mod(q, R):
    k = q["periods_per_wheel_turn"] / R

    def mod(psi):
        th = k * psi + q["phi_rad"]
        m = q["epsilon"] * (np.sin(th) + q["h2"] * np.sin(2 * th + q["phi2_rad"]))
        dm = q["epsilon"] * k * (np.cos(th) + 2 * q["h2"] * np.cos(2 * th + q["phi2_rad"]))
        return m, dm
    return mod


def _bump_height(x, q):
    shape = q.get("shape", "cosine")
    h, xb, w = q["height_mm"], q["x_mm"], q["width_mm"]
    if shape == "plank":  # a board on the floor, its edges rounded over EDGE_MM
        e = EDGE_MM
        return h * 0.5 * (np.tanh((x - (xb - w / 2)) / e) - np.tanh((x - (xb + w / 2)) / e))
    if shape == "step":  # the edge of a mat: the ground higher from x_b on
        return h * 0.5 * (1 + np.tanh((x - xb) / EDGE_MM))
    z = (x - xb) / (w / 2)
    return np.where(np.abs(z) < 1, h * 0.5 * (1 + np.cos(np.pi * z)), 0.0)


EDGE_MM = 0.5  # the rounding of a plank's or a mat's edge


def _wheel_lift(xw, R, q):
    """Centre lift of a wheel of radius R (plus belt) rolling over the bump at centre xw."""
    s = np.linspace(-R, R, 241)
    prof = _bump_height(xw[:, None] + s[None, :], q) + np.sqrt(R * R - s * s)[None, :] - R
    return np.maximum(prof.max(axis=1), 0.0)


def _bump(sc, c, rng, size, window=None, shapes=None):
    h = _uniform(rng, 0.2, 1.0, size)
    w = float(rng.uniform(20, 80))
    lo, hi = window if window is not None else (0.0, sc.travel_mm)
    # where a marked lug lies on the ground (else the lugs never show the bump)
    on = c["lx"][(c["seg"] == 0) & (c["lx"] > lo) & (c["lx"] < hi)]
    xb = float(rng.choice(on)) + float(rng.uniform(-w / 4, w / 4)) if len(on) else \
        float(rng.uniform(lo, hi))
    q = {"height_mm": h, "width_mm": w, "x_mm": xb,
         "form": "cosine bump h (1 + cos(pi (x - x_b) / (w/2))) / 2"}
    if shapes:  # ground_step: a board or a mat's edge (drawn after the bump's numbers)
        q["shape"] = str(rng.choice(shapes))
        q["width_mm"] = float(rng.uniform(30, 150))
        q["form"] = {"plank": f"a board h high, w wide, edges rounded over {EDGE_MM} mm",
                     "step": f"a mat's edge: h higher from x_b on ({EDGE_MM} mm rounding)"
                     }[q["shape"]]
    bottom = c["seg"] == 0
    c["ly"] = c["ly"] + np.where(bottom, _bump_height(c["lx"], q), 0.0)
    Xb = c["X"][c["f_b"]]
    xr = Xb + sc.x_off_mm - c["D"] / 2
    xf = Xb + sc.x_off_mm + c["D"] / 2
    Rw = sc.R_mm + sc.e_mm
    lr, lf = _wheel_lift(xr, Rw, q), _wheel_lift(xf, Rw, q)
    cx = c["cx"][c["j_b"]]
    c["by"] = c["by"] + lr + (lf - lr) * (Xb + cx - xr) / c["D"]
    return q


def _idler_wobble(sc, c, rng, size):
    w = _uniform(rng, 0.02, 0.15, size)
    phi = float(rng.uniform(0, 2 * np.pi))
    g = w * np.sin(c["psi"][c["f_b"]] / sc.R_mm + phi)
    cx = c["cx"][c["j_b"]]
    frac = (sc.x_off_mm + c["D"] / 2 - cx) / c["D"]  # 1 at the rear axle, 0 at the front
    c["by"] = c["by"] + g * frac
    return {"w_mm": w, "phi_rad": phi, "pivot": "front wheel"}


def _hunt_draw(sc, rng, size):
    eps = _uniform(rng, 0.003, 0.03, size)
    lug_f = sc.v_cruise / (1 - sc.slip) / sc.pitch
    wheel_f = lug_f * sc.pitch / (2 * np.pi * sc.R_mm)
    for _ in range(1000):  # away from what turns with the belt (that would be psi's)
        f = float(rng.uniform(2.0, min(20.0, 0.3 * sc.fps)))
        if all(abs(f / g - round(f / g)) > 0.1 or round(f / g) == 0 for g in (lug_f, wheel_f)):
            break
    phi = float(rng.uniform(0, 2 * np.pi))
    w = 2 * np.pi * f

    def mod(t):
        return eps * np.sin(w * t + phi), eps * w * np.cos(w * t + phi)
    return {"epsilon": eps, "f_Hz": f, "phi_rad": phi,
            "form": "v -> v (1 + eps sin(2 pi f t + phi))"}, mod


def _rail_bow(sc, c, rng, size):
    h = _uniform(rng, 0.05, 0.3, size)
    lam = float(rng.uniform(600.0, 1500.0))
    phi = float(rng.uniform(0, 2 * np.pi))
    Lc = float(rng.uniform(100.0, 300.0))
    Xb = c["X"][c["f_b"]]
    cx = c["cx"][c["j_b"]]

    def g(x):
        return h * np.sin(2 * np.pi * x / lam + phi)

    xr, xf = Xb - Lc / 2, Xb + Lc / 2  # the carriage's two rollers, about the body's X
    c["by"] = c["by"] + g(xr) + (g(xf) - g(xr)) * (cx - sc.x_off_mm + Lc / 2) / Lc
    return {"h_mm": h, "wavelength_mm": lam, "phi_rad": phi, "carriage_mm": Lc,
            "form": "rail h sin(2 pi x / lambda + phi) under a carriage of two rollers"}


def _frame_vibration(sc, c, rng, size):
    A = _uniform(rng, 0.01, 0.06, size)
    lp = float(rng.uniform(100, 400)) * float(rng.choice([-1.0, 1.0]))
    lug_f = sc.v_cruise / (1 - sc.slip) / sc.pitch
    wheel_f = lug_f * sc.pitch / (2 * np.pi * sc.R_mm)
    for _ in range(1000):
        f = float(rng.uniform(4.0, min(30.0, 0.3 * sc.fps)))
        if all(abs(f / g - round(f / g)) > 0.1 or round(f / g) == 0 for g in (lug_f, wheel_f)):
            break
    phi = float(rng.uniform(0, 2 * np.pi))
    tb = c["t"][c["f_b"]]
    cx = c["cx"][c["j_b"]]
    c["by"] = c["by"] + A * (1 + cx / lp) * np.sin(2 * np.pi * f * tb + phi)
    return {"A_mm": A, "B_per_mm": A / lp, "f_Hz": f, "phi_rad": phi,
            "form": "(A + B c_x) sin(2 pi f t + phi)"}


def _carrier_roller(sc, c, rng, size):
    h = _uniform(rng, 0.1, 0.6, size)
    xr = float(rng.uniform(0.3, 0.7))
    top = c["seg"] == 2
    xi = np.clip((c["u"] - c["D"] - np.pi * c["R"]) / c["D"], 0, 1)
    lift = np.where(xi < xr, h * xi / xr, h * (1 - xi) / (1 - xr))
    c["ly"] = c["ly"] + np.where(top, lift, 0.0)
    return {"h_mm": h, "xi_roller": xr, "form": "tent: straight from each wheel to the roller"}


def _lug_splay(sc, c, rng, size):
    d = [_uniform(rng, 0.05, 0.4, size), float(rng.uniform(0.05, 0.4))]
    if rng.random() < 0.5:
        d = d[::-1]
    ramp = [float(rng.uniform(0.0, 0.3)) for _ in range(2)]
    D, R = c["D"], c["R"]
    out = {"delta_rear_mm": d[0], "delta_front_mm": d[1], "ramp_rear": ramp[0],
           "ramp_front": ramp[1], "form": "radial, ramping in over the arc's first part"}
    for k, (seg, start, sgn) in enumerate(((1, D, -1.0), (3, 2 * D + np.pi * R, 1.0))):
        on = c["seg"] == seg
        phi = np.clip((c["u"] - start) / R, 0, np.pi)
        frac = phi / np.pi
        g = d[k] * np.clip(frac / max(ramp[k], 1e-9), 0, 1)
        c["lx"] = c["lx"] + np.where(on, sgn * g * np.sin(phi), 0.0)
        c["ly"] = c["ly"] + np.where(on, sgn * g * np.cos(phi), 0.0)
    return out


def _keystone(sc, c, rng, size, centre):
    ang = _uniform(rng, 0.1, 1.0, size)  # degrees, the larger of the two
    Z = float(rng.uniform(600, 1500))
    a = np.radians([ang, float(rng.uniform(-1, 1)) * ang])
    if rng.random() < 0.5:
        a = a[::-1]
    p = np.tan(a) * rng.choice([-1.0, 1.0], 2) / Z
    for xk, yk in (("lx", "ly"), ("bx", "by")):
        dx, dy = c[xk] - centre[0], c[yk] - centre[1]
        den = 1 + p[0] * dx + p[1] * dy
        c[xk], c[yk] = centre[0] + dx / den, centre[1] + dy / den
    return {"p_per_mm": p.tolist(), "angles_deg": np.degrees(a).tolist(), "Z_mm": Z,
            "centre_mm": [float(v) for v in centre],
            "form": "q -> c + (q - c) / (1 + p.(q - c))"}


def _wobble_draw(sc, rng, size):
    A = _uniform(rng, 0.1e-3, 0.6e-3, size * 1e-3 if size else None)
    f = float(rng.uniform(3.0, min(25.0, 0.3 * sc.fps)))
    phi = float(rng.uniform(0, 2 * np.pi))
    t = np.arange(int(round(sc.duration_s * sc.fps))) / sc.fps
    return ({"A_ms": A * 1e3, "f_Hz": f, "phi_rad": phi, "form": "A sin(2 pi f t + phi)"},
            A * np.sin(2 * np.pi * f * t + phi))


def _jitter_draw(sc, rng, size):
    sd = _uniform(rng, 0.03e-3, 0.25e-3, size * 1e-3 if size else None)
    nf = int(round(sc.duration_s * sc.fps))
    if rng.random() < 1 / 3:
        tau = sd * (np.arange(nf) % 2)
        form = "every other frame late"
    else:
        tau = rng.normal(0, sd, nf)
        form = "Gaussian per frame"
    return {"sd_ms": sd * 1e3, "form": form}, tau


_CATALOG_DRAW = {
    "wheel_runout": lambda rng, s: _ab("runout", _uniform(rng, 0.003, 0.01, s), rng),
    "lug_ripple": lambda rng, s: _ab("ripple", _uniform(rng, 0.002, 0.01, s), rng),
    "belt_sag": lambda rng, s: {"sag_d": _uniform(rng, 0.1, 0.5, s)},
    "body_bounce": lambda rng, s: {"bounce_A": _uniform(rng, 0.01, 0.05, s),
                                   "bounce_B": float(rng.uniform(-1e-4, 1e-4)),
                                   "bounce_phi": float(rng.uniform(-np.pi, np.pi))},
}


def _ab(prefix, eps, rng):
    phi = float(rng.uniform(0, 2 * np.pi))
    return {f"{prefix}_a": eps * math.cos(phi), f"{prefix}_b": eps * math.sin(phi)}


def make(mechanism: str, seed: int, *, size: float | None = None, faults: bool = True):
    """(recording, rig, truth) of one drawn recording with `mechanism` (see ALL).

    faults=True: seen through `realism.drive_through` (window, misses, occlusions,
    glitches, split ids; the window always sees a speed change, and for `bump` the bump);
    faults=False: the whole clean recording (every marker, every frame, noise only).
    truth: mechanism, family, coordinate (None for null and catalog recordings),
    catalog (the effect id or None), params, slip (true steady slip), slip_linear_s0,
    stiffness_N_per_mm, rolling_resistance, mass_kg, fps, window (ground x) and seed.
    """
    if mechanism not in ALL:
        raise ValueError(f"unknown mechanism {mechanism!r}; known: {', '.join(ALL)}")
    sc = scenario(seed)
    rng = np.random.default_rng([seed, 28, ALL.index(mechanism)])
    speed_mod = slip_of = tau = time_mod = None
    slip_true = sc.slip
    params: dict = {}
    if mechanism in CATALOG_CASES or mechanism == "null":
        if mechanism != "null":
            params = _CATALOG_DRAW[mechanism](rng, size)
            sc = sc.replace(effects={mechanism: params})
        rec, tr = simulate(sc, seed)
        slip_true = tr["slip"]
    else:
        if mechanism == "cogging":
            params = _cogging_draw(sc, rng, size)
            speed_mod = _cogging_mod(params, sc.R_mm)
        elif mechanism == "slip_speed":
            cv = _uniform(rng, 0.1, 0.4, size)
            cc = cv / sc.v_cruise  # per mm/s
            params = {"c_per_m_s": cc * 1000.0, "c_v_cruise": cv,
                      "form": "s = s_lin (1 + c v)"}
            slip_of = lambda s_lin, v: s_lin * (1 + cc * v)  # noqa: E731
            slip_true = sc.slip * (1 + cv)
        elif mechanism == "frame_jitter":
            params, tau = _jitter_draw(sc, rng, size)
        elif mechanism == "clock_wobble":
            params, tau = _wobble_draw(sc, rng, size)
        elif mechanism == "speed_hunt":
            params, time_mod = _hunt_draw(sc, rng, size)
        c = _clean(sc, speed_mod, slip_of, tau, time_mod)
        if mechanism == "squat":
            params = _squat(sc, c, rng, size)
        elif mechanism == "flap":
            params = _flap(sc, c, rng, size)
        elif mechanism in ("bump", "ground_step"):
            params = {"_pending": True}
        elif mechanism == "idler_wobble":
            params = _idler_wobble(sc, c, rng, size)
        elif mechanism == "frame_vibration":
            params = _frame_vibration(sc, c, rng, size)
        elif mechanism == "rail_bow":
            params = _rail_bow(sc, c, rng, size)
        elif mechanism == "carrier_roller":
            params = _carrier_roller(sc, c, rng, size)
        elif mechanism == "lug_splay":
            params = _lug_splay(sc, c, rng, size)
        if mechanism not in ("bump", "ground_step", "keystone"):
            rec = _recording(sc, c, seed)
    window = None
    info = {}
    if mechanism in ("keystone", "bump", "ground_step"):
        # the window first (from a draw without the mechanism), then the mechanism in it:
        # the keystone about the window's centre, the bump inside it
        base = _recording(sc, c, seed)
        if faults:
            _, info = realism.drive_through(base, seed=seed, need_motion=True, faults=False)
            window = info["window"]
        lo, hi = window if window is not None else (0.0, sc.travel_mm)
        if mechanism == "keystone":
            params = _keystone(sc, c, rng, size, (0.5 * (lo + hi), sc.y_off_mm + sc.R_mm))
        else:
            params = _bump(sc, c, rng, size, window=(lo + 40.0, hi - 40.0) if hi - lo > 100
                           else (lo, hi),
                           shapes=("plank", "step") if mechanism == "ground_step" else None)
        rec = _recording(sc, c, seed)
    if faults:
        rec, info = realism.drive_through(rec, seed=seed, need_motion=True, window=window)
        window = info["window"]
    truth = {
        "mechanism": mechanism,
        "family": FAMILIES.get(mechanism, (None, None))[0],
        "coordinate": FAMILIES.get(mechanism, (None, None))[1],
        "catalog": mechanism if mechanism in CATALOG_CASES else None,
        "params": {k: (float(v) if isinstance(v, (int, float, np.floating)) else v)
                   for k, v in params.items()},
        "slip": float(slip_true), "slip_linear_s0": sc.slip,
        "stiffness_N_per_mm": sc.stiffness, "rolling_resistance": sc.rolling_resistance,
        "mass_kg": sc.mass_kg, "drawbar_pull_N": sc.drawbar_pull_N, "fps": sc.fps,
        "v_cruise_mm_s": sc.v_cruise,
        "window": None if window is None else [float(v) for v in window],
        "n_glitches": len(info.get("glitches", [])), "seed": seed,
        # (marker, time_s) of each injected glitch
        "glitches": [(g[0], round(float(g[1]), 6)) for g in info.get("glitches", [])],
        "scenario": {k: v for k, v in dataclasses.asdict(sc).items() if k != "effects"},
    }
    return rec, rig_of(sc), truth


def write(out_dir, mechanism: str, seed: int, *, size: float | None = None,
          faults: bool = True, wide: bool = True) -> dict:
    """Write `make`'s recording as a user would hand it over: trajectories.csv (the wide
    export form with faults, else long form), rig.toml (with the markers' roles) and
    truth.json beside them (for the one who checks, not for fit-lug). Returns truth."""
    import os

    from fitlug.io import write_json

    rec, rig, truth = make(mechanism, seed, size=size, faults=faults)
    realism.write_realistic(out_dir, rec, rig, wide=wide)
    write_json(os.path.join(out_dir, "truth.json"), truth)
    return truth


if __name__ == "__main__":  # python tests/mechanisms.py flap 3 /tmp/flap3 [size]
    import sys

    kind, seed, out = sys.argv[1], int(sys.argv[2]), sys.argv[3]
    tr = write(out, kind, seed, size=float(sys.argv[4]) if len(sys.argv) > 4 else None)
    print(f"{out}: {kind} seed {seed}, family {tr['family']!r}, params {tr['params']}")
