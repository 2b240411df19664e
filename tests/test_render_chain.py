"""Issue 9's whole chain: a clean recording rendered as video, tracked by fitlug, fitted and
explained (video -> `fit-lug track` -> `fit-lug`).

A short clip (3.5 s, 400 mm of travel, a 300 mm wide picture: every marker crosses it and
is seen in 20-70 % of the frames) is rendered by `render_recording` (markers drawn at their
noise-free simulated positions through a distorting lens, motion blur, lighting gradient,
vignetting, sensor noise), tracked by `fitlug.vision.track`, and mapped to mm twice:

- with the calib.json the renderer wrote (the lens undistorted): clean physics, the verdict
  must be `none`;
- with the scale alone (`fit-lug track --mm-per-px`): the camera's radial distortion is
  left uncorrected, which is MODEL.md's lens_distortion exactly - OpenCV's
  x_d = x_u (1 + k1 r^2) in normalised coordinates is q -> c + (q - c)(1 + k1' |q - c|^2)
  in ground mm with k1' = k1 / (f S)^2 and c the principal point: lens_distortion must
  be named alone, with that k1' and centre.

A third clip has the lens distortion in the scene (the simulator's lens_distortion, tracked
with calib.json): lens_distortion named alone with its k1 and centre.
In every case the slip must lie within 3 reported standard deviations of the simulation's
truth.
The truth comes from the simulator and the camera's parameters, which the tracker and the
fit did not produce.
"""

import numpy as np
import pytest

from fitlug.explain import explain
from fitlug.fit import fit
from fitlug.fit._problem import build_problem
from fitlug.sim import Scenario, render_recording, simulate
from fitlug.sim._simulate import rig_of
from fitlug.vision import load_calibration, scale_calibration, to_recording, track

SCENARIO = Scenario(duration_s=3.5, travel_mm=400.0, rest_s=0.25, ramp_s=0.7)
IMAGE = (770, 300)  # px at 0.39 mm/px: 300 mm x 117 mm
SEED = 0


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    out = tmp_path_factory.mktemp("render")
    info = render_recording(out, SCENARIO, seed=SEED, image_size=IMAGE, progress=False)
    result = track(out, fps=SCENARIO.fps)
    cal = load_calibration(info["calib"])
    rec = to_recording(result, cal)
    # the same tracks with the scale alone: the lens left uncorrected
    raw = to_recording(result, scale_calibration(cal.mm_per_px, cal.image_size),
                       origin_mm=info["origin_mm"])
    _, truth = simulate(SCENARIO, SEED)
    return rec, raw, truth, cal, info["origin_mm"]


def _slip_z(res, truth):
    s = res.slip
    return (s.value - truth["slip"]) / s.std


def test_markers_cross_the_picture(chain):
    rec, _, _, _, _ = chain
    frames = np.unique(rec.t).size
    seen = [np.isfinite(rec.x[rec.marker_index == m]).sum() / frames
            for m in range(rec.n_markers)]
    assert sorted(rec.roles).count("body") == 2 and len(rec.markers) == 12  # no split ids
    assert max(seen) < 0.8 and min(seen) > 0.1


def test_clean_render_tracked_says_none(chain):
    rec, _, truth, _, _ = chain
    ex = explain(fit(rec, rig_of(SCENARIO)))
    z = _slip_z(ex.final, truth)
    print(f"verdict {ex.verdict}, chi2/dof {ex.final.chi2_per_dof:.3f}, slip z {z:.2f}, "
          f"systematics {ex.systematics}")
    assert ex.verdict == "none" and ex.effects == []
    assert abs(z) < 3


