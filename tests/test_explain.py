"""fitlug.explain: detection, location, candidate fits and the report section.

Truth the code did not produce: residuals drawn from known distributions (white noise,
injected sinusoids, steps), and recordings simulated with known effects.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from fitlug.explain import Geometry, detect, locate
from fitlug.explain._table import lag_products, structured_misfit

FPS = 100.0


def _geometry(n_frames=650, n_lug=4, n_body=2, sigma=0.0065, seed=0) -> Geometry:
    """A recording's bookkeeping without a fit: lug markers cycle through the 4 segments."""
    t1 = np.arange(n_frames) / FPS
    markers = tuple([f"B{i + 1:02d}" for i in range(n_lug)] + [f"C{j + 1}" for j in range(n_body)])
    roles = tuple(["lug"] * n_lug + ["body"] * n_body)
    t, mk, ax = [], [], []
    for m in range(n_lug + n_body):
        for a in (0, 1):
            t.append(t1)
            mk.append(np.full(n_frames, m))
            ax.append(np.full(n_frames, a))
    t, mk, ax = np.concatenate(t), np.concatenate(mk), np.concatenate(ax)
    role = (mk >= n_lug).astype(int)
    # a belt period of 2.3 s split into the 4 segments, each marker with its own phase
    period = 2.3
    u = np.mod(t / period + mk * 0.27, 1.0)
    seg = np.select([u < 0.35, u < 0.5, u < 0.85], [0, 1, 2], 3)
    seg = np.where(role == 1, 4, seg)
    # rest, accelerate, cruise, decelerate, rest
    phase = np.select([t < 0.5, t < 2.5, t < 4.5, t < 6.0], [0, 1, 2, 3], 0)
    v = np.interp(t, [0, 0.5, 2.5, 4.5, 6.0, 7.0], [0, 0, 160, 160, 0, 0])
    psi = np.cumsum(np.full(len(t), 1.0))  # not used by these tests
    series = mk * 2 + ax
    order = np.lexsort((t, series))
    so, to = series[order], t[order]
    same = (so[1:] == so[:-1]) & (np.abs(np.diff(to) - 1 / FPS) < 0.5 / FPS)
    return Geometry(t=t, marker=mk, role=role, axis=ax, segment=seg, phase=phase, psi=psi, v=v,
                    valid=np.ones(len(t), bool), series=series,
                    weight=np.full(len(t), 1 / sigma), pair_a=order[:-1][same],
                    pair_b=order[1:][same], markers=markers, roles=roles, fps=FPS,
                    v_cruise=160.0, vt_cruise=173.0, pitch=18.36, R=25.0, t_lo=0.0,
                    t_hi=float(t1[-1]))


GEO = _geometry()
N = len(GEO.t)


def test_structured_misfit_is_unbiased_for_white_noise_and_counts_a_smooth_misfit():
    rng = np.random.default_rng(1)
    Ms = [structured_misfit(GEO, rng.normal(size=N))[0] for _ in range(200)]
    sd = structured_misfit(GEO, np.ones(N))[1]
    assert abs(np.mean(Ms)) < 4 * sd / math.sqrt(200)
    assert 0.8 * sd < np.std(Ms) < 1.2 * sd
    # a 1 Hz misfit of amplitude 0.5 sigma carries sum m^2 = N/8 of chi^2
    m = 0.5 * np.sin(2 * np.pi * 1.0 * GEO.t)
    M = np.mean([structured_misfit(GEO, m + rng.normal(size=N))[0] for _ in range(20)])
    assert M == pytest.approx(np.sum(m * m), rel=0.05)
    # per-sample shares add up to the total
    r = m + rng.normal(size=N)
    assert lag_products(GEO, r).sum() == pytest.approx(structured_misfit(GEO, r)[0])


