"""Gauss-Newton bands of the campaign law (no flags, no emcee) on the limit campaign of
simulate_points: sd and mean of (estimate - truth)/std, and 95 % coverage per parameter."""
import numpy as np, sys
from fitlug.campaign import _model
from fitlug.sim._campaign import LIMIT_GROUNDS, LIMIT_K, limit_runs, simulate_points
N = int(sys.argv[1]); Z = []
runs = limit_runs(8, grounds=LIMIT_GROUNDS, masses=(1.5,))
for seed in range(1000, 1000 + N):
    pts = [_model.Point.from_dict(p) for p in simulate_points(runs, k=LIMIT_K, grounds=LIMIT_GROUNDS, law="janosi_hanamoto", seed=seed)]
    f = _model.fit_law(pts, "janosi_hanamoto")
    truth = [LIMIT_K] + [LIMIT_GROUNDS[g]["C_rr"] for g in f.design.grounds] + [1/LIMIT_GROUNDS[g]["F_max"] for g in f.design.grounds]
    Z.append((f.theta - truth) / f.std())
Z = np.array(Z); print(f.names); print("sd", Z.std(0).round(2), "mean", Z.mean(0).round(2), "cov95", (np.abs(Z) < 1.96).mean(0).round(3))
for r in runs: print(r)
