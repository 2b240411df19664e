"""After the catalog, the families (MODEL.md §5, issue 28): physics no catalog entry names
is modelled by the right family, at its place and in its coordinate, with the fit brought
to the noise and the slip covered; nulls and catalog recordings get no family term.

The recordings come from tests/mechanisms.py (its own simulator and forms: a tanh squat,
a cosine bump with wheels rolling over it, a cogging with a second harmonic at a
non-integer period per wheel turn), seen through a real tracker's faults (a window
narrower than the travel, misses, occlusions, glitches, split ids). Seed 19 draws one of
the shortest recordings (100 fps, 5.07 s: the file stays fast); squat uses seed 0 (250
fps, drawn size), where the catalog names nothing wrong first (on seed 19 it takes part of
a squat for body_bounce: a catalog matter, not the families'). slip_speed and idler_wobble
are the issue's two mechanisms of our own choosing. Set sizes are
in the upper half of the drawn ranges, so that the base model clearly fails.
"""

from __future__ import annotations

import numpy as np
import pytest

import mechanisms as M
from fitlug.explain import explain
from fitlug.fit import fit

SEED = 19  # 100 fps, 5.07 s, two body markers (pitch identifiable)

#: mechanism -> (seed, size (None: drawn), family, coordinate kept)
CASES = {
    "squat": (0, None, "body motion", "a"),  # 250 fps: A 0.099 mm per m/s^2
    "flap": (SEED, 0.2, "segment vibration", "xi"),
    # MODEL.md §5's other three families: a support roller under the top run, lugs that
    # splay round the wheels, a camera not square to the track, a jittering clock
    "carrier_roller": (SEED, 0.3, "path shape", "xi"),
    "keystone": (SEED, 0.5, "image map", "q"),
    "frame_jitter": (SEED, 0.15, "time map", "t"),
    # the frame vibrating at a fixed frequency: body motion in time, not in belt travel
    "frame_vibration": (SEED, 0.04, "body motion", "t"),
    # MODEL.md §5's fourth coordinate of body motion: the body's ground position X (a
    # carriage on a rail that bows); the lugs do not show it, so it is not the ground's
    "rail_bow": (SEED, 0.15, "body motion", "X"),
    # a speed controller hunting at 15 Hz (speed modulation in time): two 0.7 mm glitches
    # hide under its misfit from the base fit's finder; left in, they pulled the slip 5
    # sigma off
    "speed_hunt": (SEED, 0.015, "speed modulation", "t"),
}


#: cases kept for benchmarks/bench_discovery.py only (the CI's time, issue 43 item 6): the
#: same families and coordinates are held by the cases above (speed modulation: speed_hunt;
#: time map: frame_jitter; body motion in psi: the catalog's body_bounce) or by
#: tests/test_families_independent.py on the independent generator (ground profile in x:
#: its ground bump, peak within 10 % and place within a tenth of the width, not an image
#: map; slip law in v: its rolling resistance growing with speed, the change at v_ref
#: against the truth, the shape's band, the base fit's slip > 10 sigma off), and the
#: regressions they guarded are in the benchmark's rows (cogging's slip 80 sigma off,
#: ground_step's knots); marked `bench`, which the default run deselects:
#: `pytest -m bench tests/test_families.py`
BENCH_ONLY = {
    # draw 1003 (200 fps, drawn sizes): the base fit's slip 133 sigma off; one linear step
    # with the columns held at the base fit's segments left it 9.7 sigma off at chi2/dof
    # 1.05 (the term's place moves with the fit: relinearised, _relin.py). Path shape in
    # xi is held by carrier_roller above (2026-12-02: 90 s cold, the heaviest case)
    "lug_splay": (1003, None, "path shape", "xi"),
    "bump": (SEED, 0.6, "ground profile", "x"),
    # one of our own: a slip growing with speed (s_lin (1 + c v))
    "slip_speed": (SEED, 0.3, "slip law", ("F,v", "v")),
    # draw 1016 (46 Hz at 250 fps, 1.7 %): the slip answers the modulated acceleration by
    # +- 0.1 and runs the belt 0.6 % faster on average; the phase read at the base fit's
    # belt travel and the covariance of the base fit left the slip 80 sigma off
    "cogging": (1016, None, "speed modulation", "psi"),  # drawn size
    # a board on the floor (0.70 mm high, 35 mm wide, edges rounded over 0.5 mm): equal
    # knots left chi2/dof 3.1 (unexplained); knots are added where the ground changes fast
    "ground_step": (21, None, "ground profile", "x"),
    # a clock that wobbles at 10.8 Hz: a speed modulation in time would fit it too, but
    # the slip would answer a modulated speed; the criterion must tell them apart
    "clock_wobble": (SEED, 0.3, "time map", "t"),
    # an eccentric idler
    "idler_wobble": (SEED, 0.1, "body motion", "psi"),
}


