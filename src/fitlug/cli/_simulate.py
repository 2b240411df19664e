"""`fit-lug simulate DIR`: a recording with known truth (and optionally its video)."""

from __future__ import annotations

import argparse
import math
import os

from ._common import progress_enabled, say, seed_arg


# fit.json's name of an effect parameter -> (model parameter, value -> model value), for the
# effects whose report renames a parameter one to one; lug_ripple and wheel_runout report
# the polar form (epsilon, phi_rad) of their (a, b) and are converted in _to_model
_FIT_NAMES = {
    "body_bounce": {"A_mm": ("bounce_A", float), "B_per_mm": ("bounce_B", float),
                    "phi_rad": ("bounce_phi", float)},
    "lug_sliding": {"inv_s_K": ("slide_mu", float), "s_K": ("slide_mu", lambda v: 1.0 / v)},
    "belt_sag": {"d_mm": ("sag_d", float)},
    "ground_sinkage": {"z_max_mm": ("sink_z", float), "u_s_mm": ("sink_us", float)},
    "lens_distortion": {"k1_per_mm2": ("lens_k1", float), "x_c_mm": ("lens_cx", float),
                        "y_c_mm": ("lens_cy", float)},
    "marker_depth": {"epsilon": ("depth_eps", float)},
    "camera_tilt": {"theta_rad": ("tilt_theta", float)},
    "frame_drop": {"dt_s": ("drop_dt", float), "t_star_s": ("drop_tstar", float)},
}
_POLAR = ("lug_ripple", "wheel_runout")


def fit_json_names(cls) -> list[str]:
    """The parameter names fit.json reports for effect class `cls` (from its report)."""
    return list(cls.report({k: abs(cls.scales.get(k, 1.0)) or 1.0 for k in cls.defaults}))


def _to_model(cls, vals: dict[str, float], text: str) -> dict[str, float]:
    """Parameters given under fit.json's names, as the model's parameters."""
    model = {k: v for k, v in vals.items() if k in cls.defaults}
    given = {k: v for k, v in vals.items() if k not in cls.defaults}
    if not given:
        return model
    if cls.id in _POLAR:
        unknown = set(given) - {"epsilon", "phi_rad"}
        if unknown or "epsilon" not in given:
            raise ValueError(f"--effect {text!r}: {cls.id} takes epsilon[, phi_rad] (as in "
                             f"fit.json) or {', '.join(cls.defaults)}")
        eps, phi = given["epsilon"], given.get("phi_rad", 0.0)
        model.update({f"{cls.prefix}_a": eps * math.cos(phi),
                      f"{cls.prefix}_b": eps * math.sin(phi)})
        return model
    for name, value in given.items():
        target, convert = _FIT_NAMES.get(cls.id, {})[name]
        try:
            model[target] = convert(value)
        except ZeroDivisionError:
            raise ValueError(f"--effect {text!r}: {name} must not be 0") from None
    return model


