"""The engine's recordings as a real camera and tracker would deliver them (issue 41 item 3).

Takes recordings of data/engine/<case>/ (fitlug.sim.engine, MuJoCo) and writes views of
them through tests/realism.py, which owes nothing to the engine or to fitlug's model:

- `real`: the whole run in a 637 mm picture, with a tracker's misses (1 %), occlusions
  (0.1 per second per marker, 5-30 frames), glitches (0.1-0.2 % of samples moved by
  0.5-1 mm) and ids split after every gap (`trk17`, numbers at random: names say nothing);
- `dt400`: the same faults, the robot driving through a 400 mm window (100-500 mm of
  ground x: it enters and leaves the picture; markers lost near the picture's edge);
- `trkdt`: a sub-pixel centroid tracker's correlated error (pixel locking, drift) on top
  of the engine's white noise, then `dt400`'s window and faults;
- `occldt`: `dt400` with six times the occlusions (ids split into three times as many
  fragments).

Each folder gets trajectories.csv in the wide export form (time_s, <id>_x_mm, <id>_y_mm),
rig.toml with the fragments' roles, and the case's truth.json (the engine's slip).
Then `python benchmarks/bench_engine.py --data OUT` fits and explains them.

    python benchmarks/make_engine_variants.py --out /tmp/engine_views \\
        [--cases ref_100fps stiff_k06 ...] [--views real dt400 trkdt occldt]
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "tests"))

WINDOW = (100.0, 500.0)
SEED = {"real": 3, "dt400": 5, "trkdt": 21, "occldt": 9}


def view(rec, name: str, seed: int):
    """(recording, info) of one view of `rec` (module docstring)."""
    from realism import drive_through, realistic, tracker_error

    if name == "real":
        return realistic(rec, seed=seed)
    if name == "dt400":
        return drive_through(rec, seed=seed, window=WINDOW)
    if name == "trkdt":
        noisy, _ = tracker_error(rec, seed=seed)
        return drive_through(noisy, seed=seed, window=WINDOW)
    if name == "occldt":
        return drive_through(rec, seed=seed, window=WINDOW, occlusion_rate=0.6)
    raise ValueError(f"unknown view {name!r}; known: {', '.join(SEED)}")


def main(argv=None) -> int:
    from realism import write_realistic

    from fitlug.io import read_rig, read_trajectories

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=os.path.join(HERE, "..", "data", "engine"))
    ap.add_argument("--out", required=True)
    ap.add_argument("--cases", nargs="*", default=["ref_100fps", "stiff_k06", "mu025",
                                                   "wheel35", "rubber_belt", "ref_250fps"])
    ap.add_argument("--views", nargs="*", default=list(SEED))
    args = ap.parse_args(argv)
    for case in args.cases:
        src = os.path.join(args.data, case)
        rig = read_rig(os.path.join(src, "rig.toml"))
        rec = read_trajectories(os.path.join(src, "trajectories.csv"), rig=rig)
        for v in args.views:
            out, info = view(rec, v, SEED[v])
            d = os.path.join(args.out, f"{case}__{v}")
            write_realistic(d, out, rig, wide=True)
            shutil.copy(os.path.join(src, "truth.json"), d)
            print(f"{case}__{v}: {len(info['fragments'])} fragments, "
                  f"{len(info['glitches'])} glitches, picture {info['fov'][0]:.0f}.."
                  f"{info['fov'][1]:.0f} mm", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
