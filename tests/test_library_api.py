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


# --------------------------------------------------------------------------------------
# parameters as objects: held, bounded, prior'd (issue 27, items 1 and 3)
# --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def fits(sim):
    rec, truth, rig = sim
    free = fitlug.fit(rec, rig, glitches=False)
    params = fitlug.parameters(rec, rig)
    params["R"].fix(SC.R_mm)
    params["D_mm"].fix(SC.D_mm)  # the fit.json name is an alias of D
    held = fitlug.fit(rec, rig, params=params, glitches=False)
    return free, held, params


def test_holding_R_and_D_at_the_truth_keeps_them_and_shrinks_the_slip_error(sim, fits):
    """Fixing R and D worked only through undocumented p_start=/free= keywords, whole
    arrays, a recompile; now params["R"].fix(...) holds them by a mask."""
    _, truth, _ = sim
    free, held, _ = fits
    assert float(held.params["R"]) == SC.R_mm and float(held.params["D"]) == SC.D_mm
    sl = held.packing.slices()
    for k in ("R", "D"):
        assert np.all(held.cov[sl[k], :] == 0) and np.all(held.cov[:, sl[k]] == 0)
    assert held.dof == free.dof + 2 and held.n_params == free.n_params - 2
    s_free, s_held = free.quantities["slip"], held.quantities["slip"]
    # the geometry no longer trades with the slip: a smaller error, still covering the truth
    assert s_held.std < 0.8 * s_free.std
    assert abs(s_held.value - truth["slip"]) < 3 * s_held.std
    p = held.parameters
    assert p["R"].is_fixed and p["R"].std == 0.0 and not p["s0"].is_fixed
    assert fitlug.fit_json(held)["parameter_constraints"] == {
        "R": {"fixed": SC.R_mm}, "D": {"fixed": SC.D_mm}}
    assert "parameter_constraints" not in fitlug.fit_json(free)


def test_another_held_set_reuses_the_compiled_solver(sim, fits):
    """Mask, don't reshape: holding one body offset (an element) and bounding e is the
    same program as holding R and D: no compilation at all (a reshaped free list costs
    9 backend compilations, ~60 s cold on this machine)."""
    import jax

    rec, _, rig = sim
    events = []
    jax.monitoring.register_event_duration_secs_listener(
        lambda name, *a, **k: events.append(name) if "backend_compile" in name else None)
    params = fitlug.parameters(rec, rig)
    params["cx"][1].fix(60.0)
    params["e"].bound(0.0, 2.5)  # the truth is 3 mm: the bound binds
    res = fitlug.fit(rec, rig, params=params, glitches=False)
    assert events == []
    assert float(res.params["cx"][1]) == 60.0 and float(res.params["cx"][0]) != -60.0
    assert 2.5 - 1e-5 <= float(res.params["e"]) <= 2.5
    assert fitlug.fit_json(res)["parameter_constraints"] == {
        "cx": {"fixed": {"1": 60.0}}, "e": {"min": 0.0, "max": 2.5}}


def test_a_normal_prior_on_k_combines_variances(sim, fits):
    """A bench value of k with sd s_p is a pseudo-observation: 1/s^2 = 1/s_d^2 + 1/s_p^2,
    the estimate the inverse-variance mean (the fit is linear enough here)."""
    rec, truth, rig = sim
    free, _, _ = fits
    k = free.quantities["stiffness_N_per_mm"]
    bench, s_p = truth["stiffness_N_per_mm"] + 1.5 * k.std, 0.7 * k.std
    params = fitlug.parameters(rec, rig)
    params["k"].set_prior(fitlug.Prior.normal(bench, s_p))
    res = fitlug.fit(rec, rig, params=params, glitches=False)
    got = res.quantities["stiffness_N_per_mm"]
    want_sd = (1 / k.std ** 2 + 1 / s_p ** 2) ** -0.5
    want = (k.value / k.std ** 2 + bench / s_p ** 2) * want_sd ** 2
    assert got.std == pytest.approx(want_sd, rel=0.03)
    assert got.value == pytest.approx(want, abs=0.1 * want_sd)
    assert res.dof == free.dof  # a prior adds information, not parameters
    assert res.parameters["k"].prior.as_dict() == {"kind": "normal", "mean": bench, "sd": s_p}
    # the rig's mass with its uncertainty (2 %): k = m (k/m), relative errors in quadrature
    params = fitlug.parameters(rec, rig)
    params["mass_kg"].set_prior(fitlug.Prior.normal(SC.mass_kg, 0.02 * SC.mass_kg))
    got = fitlug.fit(rec, rig, params=params, glitches=False).quantities["stiffness_N_per_mm"]
    assert got.std == pytest.approx(np.hypot(k.std, 0.02 * k.value), rel=1e-3)
    assert got.value == pytest.approx(k.value, rel=1e-6)


