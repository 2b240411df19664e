"""How much of an engine recording's misfit would a body surge explain (X -> X + Delta(t)
for the body and everything it carries, not for the belt's travel; tips holding)?"""
import json, sys, time
import numpy as np
import fitlug
from fitlug.fit._fit import fit_problem
from fitlug.fit._problem import build_problem
from fitlug.explain._engine import jacobian_of
from fitlug.explain.families._context import context
from fitlug.explain.families._solve import Projector
from fitlug.explain.families._base import bspline

case = sys.argv[1]
d = f"/work/main/data/engine/{case}"
rec = fitlug.read_trajectories(d + "/trajectories.csv")
rig = fitlug.read_rig(d + "/rig.toml")
truth = json.load(open(d + "/truth.json"))
t0 = time.time()
base = fitlug.fit(rec, rig)
prob = build_problem(rec, rig, effects=["lug_shear"], noise=dict(base.problem.noise))
best = None
for h in (0.05, 0.5):
    p0 = {**prob.p0, **{k: v for k, v in base.params.items() if k in prob.p0}, "shear_h": h, "shear_tau": 0.08}
    r = fit_problem(prob, p_start=p0, require_convergence=False)
    if best is None or r.chi2 < best.chi2:
        best = r
res = best
print(case, "fit", time.time() - t0, "chi2/dof", res.chi2_per_dof, "h", res.params["shear_h"], "slip", res.slip.value, "engine", truth["slip"])
fixed = {k: v for k, v in res.params.items() if k not in res.packing.names}
J = jacobian_of(res.flat, fixed, res.packing, res.problem.lay, res.problem.obs)
ctx = context(res, J)
proj = Projector(ctx.J, ctx.r, ctx.valid)
chi2 = float(ctx.r[ctx.valid] @ ctx.r[ctx.valid]); dof = int(res.dof)
h = float(res.params["shear_h"]); tau = abs(float(res.params["shear_tau"]))
# touchdown / lift-off times of the lug rows
grid, psin = ctx.grid, ctx.psi_nodes
lug = ctx.role == 0
psi_row = np.interp(ctx.t, grid, psin)
u = np.where(lug, ctx.u, 0.0)
P = 2 * ctx.D + 2 * np.pi * ctx.R
t_e = np.interp(psi_row - u, psin, grid)
t_l = np.interp(psi_row - u + ctx.D, psin, grid)
on_run = lug & (u < ctx.D)
decay = np.exp(-np.maximum(ctx.t - t_l, 0) / max(tau, 1e-6))
lo, hi = grid[0], grid[-1]
for spacing in (0.2, 0.1, 0.05):
    n_int = int(np.ceil((hi - lo) / spacing))
    Bt = bspline(ctx.t, lo, hi, n_int)
    Be = bspline(t_e, lo, hi, n_int)
    Bl = bspline(np.minimum(t_l, ctx.t), lo, hi, n_int)
    dpsil = np.where(on_run[:, None], (1 - h) * (Bt - Be),
                     np.where(lug[:, None], (1 - h) * decay[:, None] * (Bl - Be), 0.0))
    B = ctx.dr_dX[:, None] * Bt + np.where(lug[:, None], ctx.dr_dpsi[:, None] * dpsil, 0.0)
    B = np.where(ctx.valid[:, None], B, 0.0)
    f = proj.fit(B, 0)
    print(f"  surge spacing {spacing}: {B.shape[1]} coefs, dchi2/dof {f.dchi2/dof:.1f} of {chi2/dof:.1f} ({f.dchi2/chi2:.1%}), dBIC {f.delta_bic:.0f}")
    # without the tip-holding part (surge passed to every lug marker whole)
    B2 = np.where(ctx.valid[:, None], ctx.dr_dX[:, None] * Bt, 0.0)
    f2 = proj.fit(B2, 0)
    print(f"     naive (lugs carried whole): {f2.dchi2/chi2:.1%}")
    # body markers only
    B3 = np.where((ctx.valid & (ctx.role == 1))[:, None], ctx.dr_dX[:, None] * Bt, 0.0)
    f3 = proj.fit(B3, 0)
    print(f"     body only: {f3.dchi2/chi2:.1%}")
# chi2 share by role/axis/segment
for nm, sel in (("lug x", lug & (ctx.axis == 0)), ("lug y", lug & (ctx.axis == 1)), ("body x", (ctx.role == 1) & (ctx.axis == 0)), ("body y", (ctx.role == 1) & (ctx.axis == 1))):
    s = sel & ctx.valid
    print(f"  {nm}: {float(ctx.r[s] @ ctx.r[s]) / chi2:.1%}")
for sg in range(4):
    s = lug & ctx.valid & (ctx.segment == sg)
    print(f"  seg {sg}: x {float(ctx.r[s & (ctx.axis==0)] @ ctx.r[s & (ctx.axis==0)]) / chi2:.1%} y {float(ctx.r[s & (ctx.axis==1)] @ ctx.r[s & (ctx.axis==1)]) / chi2:.1%}")
# high-pass: Delta orthogonal (over the body's span) to the speed spline's X functions
from fitlug.model._model import integrated_basis_rows
lay = res.problem.lay
body = (ctx.role == 1) & (ctx.axis == 0) & ctx.valid
blo, bhi = ctx.t[body].min(), ctx.t[body].max()
ts = np.linspace(blo, bhi, 2000)
Xb = np.zeros((len(ts), lay.n_coef))
for sel, rows in integrated_basis_rows(lay, ts):
    Xb[sel] = rows
Xb = np.hstack([np.ones((len(ts), 1)), Xb])
Q, _ = np.linalg.qr(Xb)
for spacing in (0.2, 0.1):
    n_int = int(np.ceil((bhi - blo) / spacing))
    Bts = bspline(ts, blo, bhi, n_int)
    M = Bts - Q @ (Q.T @ Bts)  # the part of each basis function outside the X space
    # coefficient directions whose function is orthogonal: null space of Q^T Bts
    U, S, Vt = np.linalg.svd(Q.T @ Bts)
    rank = int(np.sum(S > 1e-8 * S[0]))
    N = Vt[rank:].T
    Bt = bspline(ctx.t, blo, bhi, n_int); Be = bspline(t_e, blo, bhi, n_int); Bl = bspline(np.minimum(t_l, ctx.t), blo, bhi, n_int)
    dpsil = np.where(on_run[:, None], (1 - h) * (Bt - Be), np.where(lug[:, None], (1 - h) * decay[:, None] * (Bl - Be), 0.0))
    B = ctx.dr_dX[:, None] * Bt + np.where(lug[:, None], ctx.dr_dpsi[:, None] * dpsil, 0.0)
    B = np.where(ctx.valid[:, None], B, 0.0)
    f = proj.fit(B @ N, 0)
    d = Bts @ (N @ f.c)
    print(f"  high-pass spacing {spacing}: {N.shape[1]} of {B.shape[1]} dirs, {f.dchi2/chi2:.1%}, delta ptp {np.ptp(d):.3f} mm rms {d.std():.3f}")
    f0 = proj.fit(B, 0)
    d0 = Bts @ f0.c
    r0 = d0 - Q @ (Q.T @ d0)
    print(f"  full: {f0.dchi2/chi2:.1%}, raw ptp {np.ptp(d0):.3f}, outside-X ptp {np.ptp(r0):.3f} rms {r0.std():.3f}")
