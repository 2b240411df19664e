"""`fit-lug simulate DIR`: a recording with known truth (and optionally its video)."""

from __future__ import annotations

import argparse
import os

from ._common import progress_enabled, say


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("out", metavar="DIR", help="folder for trajectories.csv, rig.toml, truth.json")
    p.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    p.add_argument("--effect", action="append", default=[], metavar="ID[:P=V,...]",
                   help="add a catalog effect, e.g. lug_ripple:ripple_a=0.003 (repeatable)")
    p.add_argument("--scenario", metavar="JSON",
                   help="Scenario fields as a JSON object or a path to a .json file")
    p.add_argument("--slip", type=float, help="steady slip s0 of the linear law")
    p.add_argument("--duration", type=float, help="seconds")
    p.add_argument("--fps", type=float, help="frames per second")
    p.add_argument("--no-mass", action="store_true", help="do not write the mass to rig.toml")
    p.add_argument("--no-truth", action="store_true", help="do not write truth.json")
    p.add_argument("--video", metavar="VIDEO_DIR", help="also render the camera frames there")
    p.add_argument("--frames", type=int, help="with --video: render only the first N frames")
    p.add_argument("-q", "--quiet", action="store_true")


def parse_effect(text: str) -> tuple[str, dict]:
    from ..model.effects import get

    eid, _, rest = text.partition(":")
    cls = get(eid.strip())
    vals = {}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        k, sep, v = item.partition("=")
        if not sep or k.strip() not in cls.defaults:
            raise ValueError(f"--effect {text!r}: expected P=V with P one of {list(cls.defaults)}")
        vals[k.strip()] = float(v)
    return cls.id, vals


def run(args) -> int:
    from .._errors import InputError
    from ..sim import Scenario, scenario_from_json, write_simulation

    sc = Scenario()
    if args.scenario:
        text = args.scenario
        if os.path.exists(text):
            with open(text, encoding="utf-8") as fh:
                text = fh.read()
        try:
            sc = scenario_from_json(text)
        except (ValueError, TypeError) as exc:
            raise InputError(args.scenario, f"not a valid scenario: {exc}") from None
    effects = dict(sc.effects)
    for e in args.effect:
        try:
            eid, vals = parse_effect(e)
        except ValueError as exc:
            raise InputError(None, str(exc)) from None
        effects[eid] = vals
    kw = {"effects": effects}
    if args.slip is not None:
        kw["slip"] = args.slip
    if args.duration is not None:
        kw["duration_s"] = args.duration
    if args.fps is not None:
        kw["fps"] = args.fps
    if args.no_mass:
        kw["mass_kg"] = None
    sc = sc.replace(**kw)
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
