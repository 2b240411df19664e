"""Near the friction limit (issue 32): lug_sliding at F0/F_max up to ~0.85, and a campaign
that keeps its most telling recordings.

The truth is the simulator's Janosi-Hanamoto law (MODEL.md §3, §4) on a light track
(k 0.0524 N/mm, F_max 5 and 6 N): each recording at a steady slip of 0.17, 0.27 and 0.40
must be explained by lug_sliding alone with its s_K, k, C_rr and slip covered, and the
campaign of them must flag none and recover k and F_max per ground.
"""

from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest

from fitlug.sim import Scenario
from fitlug.sim._campaign import (LIMIT_GROUNDS, LIMIT_K, SMALL_BASE, Run, campaign_scenarios,
                                  limit_runs, simulate_campaign)

G = 9.81
N_CONTACT, L_MM = 8, 127.0
MASS = 1.5
#: short recordings (4 s at 60 fps, 5 lug + 1 body markers): the explanation in seconds
BASE = SMALL_BASE.replace(duration_s=4.0, fps=60.0, travel_mm=400.0, ramp_s=0.8)


def _pull_for(s0, ground):
    """The drawbar pull that puts the steady slip of the sliding law at s0."""
    gr = LIMIT_GROUNDS[ground]
    s_K = 2 * gr["F_max"] / (LIMIT_K * N_CONTACT * L_MM)
    F0 = gr["F_max"] * (1 - math.exp(-s0 / s_K))
    return F0 - MASS * gr["C_rr"] * G


# the three loads, and a light run on the second ground (two recordings a ground:
# each ground's C_rr and F_max, and its recordings testable against the others)
RUNS = [Run("c_017", MASS, _pull_for(0.172, "concrete"), "concrete"),
        Run("c_027", MASS, _pull_for(0.268, "concrete"), "concrete"),
        Run("s_light", MASS, _pull_for(0.08, "sand"), "sand"),
        Run("s_040", MASS, _pull_for(0.396, "sand"), "sand")]


def _single(s0, seed=100):
    """One recording on concrete (F_max 5 N) at steady slip s0 under the sliding law."""
    from fitlug.sim import simulate

    gr = LIMIT_GROUNDS["concrete"]
    s_K = 2 * gr["F_max"] / (LIMIT_K * N_CONTACT * L_MM)
    F0 = gr["F_max"] * (1 - math.exp(-s0 / s_K))
    sc = BASE.replace(mass_kg=MASS, rolling_resistance=gr["C_rr"],
                      drawbar_pull_N=F0 - MASS * gr["C_rr"] * G,
                      slip=2 * F0 / (LIMIT_K * N_CONTACT * L_MM),
                      effects={"lug_sliding": {"slide_mu": 1 / s_K}})
    sc.check()
    rec, truth = simulate(sc, seed=seed)
    return sc, rec, truth, s_K


#: the loads of the single-recording test. 0.172 and 0.268 (F0/F_max 0.60, 0.76) pass too
#: (2026-11-27, ~215 s each on the loaded 2-core machine) and are asserted one by one in
#: test_a_campaign_at_the_friction_limit (c_017, c_027); the suite runs the new case alone
SINGLE_LOADS = (0.396,)


@pytest.mark.slow
@pytest.mark.parametrize("s0", SINGLE_LOADS)
def test_one_recording_near_the_limit_is_lug_sliding(s0):
    """A single recording at F0/F_max 0.88 (its ramp peaks at 0.97 F_max) is explained by
    lug_sliding alone, with s_K (so F_max), k, C_rr and the slip within 3 sigma of the
    simulator's truth: `unexplained` (chi^2/dof ~500) until the direct fit of
    explain._sliding_direct (the linear base fit bends its speed spline there, chi^2/dof
    ~400, and no start built on it reaches the law)."""
    from fitlug.explain import explain
    from fitlug.fit import fit
    from fitlug.sim import rig_of

    sc, rec, truth, s_K = _single(s0)
    ex = explain(fit(rec, rig_of(sc)))
    doc = ex.to_json()
    assert (ex.verdict, ex.effects) == ("explained", ["lug_sliding"]), doc["candidates"]
    assert ex.final.chi2_per_dof < 1.3
    e = doc["effects"][0]
    q = ex.final.quantities
    gr = LIMIT_GROUNDS["concrete"]
    for name, got, std, want in (
            ("s_K", e["params"]["s_K"], e["params_std"]["s_K"], s_K),
            ("slip", q["slip"].value, q["slip"].std, truth["slip"]),
            ("k", q["stiffness_N_per_mm"].value, q["stiffness_N_per_mm"].std, LIMIT_K),
            ("C_rr", q["rolling_resistance"].value, q["rolling_resistance"].std, gr["C_rr"])):
        assert abs(got - want) <= 3 * std, (name, got, std, want)


