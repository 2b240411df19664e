"""A cruise-only recording (bench_coverage's cruise row): the middle of a 4 s run, its
rest and ramps cut off, so the data leave beta = ds/da nearly free."""

from fitlug.sim import Scenario, rig_of, simulate


def cruise_recording(slip: float, rolling_resistance: float, seed: int):
    """(recording, rig, truth) of the cruise between the ramps (1.15-2.85 s)."""
    sc = Scenario(duration_s=4.0, travel_mm=400, rest_s=0.3, ramp_s=0.8, slip=slip,
                  rolling_resistance=rolling_resistance)
    rec, truth = simulate(sc, seed=seed)
    sel = (rec.t >= 1.15) & (rec.t <= 2.85)
    keys = ("t", "marker_index", "x", "y", "sigma", "frame", "x_px", "y_px", "quality")
    rec = rec.with_(**{k: getattr(rec, k)[sel] for k in keys if getattr(rec, k) is not None})
    return rec, rig_of(sc), truth