def test_parameters_name_checks_and_element_access(sim):
    rec, _, rig = sim
    params = fitlug.parameters(rec, rig)
    with pytest.raises(KeyError, match="unknown parameter 'r'.*did you mean 'R'"):
        params["r"]
    with pytest.raises(ValueError, match="k is derived from the fitted parameters"):
        params["k"].fix(0.3)
    with pytest.raises(IndexError, match="cx has elements 0..1"):
        params["cx"][2]
    with pytest.raises(ValueError, match="bounds need min < max"):
        params["e"].bound(3.0, 1.0)
    with pytest.raises(ValueError, match="the spread must be > 0"):
        fitlug.Prior.normal(1.0, 0.0)
    with pytest.raises(TypeError, match="params: expected fitlug.Parameters"):
        fitlug.fit(rec, rig, params={"R": 96.0})
    assert params["R_mm"] is params["R"] and "stiffness_N_per_mm" in params
    assert len(repr(params)) < 400


def test_the_posterior_keeps_held_parameters_and_takes_a_prior_on_k(fits):
    """sample_posterior(res, prior=...) was a TypeError, and the posterior marginalised
    the held R and D again."""
    from fitlug.posterior._marginal import _Marginal

    free, held, _ = fits
    names = ["s0", "beta"]
    assert (_Marginal(held, names, 16).n_marginalised
            == _Marginal(free, names, 16).n_marginalised - 2)
    k = free.quantities["stiffness_N_per_mm"]
    post = fitlug.sample_posterior(free, prior={"k": fitlug.Prior.normal(k.value, k.std)},
                                   seed=3)
    # data and bench of equal weight: the band narrows by sqrt(2) (chain noise ~10 %)
    assert post.estimates["stiffness_N_per_mm"].std == pytest.approx(k.std / np.sqrt(2),
                                                                     rel=0.2)
    assert len(repr(post)) < 1000 and "<table>" in post._repr_html_()  # was ~5 kB
    with pytest.raises(TypeError, match=r"prior\['k'\] must be a fitlug.Prior"):
        fitlug.sample_posterior(free, prior={"k": 0.25})


def test_explain_does_not_free_held_parameters(fits):
    """explain/_final.py called free_parameters: the held R and D were fitted again."""
    _, held, _ = fits
    ex = fitlug.explain(held)
    assert float(ex.final.params["R"]) == SC.R_mm and float(ex.final.params["D"]) == SC.D_mm
    assert ex.final.constraints.as_json() == held.constraints.as_json() != {}


# --------------------------------------------------------------------------------------
# labelled results, summary, short reprs (issue 27, items 3 and 7)
# --------------------------------------------------------------------------------------
def test_covariance_and_correlation_are_labelled(fits):
    free, held, _ = fits
    cov = free.covariance_frame()
    n = len(free.flat)
    assert cov.shape == (n, n) and list(cov.index) == list(cov.columns)
    assert {"R", "D", "s0", "beta", "cx[1]", "v[0]"} <= set(cov.index)
    sl = free.packing.slices()
    assert cov.loc["R", "D"] == free.cov[sl["R"].start, sl["D"].start]
    # the slip's error from the labelled table agrees with the quantity's (delta method:
    # slip = s0 for the base model)
    assert np.sqrt(cov.loc["s0", "s0"]) == pytest.approx(free.quantities["slip"].std,
                                                         rel=1e-9)
    corr = free.correlation()
    assert np.allclose(np.diag(corr.to_numpy()), 1.0)
    assert np.all(np.abs(corr.to_numpy()) <= 1 + 1e-9)
    assert held.correlation().loc["R"].isna().all()  # held: no correlation


