"""The engine variants of session 34 (fitlug.sim.engine, MuJoCo; not committed but light5).

    python make_variants.py first [NAME ...]   # seed 5, into /tmp/s34/adv (bench_engine_before/after)
    python make_variants.py more [NAME ...]    # seed 7, into /tmp/s34/adv2 (bench_engine_more)
"""
import sys, time
from fitlug.sim.engine import simulate_engine
from fitlug.sim.engine._case import EngineCase
R=dict(k_N_per_mm=0.25, fps=100.0)
SETS={
 "first": (5, "/tmp/s34/adv", [
 EngineCase(name="fast300", **R, v_belt_mm_s=300.0, cruise_s=2.0),
 EngineCase(name="slow60", **R, v_belt_mm_s=60.0, cruise_s=4.0),
 EngineCase(name="p24_w32", **R, n_links=18, link_pitch_mm=24.0, wheel_radius_mm=32.0),
 EngineCase(name="h03_six", **R, marker_h=0.3, lug_markers=(0,1,2,3,4,5)),
 EngineCase(name="light5", **R, chassis_mass_kg=5.0, c_rr=0.05),
 EngineCase(name="drawbar10_k04", k_N_per_mm=0.4, fps=100.0, drawbar_pull_N=10.0),
 EngineCase(name="body3", **R, body_markers=((-100.0,80.0),(0.0,30.0),(100.0,80.0))),
 EngineCase(name="links200", k_N_per_mm=0.25, fps=200.0, marker_h=1.0),
 EngineCase(name="short_ramp", **R, ramp_s=0.3),
 EngineCase(name="w20_p12", **R, n_links=34, link_pitch_mm=12.0, wheel_radius_mm=20.0),
 EngineCase(name="belt_every2", **R, n_links=44, link_pitch_mm=9.18, lug_every=2, link_mass_g=5.0),
 EngineCase(name="mu02_window", **R, mu=0.2, camera_window_mm=(100.0, 420.0)),
]),
 "more": (7, "/tmp/s34/adv2", [
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
]),
}
seed, out, V = SETS[sys.argv[1]]
names=sys.argv[2:]
for c in V:
    if names and c.name not in names: continue
    t=time.time()
    try:
        tr=simulate_engine(c, out_dir=f"{out}/{c.name}", seed=seed)
        print(c.name, round(tr["slip"],4), [round(float(x),4) for x in tr["slip_per_contact_period"]], f"{time.time()-t:.0f}s", flush=True)
    except Exception as e:
        print(c.name, "FAILED", repr(e)[:300], flush=True)
