"""Issue 2 benchmark: speed of the least-squares fit and statistical efficiency of the slip.

(a) one warm fit of data/reference with fitlug (JAX + optimistix LM) against
    scipy.optimize.least_squares on the same model written in numpy (same start);
(b) a batch of 64 fits through jax.vmap against sequential scipy fits;
(c) slip RMSE over >= 100 simulated recordings against the Cramér-Rao bound (Fisher
    information of the model at the noise-free best fit).
Run: python benchmarks/bench_fit.py [--n 100] [--batch 64] [--scipy-batch 8]
"""

import argparse
import os
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
from scipy.optimize import least_squares as scipy_lsq

sys.path.insert(0, os.path.dirname(__file__))
import _numpy_model  # noqa: E402

from fitlug.fit import build_problem, fit_problem, free_parameters  # noqa: E402
from fitlug.fit._lsq import _solve  # noqa: E402
from fitlug.fit._residuals import Packing, residuals  # noqa: E402
from fitlug.fit._result import derived  # noqa: E402
from fitlug.io import read_rig, read_trajectories  # noqa: E402
from fitlug.sim import Scenario, rig_of, simulate  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
GN_STEPS = 8  # vmapped batches: Gauss-Newton steps before LM (see fitlug.fit._lsq._solve)


def timed(f, repeat=3):
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = f()
        best = min(best, time.perf_counter() - t0)
    return best, out


def scipy_fit(prob):
    packing = Packing.of(prob.p0, free_parameters(prob.lay))
    flat0 = np.asarray(packing.pack(prob.p0))
    sol = scipy_lsq(_numpy_model.residuals, flat0, args=(packing, prob.lay, prob.obs),
                    method="trf", x_scale="jac", xtol=1e-10, ftol=1e-10, gtol=1e-10)
    return sol


def _print_a(res, agree, t_jax, t_sp, sol):
    print("(a) one warm fit of data/reference (650 frames, 12 markers, "
          f"{len(res.flat)} parameters)")
    print(f"    numpy model vs JAX model residuals: max |diff| = {agree:.1e} (in sigma units)")
    print(f"    fitlug (JAX, optimistix LM): {t_jax:.2f} s, {res.steps} steps, chi2 {res.chi2:.1f}")
    print(f"    scipy least_squares (trf, numpy model, 2-point Jacobian): {t_sp:.2f} s, "
          f"{sol.nfev} evaluations, chi2 {2 * sol.cost:.1f}")
    print(f"    ratio fitlug / scipy = {t_jax / t_sp:.2f}  (target <= 2)")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=100)
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument("--scipy-batch", type=int, default=8)
    ap.add_argument("--parts", default="a,b,c", help="which of (a), (b), (c) to run")
    args = ap.parse_args()
    parts = set(args.parts.split(","))
    d = os.path.join(ROOT, "data", "reference")
    rec = read_trajectories(os.path.join(d, "trajectories.csv"))
    rig = read_rig(os.path.join(d, "rig.toml"))
    prob = build_problem(rec, rig)
    fit_problem(prob)  # compile
    t_jax, res = timed(lambda: fit_problem(prob))
    # same model in numpy: check it agrees, then time scipy
    packing = res.packing
    r_np = _numpy_model.residuals(res.flat, packing, prob.lay, prob.obs)
    agree = np.max(np.abs(r_np - res.residuals))
    t_sp, sol = timed(lambda: scipy_fit(prob), repeat=1) if "a" in parts else (None, None)
    if "a" in parts:
        _print_a(res, agree, t_jax, t_sp, sol)
    if not parts & {"b", "c"}:
        return

    # (b) batch of fits: recordings of the same scenario, one shared layout
    sc = Scenario()
    recs = [simulate(sc, seed=1000 + i)[0] for i in range(max(args.batch, args.n))]
    probs = [prob.__class__(**{**build_problem(r, rig_of(sc)).__dict__}) for r in recs[:1]]
    base = probs[0]
    obs_list, flat_list = [], []
    for r in recs:
        pb = build_problem(r, rig_of(sc))
        if pb.p0["v"].shape != base.p0["v"].shape or pb.lay.n_belt != base.lay.n_belt:
            pb = None
        obs_list.append(_obs_on(base, r))
        flat_list.append(packing.pack(base.p0 if pb is None else pb.p0))
    obs_b = {k: jnp.stack([o[k] for o in obs_list[:args.batch]]) for k in obs_list[0]}
    flat_b = jnp.stack(flat_list[:args.batch])
    solve_b = jax.jit(jax.vmap(lambda f0, ob: _solve(f0, {}, base.lay, ob, packing, 300, 1e-8,
                                                     1e-6, GN_STEPS)[0]))
    jax.block_until_ready(solve_b(flat_b, obs_b))  # compile
    if "b" in parts:
        _part_b(args, base, packing, obs_list, flat_list, solve_b, flat_b, obs_b)
    if "c" in parts:
        _part_c(args, sc, base, packing, obs_list, flat_list, solve_b)