def test_residuals_by_marker_and_axis_raw_and_standardised(sim, fits):
    """Residuals were one flat weighted vector in internal order."""
    rec, truth, _ = sim
    free, _, _ = fits
    df = free.residuals_frame()
    assert len(df) == len(free.residuals)
    assert set(df["marker"]) == set(rec.markers) and set(df["axis"]) == {"x", "y"}
    used = df[df["used"]]
    assert np.nansum(used["standardised"] ** 2) == pytest.approx(free.chi2, rel=1e-12)
    # raw residuals in mm: their scatter is the simulated noise per role
    for role, sd in (("lug", SC.noise_lug_mm), ("body", SC.noise_body_mm)):
        raw = used[used["role"] == role]["raw_mm"]
        assert np.std(raw) == pytest.approx(sd, rel=0.1)
    by = free.residuals_by_marker()
    m = rec.markers[0]
    sel = df[(df["marker"] == m) & (df["axis"] == "y")]
    assert np.array_equal(by[m]["y"], sel["raw_mm"].to_numpy(), equal_nan=True)
    assert np.all(np.diff(by[m]["t"]) > 0)


def test_summary_is_the_terminal_text_and_reprs_are_short(sim, fits):
    """repr(FitResult) was 14 kB, Explanation 35 kB; no summary()."""
    rec, _, _ = sim
    free, held, _ = fits
    text = free.summary()
    s = free.quantities["slip"]
    from fitlug.report._format import pm

    assert text.splitlines()[1].startswith("  slip s0") and pm(s.value, s.std) in text
    assert "chi2/dof" in text and "lug stiffness k" in text
    for obj in (free, held, rec, fitlug.explain(held)):
        assert len(repr(obj)) < 1000, type(obj).__name__
    assert "2 held" in repr(held) and "slip" in repr(free)
    assert "<table>" in free._repr_html_() and len(free._repr_html_()) < 3000
    assert "<table>" in fitlug.explain(held)._repr_html_()
    assert "<Recording" in repr(rec) and "samples" in repr(rec)


def test_scenario_takes_effect_parameters_by_their_fit_json_names():
    """`Scenario(effects={"wheel_runout": {"epsilon": .., "phi_rad": ..}})` (fit.json's and
    the CLI's names) raised ValueError: only runout_a/b were known."""
    from fitlug.model.effects import CATALOG

    sc = Scenario(effects={"wheel_runout": {"epsilon": 0.01, "phi_rad": 0.5}})
    a, b = sc.effects["wheel_runout"]["runout_a"], sc.effects["wheel_runout"]["runout_b"]
    assert a == pytest.approx(0.01 * np.cos(0.5)) and b == pytest.approx(0.01 * np.sin(0.5))
    sc.check()
    rng = np.random.default_rng(4)
    for eid, eff in CATALOG.items():  # every reported set maps back to the same physics
        p = {k: float(v) + float(rng.uniform(0.05, 0.2)) * (eff.scales.get(k) or 1.0)
             for k, v in eff.defaults.items()}
        rep = {k: v for k, v in eff.report(p).items() if v is not None}
        back = Scenario(effects={eid: rep}).effects[eid]
        again = eff.report({**eff.defaults, **back})
        for k, v in rep.items():
            assert again[k] == pytest.approx(v, rel=1e-9, abs=1e-15), (eid, k)
    with pytest.raises(ValueError, match=r"no parameter 'eps'.*fit.json names them: "
                                         r"epsilon, phi_rad"):
        Scenario(effects={"wheel_runout": {"eps": 0.01}}).check()
