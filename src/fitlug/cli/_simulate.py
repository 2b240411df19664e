"""`fit-lug simulate DIR`: a recording with known truth (and optionally its video)."""

from __future__ import annotations

import argparse
import os

from ._common import progress_enabled, say


def add_arguments(p: argparse.ArgumentParser) -> None:
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


def _run_campaign(args) -> int:
    from .._errors import InputError
    from ..sim._campaign import default_runs, simulate_campaign

    names = [g.strip() for g in args.grounds.split(",") if g.strip()]
    if not names or args.runs < 2:
        raise InputError(None, "--campaign needs at least one ground and --runs >= 2")
    crr = [0.06, 0.15, 0.10, 0.20]
    fmax = [50.0, 45.0, 55.0, 40.0]
    grounds = {g: {"C_rr": crr[i % 4], "F_max": fmax[i % 4]} for i, g in enumerate(names)}
    runs = default_runs(args.runs, grounds=tuple(names))
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
