"""Build bench_speed's effect recording once, fit and explain it, and pickle the
explained result (Explanation.final) so that the posterior can be probed alone.

    PYTHONPATH=src python3 benchmarks/results/2026-11-28-post2/build_effect.py /tmp/post2
"""
import os
import pickle
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", ".."))
import bench_speed  # noqa: E402

out = sys.argv[1]
t = time.process_time()
csv = bench_speed._recordings(["effect"], os.path.join(out, "rec"), None)["effect"]
import fitlug  # noqa: E402

rec = fitlug.read_trajectories(csv)
rig = fitlug.read_rig(os.path.join(os.path.dirname(csv), "rig.toml"))
res = fitlug.fit(rec, rig)
expl = fitlug.explain(res, seed=0)
print("verdict", expl.verdict, "effects", expl.final.effects, "CPU s", time.process_time() - t)
with open(os.path.join(out, "final.pkl"), "wb") as fh:
    pickle.dump(expl.final, fh)