def test_a_ramp_past_the_friction_limit_is_refused():
    F_max, C_rr = 5.0, 0.06
    s_K = 2 * F_max / (LIMIT_K * N_CONTACT * L_MM)
    F_d = 0.92 * F_max - MASS * C_rr * G  # steady traction 0.92 F_max
    sc = Scenario(mass_kg=MASS, rolling_resistance=C_rr, drawbar_pull_N=F_d, ramp_s=0.6,
                  slip=2 * 0.92 * F_max / (LIMIT_K * N_CONTACT * L_MM),
                  effects={"lug_sliding": {"slide_mu": 1 / s_K}})
    # the cos ramp's largest acceleration is v pi / (2 T): F peaks at F0 + m a_max / 1000
    v = sc.travel_mm / (sc.duration_s - 2 * sc.rest_s - sc.ramp_s)
    peak = (0.92 * F_max + MASS * v * math.pi / (2 * sc.ramp_s) / 1000) / F_max
    assert peak > 1.0
    assert sc.peak_friction_ratio() == pytest.approx(peak, rel=1e-4)
    with pytest.raises(ValueError, match="lug_sliding.*F_max"):
        sc.check()
    gentle = sc.replace(ramp_s=1.6)  # the same load with a gentler start: below the limit
    assert sc.peak_friction_ratio() > gentle.peak_friction_ratio() > 0.92
    gentle.check()


def test_the_limit_campaign_reaches_the_limit_without_spinning():
    runs = limit_runs(8, grounds=LIMIT_GROUNDS, masses=(MASS,))
    scen = campaign_scenarios(runs, k=LIMIT_K, grounds=LIMIT_GROUNDS, law="janosi_hanamoto",
                              base=SMALL_BASE)
    ratios = {}
    for run, sc in scen:
        sc.check()
        gr = LIMIT_GROUNDS[run.ground]
        F0 = MASS * gr["C_rr"] * G + run.drawbar_pull_N
        ratios.setdefault(run.ground, []).append(F0 / gr["F_max"])
        assert sc.peak_friction_ratio() < 1.0
    for g, r in ratios.items():
        assert max(r) > 0.8 and min(r) < 0.35, (g, r)


@pytest.mark.slow
@pytest.mark.bench  # deselected by default (CI time, issue 43 item 6): pytest -m bench
def test_a_campaign_at_the_friction_limit(tmp_path):
    """Four recordings explained in full (~2 CPU minutes): fails on the code before issue
    32 (c_027 and s_040 came out `unexplained`, and were flagged). Marked `bench`: the
    default run keeps test_one_recording_near_the_limit_is_lug_sliding;
    `python3 -m pytest -m bench tests/test_friction_limit.py` runs this one."""
    from fitlug.campaign import campaign

    data = tmp_path / "data"
    truth = simulate_campaign(data, runs=RUNS, k=LIMIT_K, grounds=LIMIT_GROUNDS,
                              law="janosi_hanamoto", base=BASE, seed=5)
    res = campaign([str(data)], out=str(tmp_path / "fits"), workers=0, mcmc=False,
                   report=False, campaign_budget_s=60.0)
    assert not res.failed
    for rec in truth["recordings"]:
        with open(tmp_path / "fits" / rec["name"] / "fit.json") as fh:
            doc = json.load(fh)
        tr = json.loads((data / rec["name"] / "truth.json").read_text())
        disc = doc["discrepancy"]
        if rec["slip"] < 0.15:
            continue  # light loads: the law is nearly linear there (not this issue)
        # explained by lug_sliding alone, with chi^2/dof ~ 1
        assert (disc["verdict"], [e["id"] for e in disc["effects"]]) == (
            "explained", ["lug_sliding"]), (rec["name"], disc["candidates"])
        assert doc["chi2_per_dof"] < 1.3
        s_K_true = 1.0 / tr["effects"]["lug_sliding"]["slide_mu"]
        e = disc["effects"][0]
        for got, std, want in ((e["params"]["s_K"], e["params_std"]["s_K"], s_K_true),
                               (doc["slip"]["value"], doc["slip"]["std"], rec["slip"]),
                               (doc["stiffness_N_per_mm"]["value"],
                                doc["stiffness_N_per_mm"]["std"], LIMIT_K),
                               (doc["rolling_resistance"]["value"],
                                doc["rolling_resistance"]["std"],
                                LIMIT_GROUNDS[rec["ground"]]["C_rr"])):
            assert abs(got - want) <= 3.5 * std, (rec["name"], got, std, want)
    # the campaign: the sliding law, none of its own recordings flagged, k and F_max covered
    assert res.law == "janosi_hanamoto"
    assert res.flagged == []
    k = res.stiffness
    assert abs(k["value"] - LIMIT_K) <= 3 * k["std"], k
    for g, e in res.F_max.items():
        assert abs(e["value"] - LIMIT_GROUNDS[g]["F_max"]) <= 3 * e["std"], (g, e)
    for g, e in res.rolling_resistance.items():
        assert abs(e["value"] - LIMIT_GROUNDS[g]["C_rr"]) <= 3 * e["std"], (g, e)
    doc = json.loads((tmp_path / "fits" / "campaign.json").read_text())
    assert all(r["verdict"] == "explained" for r in doc["recordings"]
               if r["name"] in ("c_017", "c_027", "s_040"))


