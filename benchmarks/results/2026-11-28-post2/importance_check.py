"""An independent reference for the posterior: importance sampling of the exact marginal
(in the slip law's coordinates, whitened) from a Student t (5 dof) at its mode and Laplace
covariance, 4096 draws, seed 123.

    PYTHONPATH=src python3 benchmarks/results/2026-11-28-post2/importance_check.py /tmp/post2/final.pkl
"""
import pickle, sys, time, numpy as np
from fitlug.posterior._tempering import tempered_marginal
from fitlug.posterior._marginal import slip_law_parameters
from fitlug.posterior._sample import _exact_log_prob
from fitlug.posterior._reparam import SlipCoordinates
from fitlug.posterior._derived import _derived_samples
res = pickle.load(open(sys.argv[1],"rb"))
names = slip_law_parameters(res)
marg, _ = tempered_marginal(res, names, batch=16); marg.linearity_check()
lpt = _exact_log_prob(marg)
c = SlipCoordinates(res, names); c.whiten(marg.theta_hat, marg.cov)
lp = c.log_prob(lpt); z0, Cz, it = c.mode(lp)
rng = np.random.default_rng(123); N=4096; d=3; nu=5.0
L = np.linalg.cholesky(Cz)
y = rng.standard_normal((N,d))*np.sqrt(nu/rng.chisquare(nu,N))[:,None]; z = z0 + y@L.T
logg = -0.5*(nu+d)*np.log1p(np.sum(y*y,1)/nu)
t=time.process_time(); l = lp(z); print("evals cpu", time.process_time()-t)
w = np.exp(l - logg - np.max(l-logg)); w/=w.sum(); print("IS ESS", 1/np.sum(w**2))
th = c.theta(z); ok=np.all(np.isfinite(th),1)
s = _derived_samples(res, names, np.where(ok[:,None], th, th[ok][0]))
for k in ("slip","delta_l_mm","stiffness_N_per_mm","rolling_resistance","s0","beta","slide_mu"):
    x=np.asarray(s[k]); m=np.sum(w*x); sd=np.sqrt(np.sum(w*(x-m)**2)); print(k, m, sd)
