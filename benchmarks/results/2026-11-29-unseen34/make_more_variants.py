import sys, time
from fitlug.sim.engine import simulate_engine
from fitlug.sim.engine._case import EngineCase
R=dict(k_N_per_mm=0.25, fps=100.0)
V=[
 EngineCase(name="body1", **R, body_markers=((30.0,40.0),)),
 EngineCase(name="noisy5", **R, noise_lug_mm=0.0325, noise_body_mm=0.0205),
 EngineCase(name="fps40", k_N_per_mm=0.25, fps=40.0),
 EngineCase(name="links_alt", k_N_per_mm=0.25, fps=100.0, marker_h=1.0, lug_markers=(0,2,4,6)),
 EngineCase(name="tips_spread", **R, lug_markers=(0,5,11,16)),
 EngineCase(name="mu03_heavy", **R, mu=0.3, chassis_mass_kg=20.0),
 EngineCase(name="k01", k_N_per_mm=0.1, fps=100.0),
 EngineCase(name="pushed", **R, drawbar_pull_N=-5.0),
 EngineCase(name="window200", **R, camera_window_mm=(200.0, 400.0)),
 EngineCase(name="v200_250fps", k_N_per_mm=0.25, fps=250.0, v_belt_mm_s=200.0),
 EngineCase(name="wheel45", **R, wheel_radius_mm=45.0),
 EngineCase(name="n26_six", **R, n_links=26, lug_markers=(0,1,2,3,4,5)),
]
names=sys.argv[1:]
for c in V:
    if names and c.name not in names: continue
    t=time.time()
    try:
        tr=simulate_engine(c, out_dir=f"/tmp/s34/adv2/{c.name}", seed=7)
        print(c.name, round(tr["slip"],4), [round(x,4) for x in tr["slip_per_contact_period"]], f"{time.time()-t:.0f}s", flush=True)
    except Exception as e:
        print(c.name, "FAILED", repr(e)[:300], flush=True)