def test_detect_false_alarm_rate_on_white_noise_is_at_most_alpha():
    """Seeded check of the false-alarm rate: 300 white-noise residual sets, sigma re-estimated."""
    rng = np.random.default_rng(2)
    alarms = 0
    for _ in range(300):
        r = rng.normal(size=N)
        alarms += not detect(GEO, r, N - 60).consistent
    # alpha = 0.05; with 300 draws a rate of 5 % gives at most 25 alarms 99 % of the time
    assert alarms <= 25


@pytest.mark.parametrize("kind", ["sinusoid", "step_one_series", "excess_chi2"])
def test_detect_finds_misfit(kind):
    rng = np.random.default_rng(3)
    r = rng.normal(size=N)
    if kind == "sinusoid":  # 0.2 sigma at 9.6 Hz in every x series: chi^2 + 0.6 %
        r += np.where(GEO.axis == 0, 0.2 * np.sin(2 * np.pi * 9.6 * GEO.t), 0.0)
    elif kind == "step_one_series":  # one marker's x jumps by 0.5 sigma
        r += np.where((GEO.series == 2) & (GEO.t > 3.0), 0.5, 0.0)
    else:  # noise 10 % larger than assumed, but white: only the chi^2 test sees it
        r *= 1.1
    det = detect(GEO, r, N - 60, sigma_estimated=False)
    assert not det.consistent
    if kind == "excess_chi2":
        assert det.chi2_p < 1e-6 and det.ljung_box_p > 1e-3
    if kind == "sinusoid":
        assert det.line_hz == pytest.approx(9.6, abs=0.2) and det.line_group in ("lug.x", "body.x")


def test_locate_names_the_marker_axis_segment_and_phase():
    rng = np.random.default_rng(4)
    r = rng.normal(size=N)
    # misfit: marker B01, y, top run (1.15-1.96 s), while accelerating, 2 sigma offset
    cell = (GEO.marker == 0) & (GEO.axis == 1) & (GEO.segment == 2) & (GEO.phase == 1)
    assert cell.sum() > 50
    r = r + np.where(cell, 2.0, 0.0)
    loc = locate(GEO, r)
    top = loc.parts[0]
    assert top["markers"] == ["B01"]
    assert (top["axis"], top["segment"], top["phase"]) == ("y", "top", "accelerate")
    assert top["share_of_misfit"] > 0.8
    assert 1.1 <= top["t_range_s"][0] < top["t_range_s"][1] <= 2.0
    assert loc.breakdown["marker"]["B01"]["share"] > 0.9
    assert loc.breakdown["phase"]["accelerate"]["share"] > 0.9


def test_locate_reports_the_frequency_of_a_periodic_misfit():
    rng = np.random.default_rng(5)
    r = rng.normal(size=N) + np.where(GEO.role == 1, 0.6 * np.sin(2 * np.pi * 3.3 * GEO.t), 0)
    loc = locate(GEO, r)
    body = [p for p in loc.parts if p["segment"] == "body"]
    assert body and all(abs(p["frequency_hz"] - 3.3) < 0.1 for p in body)
    assert sorted(body[0]["markers"]) == ["C1", "C2"]
    assert loc.breakdown["frequency"]["peak_hz"] == pytest.approx(3.3, abs=0.1)


def test_white_noise_is_located_nowhere():
    r = np.random.default_rng(6).normal(size=N)
    assert locate(GEO, r).parts == []


# ---- end to end on a short simulated recording -------------------------------------------

DATA_MD_LOCATED = {"markers", "axis", "segment", "phase", "frequency_hz", "t_range_s",
                   "share_of_misfit"}
DATA_MD_EFFECT = {"id", "params", "delta_bic", "chi2_per_dof_before", "chi2_per_dof_after"}