def _part_b(args, base, packing, obs_list, flat_list, solve_b, flat_b, obs_b):
    t_b, out = timed(lambda: jax.block_until_ready(solve_b(flat_b, obs_b)), repeat=1)
    k = args.scipy_batch
    t0 = time.perf_counter()
    for i in range(k):
        pb = base.__class__(**{**base.__dict__, "obs": obs_list[i],
                               "p0": packing.unpack(flat_list[i], {})})
        scipy_fit(pb)
    t_sk = (time.perf_counter() - t0) / k
    print(f"(b) {args.batch} fits through jax.vmap: {t_b:.2f} s ({t_b / args.batch:.3f} s per fit)")
    print(f"    scipy sequential: {t_sk:.2f} s per fit (mean of {k}), x{args.batch} = "
          f"{t_sk * args.batch:.1f} s")
    print(f"    speed-up = {t_sk * args.batch / t_b:.1f}x  (target >= 5)")
    # the same fits in vmapped chunks: a vmapped while loop runs every lane until the
    # slowest converges, so smaller batches lose less to stragglers
    for c in (4, 16):
        if args.batch % c:
            continue
        solve_c = jax.jit(jax.vmap(lambda f0, ob: _solve(f0, {}, base.lay, ob, packing, 300,
                                                         1e-8, 1e-6, GN_STEPS)[0]))
        chunks = [(flat_b[i:i + c], {kk: v[i:i + c] for kk, v in obs_b.items()})
                  for i in range(0, args.batch, c)]
        jax.block_until_ready(solve_c(*chunks[0]))  # compile
        t0 = time.perf_counter()
        for ch in chunks:
            jax.block_until_ready(solve_c(*ch))
        t_c = time.perf_counter() - t0
        print(f"    in vmapped chunks of {c}: {t_c:.2f} s ({t_c / args.batch:.3f} s per fit), "
              f"speed-up {t_sk * args.batch / t_c:.1f}x")
    one = jax.jit(lambda f0, ob: _solve(f0, {}, base.lay, ob, packing, 300, 1e-8, 1e-6)[0])
    jax.block_until_ready(one(flat_b[0], {kk: v[0] for kk, v in obs_b.items()}))
    t0 = time.perf_counter()
    for i in range(args.batch):
        jax.block_until_ready(one(flat_b[i], {kk: v[i] for kk, v in obs_b.items()}))
    t_1 = time.perf_counter() - t0
    print(f"    one after another (jitted, no vmap): {t_1:.2f} s ({t_1 / args.batch:.3f} s per "
          f"fit), speed-up {t_sk * args.batch / t_1:.1f}x")


def _part_c(args, sc, base, packing, obs_list, flat_list, solve_b):
    # (c) slip RMSE over n recordings vs the Cramér-Rao bound
    obs_n = {kk: jnp.stack([o[kk] for o in obs_list[:args.n]]) for kk in obs_list[0]}
    flat_n = jnp.stack(flat_list[:args.n])
    t0 = time.perf_counter()
    flats = np.asarray(jax.block_until_ready(solve_b(flat_n, obs_n)))
    t_n = time.perf_counter() - t0
    slip = jax.vmap(lambda f: derived(packing.unpack(f, {}), base.lay, None)["slip"])
    s_hat = np.asarray(slip(jnp.asarray(flats)))
    true_slip = sc.slip
    rmse = float(np.sqrt(np.mean((s_hat - true_slip) ** 2)))
    # CRB: Fisher information of the fitted model at the noise-free best fit
    clean = _obs_on(base, simulate(sc.replace(noise_lug_mm=0.0, noise_body_mm=0.0), 0)[0])
    clean["lug_w"] = base.obs["lug_w"] * 0 + 1.0 / sc.noise_lug_mm
    clean["body_w"] = base.obs["body_w"] * 0 + 1.0 / sc.noise_body_mm
    f_star = _solve(packing.pack(base.p0), {}, base.lay, clean, packing, 300, 1e-12, 1e-12)[0]
    J = jax.jacfwd(lambda f: residuals(packing.unpack(f, {}), base.lay, clean))(f_star)
    g = jax.grad(lambda f: derived(packing.unpack(f, {}), base.lay, None)["slip"])(f_star)
    F = np.asarray(J.T @ J)
    crb = float(np.sqrt(np.asarray(g) @ np.linalg.pinv(F, rcond=1e-14) @ np.asarray(g)))
    bias = float(np.mean(s_hat) - true_slip)
    print(f"(c) {args.n} simulated recordings ({t_n:.1f} s vmapped): slip RMSE {rmse:.3e}, "
          f"bias {bias:+.2e}, Cramér-Rao bound {crb:.3e}")
    print(f"    RMSE / CRB = {rmse / crb:.3f}  (target <= 1.1)")


def _obs_on(base, rec):
    """Observations of `rec` arranged in `base`'s layout (same scenario, same sampling)."""
    v = np.isfinite(rec.x) & np.isfinite(rec.y)
    lr, br = base.lug_rows, base.body_rows
    return {"lug_x": jnp.asarray(np.where(v[lr], rec.x[lr], 0.0)),
            "lug_y": jnp.asarray(np.where(v[lr], rec.y[lr], 0.0)),
            "lug_w": base.obs["lug_w"], "body_x": jnp.asarray(np.where(v[br], rec.x[br], 0.0)),
            "body_y": jnp.asarray(np.where(v[br], rec.y[br], 0.0)), "body_w": base.obs["body_w"]}


if __name__ == "__main__":
    main()
