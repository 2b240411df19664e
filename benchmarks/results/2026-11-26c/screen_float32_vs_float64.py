import sys, time
sys.path.insert(0, "/work/main/benchmarks")
import numpy as np
from bench_scale import scenario_for
from fitlug.sim import Scenario, rig_of, simulate
from fitlug.fit import fit
from fitlug.explain import _engine
from fitlug.explain._engine import Engine
from fitlug.explain._candidates import screen
from fitlug.explain._table import geometry
from fitlug.model import CATALOG
frames, seed, sag = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
eff = {"belt_sag": {"sag_d": sag}} if sag > 0 else {}
sc = Scenario(**scenario_for(frames), effects=eff)
rec, _ = simulate(sc, seed=seed)
res = fit(rec, rig_of(sc))
geo = geometry(res)
out = {}
for store in (np.float64, np.float32):
    _engine.STORE = store
    eng = Engine(res)
    assert eng.chunked
    th = eng.theta0
    r = eng.residuals(th)[0]
    cands = [e for e in CATALOG if e not in res.effects]
    t0 = time.time()
    scr = screen(eng, th, r, eng.jacobian(th, [], r), cands, [], geo)
    out[store.__name__] = scr
    print(store.__name__, "screen", round(time.time() - t0, 1), "s", flush=True)
    if sag > 0:  # the second round's screening: effects active, F holds the coupled columns
        f = eng.fit(scr["belt_sag"].theta_start, eng.free_names("belt_sag"))
        cands2 = [e for e in cands if e != "belt_sag"]
        scr2 = screen(eng, f.theta, f.r, eng.jacobian(f.theta, eng.free_names("belt_sag"), f.r), cands2, eng.free_names("belt_sag"), geo)
        out[store.__name__ + "_2"] = scr2
        out[store.__name__ + "_fit"] = f
for suffix in ("", "_2"):
    a, b = out.get("float64" + suffix), out.get("float32" + suffix)
    if a is None: continue
    for e in a:
        da, db = a[e].dchi2, b[e].dchi2
        ds = np.max(np.abs(a[e].theta_start - b[e].theta_start) / np.maximum(np.abs(a[e].theta_start), 1e-12))
        print(f"round{suffix or '_1'} {e:18s} dchi2 f64 {da:14.6f} f32 {db:14.6f} rel {abs(da-db)/max(abs(da),1e-12):.2e}  start rel {ds:.2e} label {a[e].label == b[e].label}")
if sag > 0:
    print("fit chi2", out["float64_fit"].chi2, out["float32_fit"].chi2)
