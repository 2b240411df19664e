"""The engine's named cases: the other team's failed cases on the reference rig, then
adversarial variants (rubber belt, wheel size, marker height, frame rate, spread markers)."""

from __future__ import annotations

from ._case import EngineCase

_REF = dict(k_N_per_mm=0.25, fps=100.0)

CASES: dict[str, EngineCase] = {c.name: c for c in [
    EngineCase(name="ref_100fps", **_REF,
               notes="reference rig: 22 links of 18.36 mm round 25 mm wheels, k 0.25 N/mm"),
    EngineCase(name="ref_250fps", **dict(_REF, fps=250.0), notes="the same at 250 fps"),
    EngineCase(name="stiff_k06", **dict(_REF, k_N_per_mm=0.6), notes="stiffer lugs"),
    EngineCase(name="soft_drawbar5", **dict(_REF, k_N_per_mm=0.15), drawbar_pull_N=5.0,
               cruise_s=4.0, notes="softer lugs pulling a 5 N drawbar load (a longer cruise: "
               "its slip settles slowly)"),
    EngineCase(name="mu025", **_REF, mu=0.25, notes="low friction: rear tips slide"),
    EngineCase(name="markers_on_links", **_REF, marker_h=1.0,
               notes="lug markers on the links (pitch line), not the lug tips"),
    EngineCase(name="rubber_belt", **_REF, n_links=88, link_pitch_mm=4.59, lug_every=4,
               link_mass_g=2.5, link_radius_mm=1.0, bend_Nm_per_rad=0.1,
               notes="a rubber belt: 4.59 mm links (almost smooth), lugs every 18.36 mm"),
    EngineCase(name="wheel35", **_REF, wheel_radius_mm=35.0,
               notes="35 mm wheels: shorter straight runs (the same 22 links)"),
    EngineCase(name="drive_through", **_REF, camera_window_mm=(150.0, 500.0),
               notes="the reference run seen through a 350 mm window: the robot drives in "
                     "and out of it"),
    EngineCase(name="h05_spread", **_REF, marker_h=0.5, lug_markers=(0, 5, 11, 16),
               notes="markers half-way up the lugs, on four lugs spread round the belt"),
    EngineCase(name="heavy20", **_REF, chassis_mass_kg=20.0,
               notes="a 20 kg chassis: twice the traction, a slower surge; its slip still "
                     "swings between the cruise's two contact periods"),
    EngineCase(name="pitch14_n30", **_REF, n_links=30, link_pitch_mm=14.0,
               notes="30 links of 14 mm: ten or eleven lugs touching, the four marked lugs "
                     "on the ground together for 1.3 s"),
    EngineCase(name="damp_tau02", **_REF, tau_s=0.2,
               notes="rubber damping of 0.2 s: the lift-off shear springs back slowly"),
    EngineCase(name="fps50_slow", k_N_per_mm=0.25, fps=50.0, v_belt_mm_s=100.0,
               notes="a 50 fps camera on a 100 mm/s run"),
    EngineCase(name="two_markers", **_REF, marker_h=0.2, lug_markers=(0, 11),
               notes="two lug markers half a belt apart, a fifth of the way up the lugs"),
    EngineCase(name="mu016", **_REF, mu=0.16,
               notes="friction 0.16: a quarter of the tip contacts at the limit, the tips "
                     "drift 2 mm over the ground in contact"),
    EngineCase(name="mu012", **_REF, mu=0.12,
               notes="friction 0.12: the rear tips slide (two thirds of the tip contacts at "
                     "the limit), the slip near 0.2"),
    EngineCase(name="long_cruise", **_REF, cruise_s=7.0,
               notes="the reference rig over a 7 s cruise: a dozen visits of the top run, "
                     "where the markers' speed along x reads 0.4 % under the chain's "
                     "travel"),
    EngineCase(name="light5", **_REF, chassis_mass_kg=5.0, c_rr=0.05,
               notes="a 5 kg chassis on half the rolling resistance: a slip of 0.01, its "
                     "belt 0.6 % faster in the half of the cruise the clock's passages "
                     "do not see"),
    EngineCase(name="window_late", **_REF, camera_window_mm=(300.0, 650.0),
               notes="the reference run through a late window: the body comes into the "
                     "picture 1.1 s into its cruise, which ends with the marked lugs on "
                     "the ground"),
    EngineCase(name="k015_heavy15", k_N_per_mm=0.15, fps=100.0, chassis_mass_kg=15.0,
               notes="a 15 kg chassis on 0.15 N/mm lugs: the body surges by +-10 % at "
                     "about 1 Hz, its slip 0.025 and 0.075 over the cruise's two contact "
                     "periods"),
    EngineCase(name="v400", k_N_per_mm=0.25, fps=100.0, v_belt_mm_s=400.0, cruise_s=2.0,
               notes="400 mm/s over a 2 s cruise: the body surges at 0.84 Hz, the slip "
                     "swings between 0.023 and 0.058 from one contact period to the next"),
    EngineCase(name="one_marker", **_REF, lug_markers=(0,),
               notes="the reference run with one marked lug: no passages a turn apart in "
                     "the cruise, one visit of the top run"),
    EngineCase(name="tight_wheels", **_REF, n_links=40, link_pitch_mm=10.0,
               wheel_radius_mm=15.0,
               notes="40 links of 10 mm round 15 mm wheels: the body swings from 146 to "
                     "136 mm/s after the ramp and settles at 143.5 a contact time later; "
                     "the marked lugs pass the clean part of the path only before it "
                     "settles"),
    EngineCase(name="fast_window", **_REF, v_belt_mm_s=300.0, cruise_s=2.0,
               chassis_mass_kg=15.0, camera_window_mm=(100.0, 500.0),
               notes="300 mm/s under a 15 kg chassis through a 400 mm window: the body "
                     "surges by +-1.2 mm at 1.7 Hz, its slip 0.031, 0.058 and 0.041 over "
                     "the cruise's contact periods; the robot leaves the picture after two "
                     "of them"),
    EngineCase(name="heavy_surge_window", k_N_per_mm=0.15, fps=100.0, v_belt_mm_s=250.0,
               cruise_s=2.0, chassis_mass_kg=20.0, camera_window_mm=(100.0, 500.0),
               notes="20 kg on 0.15 N/mm lugs at 250 mm/s through a 400 mm window: the "
                     "body surges by 2.5 mm about its line, its slip 0.020 and 0.031 over "
                     "the cruise's two contact periods"),
    EngineCase(name="rubber_fast_window", k_N_per_mm=0.25, fps=100.0, n_links=88,
               link_pitch_mm=4.59, lug_every=4, link_mass_g=2.5, link_radius_mm=1.0,
               bend_Nm_per_rad=0.1, v_belt_mm_s=300.0, cruise_s=2.0,
               camera_window_mm=(100.0, 500.0),
               notes="a rubber belt at 300 mm/s through a 400 mm window: its slip 0.053, "
                     "0.076 and 0.031 over the cruise's contact periods; the robot leaves "
                     "the picture after two of them"),
    EngineCase(name="abrupt_window", **_REF, ramp_s=0.15, rest_s=0.1, cruise_s=3.0,
               camera_window_mm=(100.0, 500.0),
               notes="started in 0.15 s and seen through a 400 mm window: the body surges "
                     "by 3.7 mm peak to peak after the start, its slip 0.051 and 0.025 over "
                     "the cruise's two contact periods; the robot leaves the picture "
                     "before the cruise ends"),
]}
