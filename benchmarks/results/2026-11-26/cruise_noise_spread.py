import sys, json, multiprocessing, numpy as np
from concurrent.futures import ProcessPoolExecutor

def one(args):
    src, sc_seed, noise_seed = args
    sys.path.insert(0, src + "/src"); sys.path.insert(0, src + "/benchmarks")
    import bench_coverage as bc
    from fitlug.sim import rig_of, simulate
    from fitlug.fit import fit
    from fitlug.explain import explain
    from fitlug.posterior import sample_posterior
    import jax
    sc, _ = bc._scenario("cruise", sc_seed)
    rec, truth = simulate(sc, noise_seed)
    rec = bc.crop(rec, sc.rest_s + sc.ramp_s + 0.05, sc.duration_s - sc.rest_s - sc.ramp_s - 0.05)
    res = fit(rec, rig_of(sc))
    ex = explain(res, seed=noise_seed)
    post = sample_posterior(ex.final, seed=noise_seed, time_budget_s=60)
    x = post.samples["slip"]
    jax.clear_caches()
    return {"noise_seed": noise_seed, "truth": truth["slip"], "median": float(np.median(x)),
            "std": float(np.std(x, ddof=1)), "lsq_std": float(ex.final.quantities["slip"].std),
            "ni": sorted(post.not_identifiable)}

if __name__ == "__main__":
    src, sc_seed, n = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(2, mp_context=ctx) as ex:
        out = list(ex.map(one, [(src, sc_seed, 1000 + i) for i in range(n)]))
    for o in out:
        print(json.dumps(o))
    med = np.array([o["median"] for o in out]); sd = np.array([o["std"] for o in out])
    z = (med - out[0]["truth"]) / sd
    print(f"SD of medians {med.std(ddof=1):.3e}; mean reported std {sd.mean():.3e}; rms z {np.sqrt(np.mean(z**2)):.2f}; covered {np.sum(np.abs(z) < 1.96)}/{len(z)}; mean lsq_std {np.mean([o['lsq_std'] for o in out]):.3e}")
