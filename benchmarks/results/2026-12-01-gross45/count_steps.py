"""LM steps and solver calls of fit + explain on engine recordings (run from a worktree)."""
import sys, os, time, json
sys.path.insert(0, os.path.join(os.getcwd(), "src"))
import numpy as np
import fitlug
from fitlug import _exported
orig = _exported.call
tally = {"calls": 0, "steps": 0, "wall": 0.0}
def call(name, fn, static, *args):
    t = time.perf_counter()
    out = orig(name, fn, static, *args)
    if name == "lsq_solve":
        np.asarray(out[0])
        tally["calls"] += 1; tally["steps"] += int(out[-1]); tally["wall"] += time.perf_counter() - t
    return out
_exported.call = call
for name in sys.argv[1:]:
    for k in tally: tally[k] = 0
    d = os.path.join("data/engine", name)
    rig = fitlug.read_rig(os.path.join(d, "rig.toml"))
    rec = fitlug.read_trajectories(os.path.join(d, "trajectories.csv"), rig=rig)
    c0 = time.process_time()
    res = fitlug.fit(rec, rig)
    ex = fitlug.explain(res)
    s = ex.final.slip
    print(json.dumps({"case": name, "src": fitlug.__file__, **tally, "cpu": round(time.process_time() - c0, 1), "slip": s.value, "std": s.std}), flush=True)