def _effects_help() -> str:
    """The catalog effects and their parameters (the names fit.json uses), for --help."""
    from ..model.effects import CATALOG

    lines = ["effects: --effect ID:P=V,... with P as fit.json names it, or as the model does",
             "(identity value = no effect, ~ a typical size; give one away from its identity):"]
    for eid, cls in CATALOG.items():
        model = ", ".join(f"{k}={v:g} (~{cls.scales.get(k, 0):g})"
                          for k, v in cls.defaults.items())
        lines.append(f"  {eid:<16} fit.json: {', '.join(fit_json_names(cls))}")
        lines.append(f"  {'':<16} model:    {model}")
    return "\n".join(lines)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.epilog = _effects_help()
    p.add_argument("out", metavar="DIR", nargs="?",
                   help="folder for trajectories.csv, rig.toml, truth.json")
    p.add_argument("--campaign", metavar="DIR",
                   help="write a simulated campaign (MODEL.md §4) into DIR instead: one "
                        "folder per recording at several drawbar pulls, masses and grounds, "
                        "and DIR/truth.json of the law")
    p.add_argument("--law", choices=("linear", "janosi_hanamoto"), default="linear",
                   help="with --campaign: the track's slip law (default linear)")
    p.add_argument("--runs", type=int, default=8, help="with --campaign: recordings (default 8)")
    p.add_argument("--k", type=float, default=0.25,
                   help="with --campaign: lug stiffness k, N/mm (default 0.25)")
    p.add_argument("--grounds", default="concrete,sand",
                   help="with --campaign: comma-separated ground names (default "
                        "concrete,sand; C_rr 0.06 / 0.15 / 0.10..., F_max 50 / 45 / 55 N)")
    p.add_argument("--seed", type=seed_arg, default=0, help="noise seed, 0 .. 2**32-1 (default 0)")
    p.add_argument("--effect", action="append", default=[], metavar="ID:P=V[,P=V...]",
                   help="add a catalog effect with its parameters, e.g. "
                        "wheel_runout:runout_a=0.002 (repeatable; the effects are listed below)")
    p.add_argument("--scenario", metavar="JSON",
                   help="Scenario fields as a JSON object or a path to a .json file")
    p.add_argument("--slip", type=float,
                   help="steady slip s0 of the linear law, 0 < s0 < 1 (default 0.07716)")
    p.add_argument("--duration", type=float,
                   help="seconds, > 0 (default 6.5); the rests, ramps and travel of the speed "
                        "profile scale with it, so the cruise speed stays the same")
    p.add_argument("--fps", type=float, help="frames per second, > 0 (default 100)")
    p.add_argument("--no-mass", action="store_true", help="do not write the mass to rig.toml")
    p.add_argument("--no-truth", action="store_true", help="do not write truth.json")
    p.add_argument("--video", metavar="VIDEO_DIR", help="also render the camera frames there")
    p.add_argument("--frames", type=int, help="with --video: render only the first N frames")
    p.add_argument("--image-size", metavar="WxH", default="1632x1200",
                   help="with --video: the picture's size in px (default 1632x1200)")
    p.add_argument("--window-mm", type=float, metavar="MM",
                   help="with --video: the ground width the picture spans, mm (mm per px = "
                        "MM / width; default 0.39 mm/px, 637 mm at 1632 px); with a window "
                        "shorter than the travel the robot drives through the picture")
    p.add_argument("--window-at", type=float, metavar="F",
                   help="with --video: where the picture's centre sits along the travel: 0 "
                        "at the markers' start position, 1 at their end position (default: "
                        "the picture centred on all the markers' positions)")
    p.add_argument("--lens-k1", type=float, metavar="K",
                   help="with --video: radial lens distortion rendered in (0: none; default "
                        "-0.02 with a focal length of 2000 px); calib.json carries it")
    p.add_argument("-q", "--quiet", action="store_true")


def parse_effect(text: str) -> tuple[str, dict]:
    """'ID:P=V,...' -> (id, {P: V}).

    Raises ValueError for an unknown id or parameter, a value that is not a finite number,
    or no parameter away from its identity value (the effect would simulate nothing).
    """
    from ..model.effects import get

    eid, _, rest = text.partition(":")
    cls = get(eid.strip())
    vals = {}
    names = list(cls.defaults) + [n for n in fit_json_names(cls) if n not in cls.defaults]
    for item in filter(None, (s.strip() for s in rest.split(","))):
        k, sep, v = item.partition("=")
        if not sep or k.strip() not in names:
            raise ValueError(f"--effect {text!r}: expected P=V with P one of {names}")
        try:
            value = float(v)
        except ValueError:
            value = float("nan")
        if not math.isfinite(value):
            raise ValueError(f"--effect {text!r}: {k.strip()} must be a finite number, "
                             f"got {v.strip()!r}")
        vals[k.strip()] = value
    vals = _to_model(cls, vals, text)
    if all(vals.get(k, d) == d for k, d in cls.defaults.items()):
        name, scale = next(iter(cls.scales.items()), (next(iter(cls.defaults)), 1.0))
        identity = ", ".join(f"{k}={d:g}" for k, d in cls.defaults.items())
        raise ValueError(f"--effect {text!r}: every parameter of {cls.id} is at its identity "
                         f"value ({identity}), so it would simulate nothing; give at least one, "
                         f"e.g. --effect {cls.id}:{name}={scale:g}")
    return cls.id, vals


def _check_options(args) -> None:
    from .._errors import InputError

    for option, value, lo, hi in (("--slip", args.slip, 0.0, 1.0),
                                  ("--duration", args.duration, 0.0, None),
                                  ("--fps", args.fps, 0.0, None)):
        if value is None:
            continue
        if not math.isfinite(value) or value <= lo or (hi is not None and value >= hi):
            bounds = f"> {lo:g}" if hi is None else f"between {lo:g} and {hi:g} (exclusive)"
            raise InputError(option, f"must be a number {bounds}, got {value!r}")
    if args.frames is not None and args.frames < 1:
        raise InputError("--frames", f"must be >= 1, got {args.frames}")
    for option, value, lo, hi in (("--window-mm", args.window_mm, 1.0, 1e5),
                                  ("--window-at", args.window_at, -1.0, 2.0),
                                  ("--lens-k1", args.lens_k1, -1.0, 1.0)):
        if value is not None and not (math.isfinite(value) and lo <= value <= hi):
            raise InputError(option, f"must be a number from {lo:g} to {hi:g}, got {value!r}")
    image_size(args.image_size)