def test_the_direct_grid_is_the_sliding_law_at_its_steady_slip_and_peak():
    """Each row of explain._sliding_direct's grid, put into the model's own slip law
    (fitlug.model.slip_law under lug_sliding), keeps the steady slip S, reaches F/F_max =
    z_pk at the largest acceleration, and its F_max (MODEL.md: mu beta = m / (1000 F_max))
    is m a_max / (1000 (z_pk - z0)): above the largest traction, z_pk F_max."""
    from types import SimpleNamespace

    import jax.numpy as jnp

    from fitlug.explain._sliding_direct import Z0_GRID, Z_PEAK_MAX, _grid
    from fitlug.model import slip_law

    lay = SimpleNamespace(effects=("lug_sliding",))
    S, a_max, m = 0.396, 304.0, 1.5
    rows = _grid(Z0_GRID, S, a_max, 7)
    assert len(rows) == 7 * len(Z0_GRID)
    for z0, z_pk, s0, beta, mu in rows:
        p = {"s0": s0, "beta": beta, "slide_mu": mu}
        assert float(slip_law(p, lay, jnp.asarray(0.0))) == pytest.approx(S, rel=1e-12)
        assert mu * (s0 + beta * a_max) == pytest.approx(z_pk, rel=1e-12)
        assert z0 < z_pk <= Z_PEAK_MAX + 1e-12
        F_max = m / (1000.0 * mu * beta)
        assert F_max == pytest.approx(m * a_max / (1000.0 * (z_pk - z0)), rel=1e-12)
        # the slip at the peak is the Janosi-Hanamoto law's -s_K ln(1 - z_pk)
        assert float(slip_law(p, lay, jnp.asarray(a_max))) == pytest.approx(
            -math.log1p(-z_pk) / mu, rel=1e-9)


def test_the_law_past_the_friction_limit_is_finite_and_rising():
    """log_ratio: -ln(1 - z)/z to 1e-12 below Z_SMOOTH (and its derivative, by finite
    differences), then finite, increasing, continuous at Z_SMOOTH."""
    import jax
    import jax.numpy as jnp

    from fitlug.model.effects._lug_sliding import Z_SMOOTH, log_ratio

    z = np.array([-0.5, 1e-6, 0.3, 0.9, 0.99, Z_SMOOTH - 1e-9])
    assert np.allclose(np.asarray(log_ratio(jnp.asarray(z))), -np.log1p(-z) / z, rtol=1e-9)
    h = 1e-7
    d = np.asarray(jax.vmap(jax.grad(log_ratio))(jnp.asarray(z[2:5])))
    fd = (-np.log1p(-(z[2:5] + h)) / (z[2:5] + h) + np.log1p(-(z[2:5] - h)) / (z[2:5] - h)) / (2 * h)
    assert np.allclose(d, fd, rtol=1e-5)
    past = np.asarray(log_ratio(jnp.asarray([Z_SMOOTH + 1e-9, 1.0, 1.05, 1.5])))
    assert np.all(np.isfinite(past)) and np.all(np.diff(past * [Z_SMOOTH, 1.0, 1.05, 1.5]) > 0)
    below = float(log_ratio(jnp.asarray(Z_SMOOTH - 1e-9)))
    assert past[0] == pytest.approx(below, rel=1e-5)
    g = np.asarray(jax.vmap(jax.grad(log_ratio))(jnp.asarray([1.0, 1.05])))
    assert np.all(np.isfinite(g)) and np.all(g > 0)
