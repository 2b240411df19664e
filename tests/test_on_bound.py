"""A fit whose slip slope beta ends on its lower bound: its refits start there.

fitlug.fit refits a recording after its first fit (the lug count, the glitch rounds, the
noise from the residuals). Where the first fit's beta sat on its bound (beta = 0, k
infinite), each refit walked the free solver back below the bound (up to 300 steps at a
gross misfit) and then refitted with beta held there (fitlug.fit._on_bound), and so did
the first fit after its stage with beta held. The refits now start held, and the first
fit keeps its held stage, where the data still pull beta below the bound (the bound's
Karush-Kuhn-Tucker condition). Checked on a recording made by a contact-
dynamics engine (MuJoCo; nothing of fitlug's model), against the old route and against
finite differences of chi^2.
"""

from __future__ import annotations

import os

import jax.numpy as jnp
import numpy as np
import pytest

import fitlug
import fitlug.fit._fit as fit_mod
from fitlug.fit import residuals

ENGINE = os.path.join(os.path.dirname(__file__), "..", "data", "engine")


def _recording(name):
    d = os.path.join(ENGINE, name)
    rig = fitlug.read_rig(os.path.join(d, "rig.toml"))
    return fitlug.read_trajectories(os.path.join(d, "trajectories.csv"), rig=rig), rig


def _chi2(res, **change):
    p = {k: jnp.asarray(v) for k, v in res.params.items()}
    p.update({k: jnp.asarray(v, float) for k, v in change.items()})
    r = np.asarray(residuals(p, res.problem.lay, res.problem.obs))
    return float(r @ r)


def test_refits_from_the_bound_reach_the_free_solvers_minimum_in_fewer_steps(monkeypatch):
    """The engine's robot driving through a 400 mm window (data/engine/drive_through: a
    gross misfit, chi^2/dof ~3 000, the data pulling beta below 0): the first fit's stage
    with beta held is its answer, and the refits started on the bound end there too, where
    the old route (free walks, each followed by a held refit) ended: the same
    chi^2 and slip, in fewer solver steps; and at the reported point no step of beta into
    its range lowers chi^2 (finite differences, the other parameters where they are)."""
    rec, rig = _recording("drive_through")
    calls = []
    real = fit_mod.refit_on_bound

    def counting(*a, **k):
        out = real(*a, **k)
        calls.append(out is not None)
        return out

    first = []
    real_holds = fit_mod.bound_holds

    def holds(held):
        out = real_holds(held)
        first.append(out)
        return out

    monkeypatch.setattr(fit_mod, "refit_on_bound", counting)
    monkeypatch.setattr(fit_mod, "bound_holds", holds)
    new = fitlug.fit(rec, rig)
    assert first == [True]  # the first fit's held stage is its answer
    assert calls and all(calls), calls  # every refit started on the bound and stayed
    monkeypatch.setattr(fit_mod, "refit_on_bound", lambda *a, **k: None)
    monkeypatch.setattr(fit_mod, "bound_holds", lambda held: False)
    old = fitlug.fit(rec, rig)

    for res in (new, old):
        assert res.converged and float(np.ravel(res.params["beta"])[0]) == 0.0
        assert "beta" in res.packing.names  # free, on its bound: it has its covariance
        assert _chi2(res) == pytest.approx(res.chi2, rel=1e-9)  # its own residuals
    assert new.chi2 == pytest.approx(old.chi2, rel=1e-9)
    s_new, s_old = (float(np.ravel(r.params["s0"])[0]) for r in (new, old))
    i = new.packing.slices()["s0"].start
    assert abs(s_new - s_old) < 1e-3 * np.sqrt(new.cov[i, i])
    assert new.steps < old.steps
    # the bound's KKT condition by finite differences: chi^2 rises as beta enters its range
    b_scale = 1e-6
    assert _chi2(new, beta=b_scale) > new.chi2
    assert _chi2(new, beta=2 * b_scale) > _chi2(new, beta=b_scale)


def test_a_refit_whose_data_pull_beta_into_its_range_frees_it():
    """Where the held refit's chi^2 falls as beta enters its range, the held fit is not
    the constrained minimum: refit_on_bound declines it (the caller then frees beta).
    The reference recording's beta is well inside its range (k = 0.25 N/mm): started on
    the bound, the held fit's gradient points into the range."""
    from fitlug.fit import build_problem, fit_problem
    from fitlug.fit._on_bound import on_lower_bound, refit_on_bound

    root = os.path.join(os.path.dirname(__file__), "..", "data", "reference")
    prob = build_problem(os.path.join(root, "trajectories.csv"), os.path.join(root, "rig.toml"))
    res = fit_problem(prob)
    free = list(res.packing.names)
    start = {**res.params, "beta": np.zeros_like(np.asarray(res.params["beta"]))}
    assert on_lower_bound(start, free) and not on_lower_bound(res.params, free)
    assert refit_on_bound(start, free, prob.lay, prob.obs, max_steps=300) is None
    # and by finite differences at the fit: chi^2 is lowest inside the range
    b = float(np.ravel(res.params["beta"])[0])
    assert b > 0 and _chi2(res, beta=0.0) > res.chi2
