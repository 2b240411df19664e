"""trackpy run on a rendered video feeds fitlug directly (issue 29; the `[bench]` extra).

A simulated recording is rendered as camera frames (lens distortion, blur, noise; every
marker drawn as a bright disc, trackpy's target), trackpy locates and links the discs, and
`Recording.from_dataframe` maps its pixels through the camera's calibration (the code of
`fit-lug track`); the fit recovers the simulation's slip. Skips without trackpy (`pip install
'fitlug[bench]'`).
"""

import numpy as np
import pytest

from fitlug.fit import fit
from fitlug.io import Recording
from fitlug.sim import Scenario, default_camera, render_frames, simulate

SCENARIO = Scenario(duration_s=2.5, travel_mm=250.0, rest_s=0.25, ramp_s=0.7, fps=50.0)


@pytest.mark.slow  # ~90 s on 2 cores: trackpy's pure-Python engine on 125 frames, then a fit
def test_trackpy_features_of_a_rendered_clip_give_the_slip():
    tp = pytest.importorskip("trackpy")
    pd = pytest.importorskip("pandas")
    tp.quiet()
    rec, truth = simulate(SCENARIO.replace(noise_lug_mm=0.0, noise_body_mm=0.0), 0)
    t = np.unique(rec.t)
    xy = np.full((t.size, rec.n_markers, 2), np.nan)
    row = np.searchsorted(t, rec.t)
    xy[row, rec.marker_index, 0], xy[row, rec.marker_index, 1] = rec.x, rec.y
    camera = default_camera(0.8, (800, 600), focal_px=1000.0)
    features, truth_px = [], []
    for i, frame in enumerate(render_frames(t, list(rec.markers), ["lug"] * rec.n_markers, xy,
                                            camera=camera, seed=1)):
        f = tp.locate(frame.image, 13, minmass=10000, preprocess=False, engine="python")
        f["frame"] = i
        features.append(f)
        truth_px.append(frame.truth_px)
    truth_px = np.array(truth_px)  # (F, M, 2)
    linked = tp.link(pd.concat(features, ignore_index=True), search_range=8, memory=0)
    # which particle is which marker (test-side bookkeeping only): the marker whose true
    # pixel path it follows throughout, within a pixel; a particle that trackpy linked
    # across two markers (where one leaves the view as another enters) is dropped
    owner = {}
    for pid, g in linked.groupby("particle"):
        fr = g.frame.to_numpy()
        d = np.hypot(g.x.to_numpy()[:, None] - truth_px[fr, :, 0],
                     g.y.to_numpy()[:, None] - truth_px[fr, :, 1])
        worst = np.max(np.nan_to_num(d, nan=np.inf), axis=0)
        if worst.min() < 1.0:
            owner[str(int(pid))] = rec.markers[int(np.argmin(worst))]
    assert set(owner.values()) == set(rec.markers)  # every marker followed
    kept = linked[linked.particle.astype(int).astype(str).isin(owner)]
    assert len(kept) > 0.9 * len(linked)
    body = [p for p, m in owner.items() if m in ("C1", "C2")]
    got = Recording.from_dataframe(kept, fps=SCENARIO.fps, calibration=camera, body=body)
    assert got.meta["source"].startswith("trackpy")
    res = fit(got)
    slip = res.quantities["slip"]
    z = (slip.value - truth["slip"]) / slip.std
    print(f"trackpy: {got.n_markers} particles, slip {slip.value:.6f} +- {slip.std:.2g} "
          f"(truth {truth['slip']}), z = {z:.2f}, chi2/dof {res.chi2_per_dof:.2f}")
    # measured: z = 2.9, 0.18 % off, chi2/dof 1.7 (trackpy's unfiltered centroids carry a
    # bias the fit's noise model does not know); fitlug's own tracker does better
    # (tests/test_end_to_end.py), the point here is that trackpy's output feeds it directly
    assert abs(z) < 4 and abs(slip.value / truth["slip"] - 1) < 0.01
