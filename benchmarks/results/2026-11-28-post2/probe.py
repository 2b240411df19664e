"""sample_posterior alone on a pickled FitResult (build_effect.py), CPU seconds in-process.

    PYTHONPATH=src python3 benchmarks/results/2026-11-28-post2/probe.py /tmp/post2/final.pkl [seed]
"""
import json
import pickle
import sys
import time

import numpy as np

from fitlug.posterior import sample_posterior

with open(sys.argv[1], "rb") as fh:
    res = pickle.load(fh)
seed = int(sys.argv[2]) if len(sys.argv) > 2 else 0
t = time.process_time()
post = sample_posterior(res, seed=seed)
cpu = time.process_time() - t
m = post.mcmc_json()
print(json.dumps({"cpu_s": cpu, "steps": m["steps"], "converged": m["converged"],
                  "tau": m["autocorr_time_per_parameter"], "ess": m["ess"],
                  "method": m["method"], "coordinates": m.get("coordinates"),
                  "estimates": {k: (e.value, e.std, e.ci95) for k, e in post.estimates.items()},
                  "theta": {k: (float(np.median(post.samples[k])), float(np.std(post.samples[k])))
                            for k in post.parameters}}, default=str, indent=1))
