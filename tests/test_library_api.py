"""The library's public boundary (issue 27): stable names, early and loud errors,
parameters as objects, labelled results."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

SRC = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "src")


def _run(code: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": SRC + os.pathsep + os.environ.get("PYTHONPATH", "")}
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env=env, timeout=120)


# each order touches the three stage names differently before checking both uses
_ORDERS = [
    "import fitlug",
    "import fitlug; fitlug.campaign",
    "import fitlug.fit, fitlug.explain, fitlug.campaign; import fitlug",
    "import fitlug.campaign._law; import fitlug; fitlug.campaign",
]

_CHECK = """
import inspect, fitlug
from fitlug.campaign import fit_points
assert fitlug.campaign.fit_points is fit_points
assert fitlug.campaign.CampaignResult is fitlug.CampaignResult
assert fitlug.fit.FitResult is fitlug.FitResult
assert fitlug.explain.Explanation.__name__ == 'Explanation'
for name in ('fit', 'explain', 'campaign'):
    obj = getattr(fitlug, name)
    assert callable(obj), name
    assert list(inspect.signature(obj).parameters)[0] in ('rec', 'res', 'recordings'), name
try:
    fitlug.fit(None)
except Exception as e:
    print('CALLED', type(e).__name__)
"""


@pytest.mark.parametrize("order", _ORDERS)
def test_stage_names_are_callable_and_sub_packages_in_any_import_order(order):
    """`import fitlug; fitlug.campaign.fit_points` raised AttributeError (the lazy table
    bound the function `campaign` over the sub-package) while `import fitlug.campaign`
    first made it work: now `fitlug.fit`, `.explain`, `.campaign` are always the callable
    sub-packages."""
    out = _run(order + "\n" + _CHECK)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "CALLED" in out.stdout


# --------------------------------------------------------------------------------------
# fail loudly and early (issue 27, item 2)
# --------------------------------------------------------------------------------------
import numpy as np  # noqa: E402

import fitlug  # noqa: E402
from fitlug.io import Recording, Rig  # noqa: E402
from fitlug.sim import Scenario, simulate  # noqa: E402

SC = Scenario(duration_s=2.5, travel_mm=250.0, rest_s=0.25, ramp_s=0.7)


@pytest.fixture(scope="module")
def sim():
    rec, truth = simulate(SC, 0)
    return rec, truth, Rig(lug_pitch_mm=SC.lug_pitch_mm, mass_kg=SC.mass_kg)


@pytest.mark.parametrize("effects, error, words", [
    ("wheel_runout", TypeError, ["list of effect ids", "['wheel_runout']"]),
    (["Wheel_Runout"], ValueError, ["did you mean 'wheel_runout'", "lug_sliding"]),
    (["nope"], ValueError, ["unknown effect 'nope'", "wheel_runout", "belt_sag"]),
    ([3], TypeError, ["strings"]),
])
def test_bad_effects_fail_before_any_fit_naming_the_valid_ids(sim, effects, error, words):
    """`effects="wheel_runout"`, wrong case and unknown ids silently fitted the base model."""
    rec, _, rig = sim
    with pytest.raises(error) as exc:
        fitlug.fit(rec, rig, effects=effects)
    for w in words:
        assert w in str(exc.value)
    with pytest.raises(error):
        fitlug.build_problem(rec, rig, effects=effects)


def test_wrong_types_are_one_line_type_errors(sim):
    """A dict rig with a misspelt key, an object as recording, noise of the wrong kind,
    an unknown free name: AttributeErrors and JAX concatenate errors before."""
    rec, _, rig = sim
    with pytest.raises(TypeError, match=r"rig: unknown field 'mass'; a rig dict takes "
                                        r"load_bearing_length_mm, .*mass_kg"):
        fitlug.fit(rec, {"mass": 10.0})
    with pytest.raises(TypeError, match="recording: expected a fitlug.io.Recording, a pandas "
                                        "DataFrame or the path of a trajectory file, got dict"):
        fitlug.fit({"x": 1}, rig)
    with pytest.raises(TypeError, match="rig: expected .* got int"):
        fitlug.fit(rec, 3)
    with pytest.raises(TypeError, match="noise must be a positive number"):
        fitlug.fit(rec, rig, noise="0.005")
    with pytest.raises(ValueError, match=r"noise\['lug'\] must be finite and > 0"):
        fitlug.fit(rec, rig, noise=-1.0)
    with pytest.raises(ValueError, match="noise: no value for role 'body'"):
        fitlug.fit(rec, rig, noise={"lug": 0.01})
    with pytest.raises(ValueError, match=r"free: unknown parameter 'R_m'; valid: v, s0, beta, R"):
        fitlug.fit(rec, rig, free=["R_m"])
    with pytest.raises(TypeError, match="explain needs the FitResult"):
        fitlug.explain(rec)
    with pytest.raises(TypeError, match="sample_posterior needs a FitResult"):
        fitlug.sample_posterior(rec)


def test_dataframes_dict_rigs_paths_and_a_float_noise_are_accepted(sim, tmp_path):
    """DataFrame in and out, a dict rig, paths and noise=0.005 are converted (they raised
    AttributeError / TypeError)."""
    rec, _, rig = sim
    df = rec.to_dataframe()
    assert list(df.columns)[:5] == ["time_s", "marker", "role", "x_mm", "y_mm"]
    assert len(df) == rec.n_samples
    back = Recording.from_dataframe(df)
    assert np.array_equal(back.x, rec.x, equal_nan=True) and back.markers == rec.markers
    fitlug.write_trajectories(tmp_path / "t.csv", rec)
    (tmp_path / "rig.toml").write_text("[track]\nlug_pitch_mm = 18.36\n[vehicle]\nmass_kg = 10\n")
    a = fitlug.build_problem(df, {"lug_pitch_mm": SC.lug_pitch_mm, "mass_kg": 10.0},
                             noise=0.005)
    b = fitlug.build_problem(str(tmp_path / "t.csv"), tmp_path / "rig.toml",
                             noise={"lug": 0.005, "body": 0.005})
    assert a.noise == b.noise == {"lug": 0.005, "body": 0.005}
    assert a.rig.mass_kg == b.rig.mass_kg == 10.0
    for k in ("lug_x", "body_y"):
        assert np.allclose(np.asarray(a.obs[k]), np.asarray(b.obs[k]), atol=1e-9)