def _explained(mechanism, seed=SEED, size=None):
    rec, rig, truth = M.make(mechanism, seed, size=size)
    return explain(fit(rec, rig)), truth


@pytest.mark.parametrize("mechanism", [*CASES, *(pytest.param(k, marks=pytest.mark.bench)
                                                 for k in BENCH_ONLY)])
def test_a_mechanism_outside_the_catalog_is_modelled_by_its_family(mechanism, tmp_path):
    check_modelled(mechanism, tmp_path)


def check_modelled(mechanism, tmp_path):
    """The recording CASES[mechanism] is modelled by its family, in its coordinate, with
    the fit brought to the noise, the slip covered and the shape against the truth."""
    seed, size, family, coordinate = {**CASES, **BENCH_ONLY}[mechanism]
    ex, truth = _explained(mechanism, seed, size)
    assert ex.effects == []  # no catalog entry takes it
    assert ex.verdict == "modelled", ex.to_json().get("families_tried")
    terms = ex.discovered
    assert [t["family"] for t in terms][:1] == [family]
    t = terms[0]
    assert t["coordinate"] in ((coordinate,) if isinstance(coordinate, str) else coordinate)
    assert t["delta_bic"] < -10
    assert t["chi2_per_dof_after"] <= 1.3 < t["chi2_per_dof_before"]
    assert ex.final.chi2_per_dof <= 1.3
    s = ex.final.slip
    assert abs(s.value - truth["slip"]) <= 3 * s.std, (s.value, s.std, truth["slip"])
    # DATA.md's discovered entry: the shape with its band, a reading in words
    sh = t["shape"]
    n = len(sh["coordinate"])
    assert n > 10 and len(sh["value"]) == len(sh["lo"]) == len(sh["hi"]) == n
    assert all(lo <= v <= hi for lo, v, hi in zip(sh["lo"], sh["value"], sh["hi"]))
    assert t["reading"] and not t["partial"]
    p, q = t["params"], truth["params"]
    if mechanism == "flap":  # the frequency and the mid-span amplitude, against the truth
        assert t["frequency_hz"] == pytest.approx(q["f_Hz"], abs=0.05)
        assert p["amplitude_mid_span_mm"] == pytest.approx(q["A_mm"], rel=0.1)
        assert "flaps" in t["reading"]
    elif mechanism == "cogging":
        assert p["period_mm"] == pytest.approx(q["period_mm"], rel=2e-3)
        assert p["amplitude"] == pytest.approx(q["epsilon"] * (1 + q["h2"]), rel=0.35)
        # in Hz under the extended fit's belt speed (the base fit's was 0.6 % fast)
        assert t["frequency_hz"] == pytest.approx(q["f_cruise_Hz"], rel=2e-3)
    elif mechanism == "bump":
        assert p["at_x_mm"] == pytest.approx(q["x_mm"], abs=0.15 * q["width_mm"])
        assert p["peak_mm"] == pytest.approx(q["height_mm"], rel=0.2)
    elif mechanism == "ground_step":  # on the board; the drawn shape at its height
        assert q["shape"] == "plank" and p["knots_added"] > 0
        assert abs(p["at_x_mm"] - q["x_mm"]) <= q["width_mm"] / 2
        x, y = np.asarray(sh["coordinate"]), np.asarray(sh["value"])
        top = np.abs(x - q["x_mm"]) < q["width_mm"] / 4
        floor = np.abs(x - q["x_mm"]) > q["width_mm"] / 2 + 10.0
        assert top.sum() >= 3 and floor.sum() >= 3
        # the level is the fit's (y_off): the board's height above the floor round it
        assert np.median(y[top]) - np.median(y[floor]) == pytest.approx(q["height_mm"],
                                                                        rel=0.15)
        assert p["peak_mm"] == pytest.approx(q["height_mm"], rel=0.15)  # above the floor
    elif mechanism == "squat":
        assert p["heave_mm_per_m_s2"] < 0 and "squats" in t["reading"]
    elif mechanism == "slip_speed":  # s_lin (1 + c v): the change at v_ref is s0 c v_ref
        g = truth["slip_linear_s0"] * q["c_per_m_s"] * p["v_ref_mm_s"] / 1000.0
        assert p["slip_change_at_v_ref"] == pytest.approx(g, rel=0.1)
        assert "grows with speed" in t["reading"]
        # the base fit's slip was off (a linear law bent by the speed): the headline moved
        before = ex.base.slip
        assert abs(before.value - truth["slip"]) > 10 * before.std
    elif mechanism == "idler_wobble":
        assert "once per wheel turn" in t["reading"]
    elif mechanism == "carrier_roller":  # a tent on the top run: its height and place
        assert t["segment"] == "top"
        assert p["peak_mm"] == pytest.approx(q["h_mm"], rel=0.15)
        assert p["at_xi"] == pytest.approx(q["xi_roller"], abs=0.08)
    elif mechanism == "lug_splay":  # the mean radial offset round each wheel
        for wheel in ("rear", "front"):
            want = q[f"delta_{wheel}_mm"] * (1 - q[f"ramp_{wheel}"] / 2)
            assert p["mean_radial_mm"][wheel] == pytest.approx(want, rel=0.2, abs=0.02)
    elif mechanism == "keystone":  # a projective warp is quadratic at first order
        assert p["degree"] >= 2 and "squarely" in t["reading"]
    elif mechanism == "frame_vibration":
        assert t["frequency_hz"] == pytest.approx(q["f_Hz"], abs=0.02)
        assert "vibrates" in t["reading"]
    elif mechanism == "speed_hunt":
        assert t["frequency_hz"] == pytest.approx(q["f_Hz"], abs=0.02)
        assert p["amplitude"] == pytest.approx(q["epsilon"], rel=0.15)
        # two 0.7 mm glitches in frames that the hunt's misfit flags on three markers or
        # more: the base fit's finder keeps them out as glitches on top of that common
        # cause (before, only the discovery's finder found them, after the terms)
        assert truth["n_glitches"] == len(truth["glitches"]) >= 4
        listed = {(g["marker"], round(g["time_s"], 6))
                  for g in ex.final.problem.init_info["glitches"]}
        assert set(truth["glitches"]) <= listed
    elif mechanism == "rail_bow":
        assert "rail" in t["reading"] and p["X_range_mm"][1] - p["X_range_mm"][0] > 100
    elif mechanism == "clock_wobble":
        assert t["frequency_hz"] == pytest.approx(q["f_Hz"], abs=0.02)
        assert p["amplitude_ms"] == pytest.approx(q["A_ms"], rel=0.1)
    elif mechanism == "frame_jitter":
        if q["form"] == "every other frame late":
            assert abs(p["late_ms"]) == pytest.approx(q["sd_ms"], rel=0.15)
        else:
            assert p["rms_ms"] == pytest.approx(q["sd_ms"], rel=0.25)
    if mechanism == "flap":  # the report draws it, the terminal line reads it
        _report_shows_the_term(ex, tmp_path)


