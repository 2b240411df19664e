"""Do the lug markers drift because they sit above the tips, or because the tips slide?

MODEL.md §2 reads the markers' height h off their drift over the ground in contact; a
lug whose tip slides drifts its marker too (issue 41: "lug_sliding named where the tips
reach the friction limit"). This script fits, on engine recordings, the base model with
the marker on the lug (`lug_shear`: h, tau) against the same with a lug shear that
saturates as a sliding tip's does: the elastic shear after slip displacement j is
d_c (1 - exp(-j / d_c)) (the tip holds while j << d_c and slides at the creep once the
shear nears d_c; 1/d_c = 0 is lug_shear). The variant is a plugin effect defined here,
not part of fitlug. Each is fitted from three starts of h (0.05, 0.5, 0.8), the best kept.

    python benchmarks/bench_tip_sliding.py mu016 mu012 h05_spread ref_100fps
"""

from __future__ import annotations

import argparse
import os
import sys
import time


def _plugin():
    import jax.numpy as jnp

    from fitlug.model.effects._lug_shear import _V_REST, LugShear, _at_psi
    from fitlug.model.effects._registry import register_effect

    def saturate(d, q):
        x = q * d
        small = jnp.abs(x) < 1e-6
        xs = jnp.where(small, 1.0, x)
        return d * jnp.where(small, 1.0 - x / 2, (1.0 - jnp.exp(-xs)) / xs)

    class TipSlide(LugShear):
        id = "tip_slide"
        defaults = {"tip_h": 1.0, "tip_tau": 0.05, "tip_q": 0.0}
        scales = {"tip_h": 0.2, "tip_tau": 0.02, "tip_q": 0.05}
        meaning = "lug shear saturating at d_c = 1/tip_q (sliding tips): an experiment"

        @classmethod
        def lug_lag(cls, p, sigma, psi, X, t, nodes, grid, ctx):
            Xn, psin, vn, dpn = nodes
            u = jnp.mod(sigma, ctx.P)
            psi_e = psi - u
            psi_l = psi_e + ctx.D
            Sn = psin - Xn
            v0 = jnp.maximum(dpn[0], _V_REST)
            s_start = jnp.where(dpn[0] > _V_REST, 1.0 - vn[0] / v0, p["s0"])
            (S_e,) = _at_psi(psi_e, psin, [(Sn, s_start)])
            S_l, t_l = _at_psi(jnp.minimum(psi_l, psi), psin,
                               [(Sn, s_start), (grid, 1.0 / v0)])
            decay = jnp.exp(-jnp.maximum(t - t_l, 0.0)
                            / jnp.maximum(jnp.abs(p["tip_tau"]), 1e-6))
            q = jnp.abs(p["tip_q"])
            d = jnp.where(u < ctx.D, saturate(psi - X - S_e, q),
                          saturate(S_l - S_e, q) * decay)
            return (1.0 - p["tip_h"]) * d

        @classmethod
        def report(cls, p):
            return {"h": float(p["tip_h"]), "tau_s": abs(float(p["tip_tau"])),
                    "d_c_mm": 1.0 / max(abs(float(p["tip_q"])), 1e-12)}

    register_effect(TipSlide)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cases", nargs="+")
    ap.add_argument("--data", default=os.path.join("data", "engine"))
    args = ap.parse_args(argv)
    import json

    import fitlug
    from fitlug.fit._fit import fit_problem
    from fitlug.fit._problem import build_problem

    _plugin()
    print(f"{'case':12s} {'tips at limit':>13s} {'model':10s} {'chi2/dof':>9s} {'h':>6s} "
          f"{'tau s':>6s} {'d_c mm':>8s} {'slip':>7s} {'engine':>7s} {'s':>4s}")
    for case in args.cases:
        d = os.path.join(args.data, case)
        rec = fitlug.read_trajectories(os.path.join(d, "trajectories.csv"))
        rig = fitlug.read_rig(os.path.join(d, "rig.toml"))
        with open(os.path.join(d, "truth.json")) as f:
            truth = json.load(f)
        base = fitlug.fit(rec, rig)
        for eid, hk, tk, extra in (("lug_shear", "shear_h", "shear_tau", {}),
                                   ("tip_slide", "tip_h", "tip_tau", {"tip_q": 0.1})):
            t0 = time.process_time()
            prob = build_problem(rec, rig, effects=[eid], noise=dict(base.problem.noise))
            best = None
            for h in (0.05, 0.5, 0.8):
                p0 = {**prob.p0, **{k: v for k, v in base.params.items() if k in prob.p0},
                      hk: h, tk: 0.08, **extra}
                r = fit_problem(prob, p_start=p0, require_convergence=False)
                if best is None or r.chi2 < best.chi2:
                    best = r
            ep = best.effect_params(eid)
            dc = ep.get("d_c_mm")
            print(f"{case:12s} {truth['tip_contacts_at_friction_limit']:13.3f} {eid:10s} "
                  f"{best.chi2_per_dof:9.1f} {ep['h']:6.2f} {ep['tau_s']:6.3f} "
                  f"{'' if dc is None else ('> 1e3' if dc > 1e3 else f'{dc:.1f}'):>8s} "
                  f"{best.slip.value:7.4f} {truth['slip']:7.4f} {time.process_time() - t0:4.0f}",
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
