"""The body surging on its lugs (MODEL.md §2, real tracks; explain.families._surge).

Truth from the contact-dynamics engine (MuJoCo, data/engine: a 10 kg chassis on 22
sprung lugs, its surge measured by the engine in truth.json) and from the recording's own
body markers read without the model (their x about a straight line over the engine's
cruise), and the term's columns against finite differences of the model itself."""

from __future__ import annotations

import json
import os

import jax.numpy as jnp
import numpy as np
import pytest

import fitlug
from fitlug.explain.families._base import bspline
from fitlug.explain.families._context import context
from fitlug.explain.families._surge import _carried, _columns
from fitlug.fit._residuals import _weighted
from fitlug.model import integrate, positions
from fitlug.model._model import sampled_from_nodes

ENGINE = os.path.join(os.path.dirname(__file__), "..", "data", "engine", "ref_100fps")


@pytest.fixture(scope="module")
def explained():
    rec = fitlug.read_trajectories(os.path.join(ENGINE, "trajectories.csv"))
    rig = fitlug.read_rig(os.path.join(ENGINE, "rig.toml"))
    with open(os.path.join(ENGINE, "truth.json")) as f:
        truth = json.load(f)
    return fitlug.explain(fitlug.fit(rec, rig)), truth, rec


def _body_x_about_its_line(rec, window):
    """Peak-to-peak (mm) of each body marker's x about its least-squares line over the
    window, the largest: what the body does beyond a steady cruise, read off the data."""
    out = 0.0
    for i, role in enumerate(rec.roles):
        if role != "body":
            continue
        sel = rec.marker_index == i
        t, x = rec.t[sel], rec.x[sel]
        w = (t > window[0]) & (t < window[1]) & np.isfinite(x)
        r = x[w] - np.polyval(np.polyfit(t[w], x[w], 1), t[w])
        out = max(out, float(np.ptp(r)))
    return out


def test_the_body_surge_is_named_and_modelled_on_an_engine_recording(explained):
    """The engine's chassis surges on its lugs' springs; the explanation names it, models
    it (a family term the fit improves by a third of its excess and more), claims no
    camera or clock, and the slip stays the belt clock's, within 3 sigma of the engine's."""
    ex, truth, rec = explained
    d = ex.to_json()
    assert d["verdict"] == "unexplained"
    terms = d["discovered"]
    fams = [t["family"] for t in terms]
    assert "body surge" in fams
    assert not {"image map", "time map"} & set(fams)
    t = terms[fams.index("body surge")]
    before, after = t["chi2_per_dof_before"], t["chi2_per_dof_after"]
    assert after < before - 0.3 * (before - 1.0), (before, after)
    assert t["partial"] and "surges fore and aft on its lugs" in t["reading"]
    # its size is the body's own beyond a steady cruise (0.5x-2x), its frequency the
    # engine's surge band (the engine's measured 0.86 Hz, sqrt(n k / m) / 2 pi = 2.2 Hz)
    ptp = _body_x_about_its_line(rec, truth["cruise_window_s"])
    assert 0.5 * ptp < t["params"]["peak_to_peak_mm"] < 2.0 * ptp, (t["params"], ptp)
    f = t["params"]["frequency_hz"]
    assert 0.5 * truth["surge_frequency_hz"] < f < 2.0 * truth["surge_estimate_hz"], f
    s = ex.final.quantities["slip"]
    assert ex.final.robust["headline"] == "straight runs"
    # the lug-passing frequency the located lines are named by is the cruise's (the engine
    # measures it: belt speed over pitch), not that of the chain's overshoot after its ramp
    f_lug = d["spectra"]["before"]["lug_passing_hz"]
    assert abs(f_lug / truth["lug_passing_hz"] - 1.0) < 0.05, (f_lug, truth["lug_passing_hz"])
    assert abs(s.value - truth["slip"]) < 3.0 * s.std


def test_the_surge_columns_are_the_models_own_derivative(explained):
    """The term's columns (the body, the lugs it carries, and the tips that hold while the
    lug's shear takes the surge up, relaxing after lift-off) equal central differences of
    the model with X shifted by Delta(t) at the integration's nodes and psi kept."""
    ex, _, _ = explained
    res = ex.final
    assert "shear_h" in res.params  # the marker on the lug is in this model
    ctx = context(res, np.zeros((len(res.residuals), 1)))
    body = (ctx.role == 1) & (ctx.axis == 0) & ctx.valid
    lo, hi = float(ctx.t[body].min()), float(ctx.t[body].max())
    n_int = 20
    B = _columns(ctx, _carried(ctx), lo, hi, n_int)
    c = np.random.default_rng(5).standard_normal(B.shape[1])
    prob = res.problem
    p = {k: jnp.asarray(v, float) for k, v in res.params.items()}
    X, psi, vn, dpn = (np.asarray(a) for a in integrate(p, prob.lay))
    g = np.asarray(prob.lay.grid)
    dl = bspline(g, lo, hi, n_int) @ c
    ddl = (bspline(g + 1e-5, lo, hi, n_int) - bspline(g - 1e-5, lo, hi, n_int)) @ c / 2e-5

    def r(eps):
        nodes = (jnp.asarray(X + eps * dl), jnp.asarray(psi), jnp.asarray(vn + eps * ddl),
                 jnp.asarray(dpn))
        return np.asarray(_weighted(positions(p, prob.lay,
                                              *sampled_from_nodes(p, prob.lay, nodes)),
                                    prob.obs))

    eps = 1e-3
    fd = (r(eps) - r(-eps)) / (2 * eps)
    lin = B @ c
    v = ctx.valid
    assert np.max(np.abs(lin[v] - fd[v])) < 3e-4 * np.max(np.abs(fd[v]))
    # the tips' share is in it: the lugs carried whole would differ by far more
    whole = np.where(v, ctx.dr_dX * (bspline(ctx.t, lo, hi, n_int) @ c), 0.0)
    assert np.max(np.abs(whole[v] - fd[v])) > 0.1 * np.max(np.abs(fd[v]))