@pytest.fixture(scope="module")
def frame_drop_explained():
    from fitlug.explain import explain
    from fitlug.fit import fit
    from fitlug.sim import Scenario, rig_of, simulate

    sc = Scenario(duration_s=3.5, travel_mm=300.0, rest_s=0.3, ramp_s=0.8,
                  effects={"frame_drop": {"drop_dt": 0.01, "drop_tstar": 1.83}})
    rec, truth = simulate(sc, 11)
    return explain(fit(rec, rig_of(sc))), truth


def test_a_lost_frame_is_found_where_it_happened(frame_drop_explained):
    ex, truth = frame_drop_explained
    assert ex.verdict == "explained" and ex.effects == ["frame_drop"]
    p = ex.final.effect_params("frame_drop")
    assert p["t_star_s"] == pytest.approx(1.83, abs=1e-9)  # the first frame stamped early
    assert p["dt_s"] == pytest.approx(0.01, rel=0.03)
    s = ex.final.slip
    assert abs(s.value - truth["slip"]) < 3 * s.std
    assert ex.base.chi2_per_dof > 2 and ex.final.chi2_per_dof < 1.1
    # located: every marker jumps in x at t*, so the parts are in x around 1.83 s
    top = ex.located[0]
    assert top["axis"] == "x" and top["t_range_s"][0] <= 1.83 <= top["t_range_s"][1] + 0.05


def test_the_discrepancy_block_follows_data_md(frame_drop_explained):
    import json

    ex, _ = frame_drop_explained
    doc = json.loads(json.dumps(ex.to_json()))  # plain JSON types only
    assert doc["verdict"] in ("none", "explained", "unexplained")
    assert doc["located"] and all(DATA_MD_LOCATED <= set(p) for p in doc["located"])
    for p in doc["located"]:
        assert p["axis"] in ("x", "y")
        assert p["segment"] in ("bottom", "rear_arc", "top", "front_arc", "body")
        assert p["phase"] in ("accelerate", "cruise", "decelerate", "all")
        if "test" in p:  # a spectral line or one series: not a share of the cells'
            assert p["share_of_misfit"] is None and 0 <= p["share_of_excess_chi2"] <= 1
        else:
            assert 0 <= p["share_of_misfit"] <= 1
    cells = [p["share_of_misfit"] for p in doc["located"] if "test" not in p]
    assert sum(cells) <= 1 + 1e-9  # the located table's shares add up
    assert all(DATA_MD_EFFECT <= set(e) for e in doc["effects"])
    assert doc["effects"][0]["delta_bic"] < -10
    for key in ("slip_before", "slip_after"):
        assert set(doc[key]) == {"value", "std", "ci95"}


def test_the_report_section_shows_before_and_after(frame_drop_explained):
    from fitlug.report._section_discrepancy import discrepancy_section

    ex, _ = frame_drop_explained
    html = discrepancy_section({"discrepancy": ex.to_json()}, None)
    assert "What the model left out" in html and "frame_drop" in html
    assert html.count("data:image/png;base64,") == 3  # maps, breakdown, spectra
    assert discrepancy_section({}, None) == ""


def test_the_reports_early_parts_do_not_read_the_posterior(frame_drop_explained, tmp_path):
    """fitlug.report._aside draws the page's EARLY parts (the discrepancy's figures among
    them) from fit.json and state.npz made before the posterior: they must be the same
    HTML as drawn from the final files, which carry the posterior's estimates."""
    from fitlug.io import read_json, write_json
    from fitlug.posterior import sample_posterior
    from fitlug.report import fit_json, load_state
    from fitlug.report._page import EARLY, early_parts
    from fitlug.report._state import state_arrays, write_state

    ex, _ = frame_drop_explained
    disc = ex.to_json()
    post = sample_posterior(ex.final, seed=0)
    docs = {"before": fit_json(ex.final, discrepancy=disc),
            "after": fit_json(ex.final, discrepancy=disc, posterior=post.estimates,
                              not_identifiable=post.not_identifiable,
                              uncertainty_method=post.uncertainty_method,
                              mcmc=post.mcmc_json())}
    assert docs["before"]["slip"] != docs["after"]["slip"]  # the posterior moved them
    parts = {}
    for key, posterior in (("before", None), ("after", post)):
        d = tmp_path / key
        d.mkdir()
        write_json(d / "fit.json", docs[key])
        write_state(d, *state_arrays(ex.final, posterior, ex))
        parts[key] = early_parts(read_json(d / "fit.json"), load_state(d))
    assert set(parts["before"]) == set(EARLY)
    assert parts["before"] == parts["after"]
    # residuals before/after, maps, breakdown, spectra
    assert parts["before"]["discrepancy-plots"].count("data:image/png;base64,") == 4


