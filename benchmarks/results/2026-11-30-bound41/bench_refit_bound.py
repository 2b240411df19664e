"""fitlug.fit's refits from a fit whose slip slope beta sat on its lower bound, side by side.

A record of a change tried and not kept (README.md beside it): it needs
`fitlug.fit._fit.refit_on_bound`, which exists at commit 774d833 only (reverted in
90bdc4f). Run it with that commit's source first on the path, e.g.
`git worktree add /tmp/b41 774d833 && PYTHONPATH=/tmp/b41/src python3 bench_refit_bound.py`.

fit() refits a recording after its first fit (the lug count, the glitch rounds, the noise
from the residuals). Where the first fit ended with beta held on its bound
(fitlug.fit._on_bound), each refit walks the free solver below the bound again and then
refits with beta held; at 774d833 it started held instead (`refit_on_bound`, the bound's
KKT condition). The first fit walks either way. Per recording (data/engine by default: MuJoCo's crawlers, gross misfits) this
runs fit() with the new route ("on") and the old ("off") in one process, after one warm-up
fit, and prints wall and CPU seconds, chi^2/dof, solver steps and the slip s0 of each.
Recordings whose beta is inside its range take neither route and are listed once.

    python bench_refit_bound.py [FOLDER] [CASE ...]
"""

from __future__ import annotations

import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))

import fitlug  # noqa: E402
from fitlug.fit import _fit  # noqa: E402

ON = _fit.refit_on_bound


def _off(*a, **k):
    return None


def run(rec, rig, mode):
    _fit.refit_on_bound = ON if mode == "on" else _off
    t, c = time.perf_counter(), time.process_time()
    r = fitlug.fit(rec, rig)
    return r, time.perf_counter() - t, time.process_time() - c


def main(argv):
    root = argv[0] if argv else os.path.join(HERE, "..", "..", "..", "data", "engine")
    cases = argv[1:] or sorted(os.listdir(root))
    for case in cases:
        d = os.path.join(root, case)
        if not os.path.exists(os.path.join(d, "rig.toml")):
            continue
        rig = fitlug.read_rig(os.path.join(d, "rig.toml"))
        rec = fitlug.read_trajectories(os.path.join(d, "trajectories.csv"), rig=rig)
        try:
            r0, w0, _ = run(rec, rig, "off")  # also the warm-up (compiles)
        except Exception as e:  # noqa: BLE001 - a benchmark lists what failed
            print(f"{case:24s} error {str(e)[:100]}", flush=True)
            continue
        beta = float(np.ravel(r0.params["beta"])[0])
        if beta != 0.0:
            print(f"{case:24s} beta {beta:.3g} (not on its bound): off only, {w0:.1f} s",
                  flush=True)
            continue
        rows = {}
        for mode in ("on", "off", "on"):
            rows[mode] = run(rec, rig, mode)
        for mode in ("off", "on"):
            r, w, c = rows[mode]
            print(f"{case:24s} {mode:3s} wall {w:6.2f} cpu {c:6.2f} "
                  f"chi2/dof {r.chi2_per_dof:.6g} steps {r.steps:4d} "
                  f"s0 {float(np.ravel(r.params['s0'])[0]):.6f} conv {r.converged}",
                  flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