def _report_shows_the_term(ex, folder):
    from fitlug.io import write_json
    from fitlug.report import fit_json, save_state, write_report

    doc = fit_json(ex.final, input_path="trajectories.csv", discrepancy=ex.to_json())
    doc["mcmc"] = None
    write_json(folder / "fit.json", doc)
    save_state(folder, ex.final, explanation=ex)
    page = open(write_report(folder), encoding="utf-8").read()
    assert "Modelled beyond the catalog" in page
    assert 'alt="segment vibration term: shape and residuals"' in page
    assert doc["slip"]["value"] == pytest.approx(ex.final.slip.value)


@pytest.mark.parametrize("mechanism", ["null", "wheel_runout"])
def test_no_family_term_on_a_null_or_a_catalog_recording(mechanism):
    ex, truth = _explained(mechanism, size=0.008 if mechanism == "wheel_runout" else None)
    assert ex.discovered == []
    assert ex.verdict in ("none", "explained")
    if mechanism == "wheel_runout":
        assert ex.effects == ["wheel_runout"]
    assert "discovered" not in ex.to_json() or ex.to_json()["discovered"] == []


def test_a_term_fitted_jointly_with_the_fit_equals_the_joint_least_squares():
    """The projection (_solve.Projector) against numpy's least squares on [J B]: the
    term's coefficients, the chi^2 it removes, its marginal covariance, and the fit's
    parameters moved with it (a degenerate column of J and a dead column of B included)."""
    import numpy as np

    from fitlug.explain.families._solve import Projector

    rng = np.random.default_rng(3)
    n, k, m = 400, 6, 3
    J = rng.normal(size=(n, k)) * np.array([1e3, 1, 1e-2, 5, 1, 1])
    J[:, 5] = J[:, 4]  # a gauge direction
    B = rng.normal(size=(n, m))
    B[:, 2] = 0.0  # no datum at this coefficient
    B[:50] = 0.0
    valid = np.ones(n, bool)
    valid[::7] = False
    r0 = rng.normal(size=n)
    # r at the fit's minimum: r0 with its projection on J removed
    Jv = J[valid]
    r = r0.copy()
    r[valid] -= Jv @ np.linalg.lstsq(Jv, r0[valid], rcond=None)[0]
    A = np.hstack([Jv, B[valid][:, :2]])
    sol = np.linalg.lstsq(A, -r[valid], rcond=None)[0]
    dchi2 = float(r[valid] @ r[valid] - np.sum((r[valid] + A @ sol) ** 2))
    proj = Projector(J, r, valid)
    f = proj.fit(B, n_extra=1)
    np.testing.assert_allclose(f.c[:2], sol[k:], rtol=1e-8, atol=1e-12)
    assert f.c[2] == 0.0 and f.cov[2, 2] == 0.0
    assert f.dchi2 == pytest.approx(dchi2, rel=1e-9)
    assert proj.gain(B) == pytest.approx(dchi2, rel=1e-9)
    assert f.k == 4 and f.delta_bic == pytest.approx(-dchi2 + 4 * np.log(valid.sum()))
    cov = np.linalg.pinv(A.T @ A)[k:, k:]
    np.testing.assert_allclose(f.cov[:2, :2], cov, rtol=1e-7)
    moved = proj.moved(B, f.c)
    np.testing.assert_allclose((r + moved)[valid], r[valid] + A @ sol, atol=1e-9)