def test_engine_keeps_analytic_columns_only_where_every_effect_is_at_identity():
    """The search's first-round Jacobian keeps the starting model's analytic columns of the
    coupled scalars (s0, beta, R, ...): valid because with every catalog effect at its
    identity value the all-effects model is the starting model. Checked against central
    differences of the all-effects model, which the engine uses once an effect moves."""
    from fitlug.explain._engine import COUPLED, Engine
    from fitlug.fit import fit
    from fitlug.sim import Scenario, rig_of, simulate

    sc = Scenario(duration_s=3.0, travel_mm=250.0, rest_s=0.3, ramp_s=0.8)
    rec, _ = simulate(sc, 5)
    eng = Engine(fit(rec, rig_of(sc)))
    theta = eng.theta0
    assert not eng.effects_active(theta)
    coupled = [k for k in COUPLED if k in eng.cur_packing.names]
    assert len(coupled) >= 5
    Jb = np.asarray(eng.base_jacobian(theta))
    F = eng.fd_columns([({}, k) for k in coupled], theta)
    for i, k in enumerate(coupled):
        a = Jb[:, eng.cur_positions[k]]
        assert np.linalg.norm(a - F[:, i]) <= 1e-5 * np.linalg.norm(a), k
    J = eng.jacobian(theta, [])
    assert np.array_equal(J, Jb)  # nothing replaced
    moved = eng.with_values(theta, {"sag_d": 0.2})
    assert eng.effects_active(moved)
    J2 = eng.jacobian(moved, [])
    # the belt sag moves the top run's y: the differenced columns are the all-effects model's
    assert not np.allclose(J2[:, eng.cur_positions["R"]], Jb[:, eng.cur_positions["R"]])


def test_entries_whose_final_fit_stops_worse_than_the_base_are_withdrawn():
    """An engine's rubber belt seen through heavy occlusions (benchmarks/
    make_engine_variants.py, `occldt`): the search accepted lug_sliding at s_K 1e-11 on a
    misfit it measured in other units, and the exact final fit with it stopped unconverged
    at chi2/dof 75 000 for the base model's 8 000, which the user saw as the model 'after'.
    Such entries are withdrawn (the round says why) and the base model stands."""
    from types import SimpleNamespace as NS

    from fitlug.explain._final import withdrawn

    base = NS(chi2_per_dof=8040.7)
    rounds = [{"round": 1, "accepted": "lug_sliding"}, {"round": 2}]
    assert withdrawn(base, NS(converged=False, chi2_per_dof=75211.2), ["lug_sliding"], rounds)
    assert "accepted" not in rounds[0] and rounds[0]["withdrawn"].startswith("lug_sliding:")
    assert "75211" in rounds[0]["withdrawn"] and "8041" in rounds[0]["withdrawn"]
    assert rounds[1] == {"round": 2}
    for final in (NS(converged=True, chi2_per_dof=75211.2),    # converged: its own answer
                  NS(converged=False, chi2_per_dof=5000.0)):  # stopped short, but better
        keep = [{"round": 1, "accepted": "lug_sliding"}]
        assert not withdrawn(base, final, ["lug_sliding"], keep)
        assert keep == [{"round": 1, "accepted": "lug_sliding"}]
