"""End to end (issue 5, point 8): simulate -> render camera frames -> track -> mm -> fit.

A short simulated clip is rendered in memory (the renderer draws the noise-free marker
positions through a distorting lens, with motion blur and camera noise), tracked, mapped
back to ground mm with the rendered camera, and fitted; the fitted slip must agree with
the simulation's truth (which the vision and fit code did not produce) within 3 sigma.
"""

import numpy as np
import pytest

from fitlug.fit import fit
from fitlug.sim import Scenario, default_camera, render_frames, simulate
from fitlug.sim._render import auto_origin
from fitlug.vision import to_recording, track

SCENARIO = Scenario(duration_s=2.5, travel_mm=250.0, rest_s=0.25, ramp_s=0.7)


@pytest.fixture(scope="module")
def tracked():
    rec, truth = simulate(SCENARIO.replace(noise_lug_mm=0.0, noise_body_mm=0.0), 0)
    t = np.unique(rec.t)
    xy = np.full((t.size, rec.n_markers, 2), np.nan)
    row = np.searchsorted(t, rec.t)
    xy[row, rec.marker_index, 0] = rec.x
    xy[row, rec.marker_index, 1] = rec.y
    camera = default_camera()
    frames = list(render_frames(t, list(rec.markers), list(rec.roles), xy, camera=camera, seed=1))
    origin = auto_origin(xy, camera)
    images = np.stack([f.image for f in frames])
    result = track(images, fps=SCENARIO.fps)
    out = to_recording(result, camera, origin_mm=origin)
    return out, truth, rec


def test_tracked_clip_recovers_simulated_slip(tracked):
    rec, truth, _ = tracked
    res = fit(rec)
    slip = res.quantities["slip"]
    z = (slip.value - truth["slip"]) / slip.std
    print(f"slip {slip.value:.7f} +- {slip.std:.2g} (truth {truth['slip']}), z = {z:.2f}, "
          f"chi2/dof = {res.chi2_per_dof:.2f}")
    assert abs(z) < 3
    # measured 1.05 on this clip: the tracked positions are the truth plus ~0.0017 mm noise
    assert res.chi2_per_dof < 2.0