def test_the_headline_of_a_slip_term_has_the_joint_least_squares_variance():
    """extended()'s variance of s0 + h . c (a slip law in the speed moves the headline)
    against the inverse of the joint normal matrix [J B]'[J B] computed by numpy."""
    import numpy as np

    from fitlug.explain.families._extend import joint_variances
    from fitlug.explain.families._solve import Projector

    rng = np.random.default_rng(5)
    n, k, m = 300, 5, 2
    J = rng.normal(size=(n, k))
    B = 0.7 * J[:, :1] + rng.normal(size=(n, m))  # correlated with the fit's parameters
    valid = np.ones(n, bool)
    proj = Projector(J, np.zeros(n), valid)
    f = proj.fit(B)
    K = proj.solve(B)
    cov = np.linalg.inv(J.T @ J) + K @ f.cov @ K.T
    gs, h = rng.normal(size=k), np.array([1.0, 1.0])
    var_s, var_g, cov_sg = joint_variances(gs, cov, K, f.cov, h)
    full = np.linalg.inv(np.hstack([J, B]).T @ np.hstack([J, B]))
    w = np.r_[gs, h]
    assert var_s + var_g + 2 * cov_sg == pytest.approx(w @ full @ w, rel=1e-9)
    assert cov_sg == pytest.approx(gs @ full[:k, k:] @ h, rel=1e-9)


def test_the_posterior_draws_a_slip_term_beside_its_samples():
    """posterior._slip_term: the slip samples gain the term's change drawn from its
    Gaussian given each sample's steady slip: mean and variance of the sum as the joint
    Gaussian's (var_s + var_g + 2 cov), and the term's correlation with s0 kept."""
    import types

    import numpy as np

    from fitlug.posterior._sample import _slip_term

    rng = np.random.default_rng(7)
    s_hat, var_s, g, var_g, cov_sg = 0.04, 4e-10, 0.012, 9e-10, -3e-10
    s = s_hat + np.sqrt(var_s) * rng.standard_normal(200_000)
    res = types.SimpleNamespace(robust={"slip_term": {
        "value": g, "var": var_g, "cov_with_slip": cov_sg, "slip_var": var_s,
        "steady_slip": s_hat}})
    samples = {"slip": s.copy()}
    _slip_term(samples, res, np.random.default_rng(8))
    out = samples["slip"]
    assert np.mean(out) == pytest.approx(s_hat + g, abs=5 * np.sqrt(var_s + var_g) / 400)
    assert np.var(out) == pytest.approx(var_s + var_g + 2 * cov_sg, rel=0.02)
    assert np.cov(out - s, s)[0, 1] == pytest.approx(cov_sg, rel=0.05)