def test_uncorrected_lens_is_named_alone(chain):
    _, raw, truth, cal, origin = chain
    ex = explain(fit(raw, rig_of(SCENARIO)))
    z = _slip_z(ex.final, truth)
    print(f"verdict {ex.verdict}, effects {ex.effects}, chi2/dof {ex.final.chi2_per_dof:.3f}, "
          f"slip z {z:.2f}, systematics {ex.systematics}")
    assert ex.verdict == "explained" and list(ex.effects) == ["lens_distortion"]
    assert abs(z) < 3
    # the lens as the camera has it: k1 / (f S)^2 about the principal point (ground mm)
    k = cal.camera_matrix
    s = cal.mm_per_px
    k1 = cal.dist_coeffs[0] / (k[0, 0] * s) ** 2
    centre = (origin[0] + s * k[0, 2], origin[1] + s * (cal.image_size[1] - k[1, 2]))
    p = ex.final.effect_params("lens_distortion")
    sd = ex.final.effect_params_std("lens_distortion")
    print(f"k1 {p['k1_per_mm2']:.5g} +- {sd['k1_per_mm2']:.2g} (camera {k1:.5g}); centre "
          f"({p['x_c_mm']:.2f}, {p['y_c_mm']:.2f}) +- ({sd['x_c_mm']:.2g}, "
          f"{sd['y_c_mm']:.2g}) (camera {centre[0]:.2f}, {centre[1]:.2f})")
    assert abs(p["k1_per_mm2"] - k1) < 3 * sd["k1_per_mm2"] + 0.01 * abs(k1)
    assert abs(p["x_c_mm"] - centre[0]) < 3 * sd["x_c_mm"] + 1.0
    assert abs(p["y_c_mm"] - centre[1]) < 3 * sd["y_c_mm"] + 1.0


LENS = {"lens_k1": 2e-8, "lens_cx": 200.0, "lens_cy": 40.0}  # per mm^2, mm (ground frame)


def test_lens_distortion_rendered_in_is_named_alone(tmp_path):
    """The lens distortion in the scene (the simulator's lens_distortion, drawn through the
    calibrated camera and undone by its calib.json): named alone, with its k1 and centre.
    What is left is the tracker's own bias (~0.35 um RMS, a lug-y cell on the top run):
    before the family-wise cell level of explain/_locate it was located, and the
    tracker-systematics check carried it, its nuisance moving the slip by 1.76 errors = 1.55
    times the spread that freeing it gives through the noise alone (the old rule, 1 error,
    said 'unexplained')."""
    sc = SCENARIO.replace(effects={"lens_distortion": LENS})
    info = render_recording(tmp_path, sc, seed=SEED, image_size=IMAGE, progress=False)
    rec = to_recording(track(tmp_path, fps=sc.fps), load_calibration(info["calib"]))
    _, truth = simulate(sc, SEED)
    ex = explain(fit(rec, rig_of(sc)))
    z = _slip_z(ex.final, truth)
    p = ex.final.effect_params("lens_distortion")
    sd = ex.final.effect_params_std("lens_distortion")
    print(f"verdict {ex.verdict}, effects {ex.effects}, slip z {z:.2f}, k1 "
          f"{p['k1_per_mm2']:.5g} +- {sd['k1_per_mm2']:.2g}, centre ({p['x_c_mm']:.2f}, "
          f"{p['y_c_mm']:.2f}), systematics {ex.systematics and ex.systematics['why_not']}")
    assert ex.verdict == "explained" and list(ex.effects) == ["lens_distortion"]
    assert abs(z) < 3
    assert abs(p["k1_per_mm2"] - LENS["lens_k1"]) < 3 * sd["k1_per_mm2"] + 0.01 * LENS["lens_k1"]
    assert abs(p["x_c_mm"] - LENS["lens_cx"]) < 3 * sd["x_c_mm"] + 1.0
    assert abs(p["y_c_mm"] - LENS["lens_cy"]) < 3 * sd["y_c_mm"] + 1.0


def test_no_end_knot_interval_without_samples():
    """A recording whose markers leave before its end: the speed spline's last knot interval
    must hold a sample (else its last coefficient has a zero Jacobian column: NaN errors;
    a rendered, tracked recording with lens distortion stopped there). Cut inside a ramp
    (fine knot spacing): before the fix 2.23, 2.24, 2.27 and 2.28 s put the last interior
    break in the 3-frame margin after the last sample."""
    sc = Scenario(duration_s=3.0, travel_mm=300.0, rest_s=0.25, ramp_s=0.8)
    rec, _ = simulate(sc, 0)
    for cut in (2.22, 2.23, 2.24, 2.26, 2.27, 2.28):
        gone = rec.t > cut
        r = rec.with_(x=np.where(gone, np.nan, rec.x), y=np.where(gone, np.nan, rec.y))
        breaks = np.asarray(build_problem(r, rig_of(sc)).lay.breaks)
        t_valid = r.t[np.isfinite(r.x)]
        assert breaks[-2] < t_valid.max(), (cut, breaks[-3:], t_valid.max())
        assert breaks[1] > t_valid.min()
