"""The old route's first fit (free walk after the held stage) against the bound's KKT
condition at its held stage, per recording: where the condition holds, did the old route
end at the held stage's point? (Session 41's check before the first fit kept its held
stage: `python held_stage_check.py data/engine`.)"""
import os, sys, time
import numpy as np
import fitlug
from fitlug.fit import _lsq, build_problem, fit_problem
import fitlug.fit._fit as ff
orig = _lsq.least_squares
calls = []
def wrap(*a, **k):
    out = orig(*a, **k); calls.append((k.get("hold"), out)); return out
ff.least_squares = wrap
ff.bound_holds = lambda held: False  # the old route: always walk
root = sys.argv[1]
for case in sorted(os.listdir(root)):
    d = os.path.join(root, case)
    if not os.path.exists(os.path.join(d, "rig.toml")): continue
    calls.clear()
    try:
        prob = build_problem(os.path.join(d, "trajectories.csv"), os.path.join(d, "rig.toml"))
        res = fit_problem(prob, require_convergence=False)
    except Exception as e:
        print(case, "error", str(e)[:80], flush=True); continue
    held = [o for h, o in calls if h]
    if not held:
        print(case, "no held stage", flush=True); continue
    h = held[0]
    j = h.packing.slices()["beta"].start
    g = 2.0 * float(np.asarray(h.J)[:, j] @ np.asarray(h.r))
    b = float(np.ravel(res.params["beta"])[0])
    c2h = float(np.sum(np.asarray(h.r) ** 2))
    flag = "KKT" if g >= 0 else "into range"
    agree = ""
    if g >= 0:
        agree = "SAME" if (b == 0.0 and abs(res.chi2 / c2h - 1) < 1e-6) else "DIFFERS"
    print(f"{case:24s} held conv {h.converged} grad {g:+.3g} -> {flag:10s} final beta {b:.3g} chi2 {res.chi2:.7g} held chi2 {c2h:.7g} {agree}", flush=True)
