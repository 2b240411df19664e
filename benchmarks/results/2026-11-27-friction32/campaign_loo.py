"""Leave-one-out chi-square (2 dof) of every point of the limit campaign, against chi2(2):
the linearised predictive form (fit_with_flags) and the profile form chi2(all) - chi2(without)."""
import numpy as np, sys
from fitlug.campaign import _model
from fitlug.sim._campaign import LIMIT_GROUNDS, LIMIT_K, limit_runs, simulate_points
N = int(sys.argv[1])
A, B = [], []
for seed in range(1000, 1000 + N):
    runs = limit_runs(8, grounds=LIMIT_GROUNDS, masses=(1.5,))
    pts = [_model.Point.from_dict(p) for p in simulate_points(runs, k=LIMIT_K, grounds=LIMIT_GROUNDS, law="janosi_hanamoto", seed=seed)]
    f = _model.fit_law(pts, "janosi_hanamoto")
    for i in range(len(pts)):
        others = pts[:i] + pts[i+1:]
        fi = _model.fit_law(others, "janosi_hanamoto", start=f.theta)
        A.append(_model.point_chi2(fi, [pts[i]])[0]); B.append(f.chi2 - fi.chi2)
A, B = np.array(A), np.array(B)
from scipy import stats
for name, x in (("loo-linearised", A), ("delta chi2", B)):
    print(name, "mean", x.mean().round(2), "frac > chi2(2) 99%", np.mean(x > stats.chi2.ppf(0.99, 2)).round(3), "frac > 99.9%", np.mean(x > stats.chi2.ppf(0.999, 2)).round(4), "max", x.max().round(1))
# per point position
A = A.reshape(N, -1); B = B.reshape(N, -1)
print("mean per point loo", A.mean(0).round(2)); print("mean per point dchi2", B.mean(0).round(2))