def image_size(text: str) -> tuple[int, int]:
    """'WxH' -> (W, H) px; raises InputError unless both are integers >= 32."""
    from .._errors import InputError

    w, sep, h = str(text).lower().partition("x")
    try:
        size = (int(w), int(h))
    except ValueError:
        size = None
    if not sep or size is None or min(size) < 32:
        raise InputError("--image-size", f"must be WxH with whole numbers >= 32, got {text!r}")
    return size


# Scenario field -> the option that sets it
_OPTION_OF = {"slip": "--slip", "duration_s": "--duration", "fps": "--fps"}


def _run_campaign(args) -> int:
    from .._errors import InputError
    from ..sim._campaign import default_runs, limit_runs, simulate_campaign

    names = [g.strip() for g in args.grounds.split(",") if g.strip()]
    if not names or args.runs < 2:
        raise InputError(None, "--campaign needs at least one ground and --runs >= 2")
    crr = [0.06, 0.15, 0.10, 0.20]
    fmax = [50.0, 45.0, 55.0, 40.0]
    grounds = {g: {"C_rr": crr[i % 4], "F_max": fmax[i % 4]} for i, g in enumerate(names)}
    # the sliding law's campaign reaches the friction limit (issue 32): pulls to 0.9 F_max
    # at cruise, the ramps below 0.97 F_max
    runs = (limit_runs(args.runs, grounds=grounds, k=args.k) if args.law == "janosi_hanamoto" else
            default_runs(args.runs, grounds=tuple(names)))
    truth = simulate_campaign(args.campaign, runs=runs, k=args.k, grounds=grounds,
                              law=args.law, seed=args.seed)
    say(args, f"wrote {len(runs)} recordings into {args.campaign} ({args.law} law, "
              f"k = {truth['stiffness_N_per_mm']:g} N/mm) and {args.campaign}/truth.json")
    return 0


def run(args) -> int:
    from .._errors import InputError
    from ..sim import Scenario, scenario_from_json, write_simulation

    if args.campaign:
        return _run_campaign(args)
    if not args.out:
        raise InputError(None, "fit-lug simulate: give DIR (or --campaign DIR)")

    _check_options(args)
    sc = Scenario()
    if args.scenario:
        text = args.scenario
        try:
            if os.path.exists(text):
                with open(text, encoding="utf-8") as fh:
                    text = fh.read()
            sc = scenario_from_json(text)
        except (ValueError, TypeError) as exc:
            raise InputError(args.scenario, f"not a valid scenario: {exc}") from None
        except OSError as exc:
            raise InputError(args.scenario, f"cannot read: {exc.strerror or exc}") from None
    effects = dict(sc.effects)
    for e in args.effect:
        try:
            eid, vals = parse_effect(e)
        except ValueError as exc:
            message, prefix = str(exc), f"--effect {e!r}: "
            raise InputError(prefix[:-2], message.removeprefix(prefix)) from None
        effects[eid] = vals
    kw = {"effects": effects}
    if args.slip is not None:
        kw["slip"] = args.slip
    if args.duration is not None and math.isfinite(sc.duration_s) and sc.duration_s > 0:
        k = args.duration / sc.duration_s  # the same profile, stretched: same cruise speed
        kw.update(duration_s=args.duration, rest_s=sc.rest_s * k, ramp_s=sc.ramp_s * k,
                  travel_mm=sc.travel_mm * k)
    if args.fps is not None:
        kw["fps"] = args.fps
    if args.no_mass:
        kw["mass_kg"] = None
    sc = sc.replace(**kw)
    try:
        sc.check()
    except (ValueError, TypeError) as exc:
        field, _, problem = str(exc).partition(": ")
        if field in _OPTION_OF and field in kw:
            raise InputError(_OPTION_OF[field], problem) from None
        raise InputError(args.scenario, f"not a valid scenario: {exc}") from None
    rec, truth = write_simulation(args.out, sc, args.seed, truth=not args.no_truth)
    say(args, f"wrote {args.out}/trajectories.csv ({len(rec.t)} samples, {rec.n_markers} markers), "
              f"rig.toml" + ("" if args.no_truth else ", truth.json")
        + f"; true slip {truth['slip']:.5f}")
    if args.video:
        from ..sim import render_recording

        render_recording(args.video, sc, seed=args.seed, frames=args.frames,
                         progress=progress_enabled(args), image_size=image_size(args.image_size),
                         window_mm=args.window_mm, window_at=args.window_at,
                         lens_k1=args.lens_k1)
        say(args, f"rendered the video frames into {args.video}")
    return 0
