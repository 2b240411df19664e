"""`fit-lug simulate DIR`: a recording with known truth (and optionally its video)."""

from __future__ import annotations

import argparse
import math
import os

from ._common import progress_enabled, say


def _effects_help() -> str:
    """The catalog effects and their parameters (the names fit.json uses), for --help."""
    from ..model.effects import CATALOG

    lines = ["effects (--effect ID:P=V,...): parameters as fit.json names them, each shown at",
             "its identity value (no effect) and, after ~, a typical magnitude; give at least",
             "one away from its identity value:"]
    for eid, cls in CATALOG.items():
        params = ", ".join(f"{k}={v:g} (~{cls.scales.get(k, 0):g})"
                           for k, v in cls.defaults.items())
        lines.append(f"  {eid:<16} {params}")
    return "\n".join(lines)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.epilog = _effects_help()
    p.add_argument("out", metavar="DIR", help="folder for trajectories.csv, rig.toml, truth.json")
    p.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
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
    for item in filter(None, (s.strip() for s in rest.split(","))):
        k, sep, v = item.partition("=")
        if not sep or k.strip() not in cls.defaults:
            raise ValueError(f"--effect {text!r}: expected P=V with P one of {list(cls.defaults)}")
        try:
            value = float(v)
        except ValueError:
            value = float("nan")
        if not math.isfinite(value):
            raise ValueError(f"--effect {text!r}: {k.strip()} must be a finite number, "
                             f"got {v.strip()!r}")
        vals[k.strip()] = value
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


# Scenario field -> the option that sets it
_OPTION_OF = {"slip": "--slip", "duration_s": "--duration", "fps": "--fps"}


def run(args) -> int:
    from .._errors import InputError
    from ..sim import Scenario, scenario_from_json, write_simulation

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
        from ..vision import render_recording

        render_recording(args.video, sc, seed=args.seed, frames=args.frames,
                         progress=progress_enabled(args))
        say(args, f"rendered the video frames into {args.video}")
    return 0
