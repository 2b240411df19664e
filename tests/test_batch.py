"""fitlug.fit_many (issue 27, item 8): recordings of one rig that differ in length, sample
count and knot count are fitted with one compiled solver; each result is the recording's
own fit (truth: the simulator's slip; and the one-by-one fit within a small fraction of
its error, measured by benchmarks/bench_batch.py, which fits both ways)."""

from __future__ import annotations

import numpy as np

from fitlug import _exported
from fitlug.fit import fit_many
from fitlug.sim import Scenario, rig_of, simulate

SC = Scenario(duration_s=1.5, travel_mm=150, rest_s=0.2, ramp_s=0.4)  # test_predict's


def test_fit_many_compiles_once_and_gives_each_recordings_fit(monkeypatch):
    scs = [SC, Scenario(duration_s=1.8, travel_mm=170, rest_s=0.2, ramp_s=0.5)]
    drawn = [simulate(sc, 5 + i) for i, sc in enumerate(scs)]
    recs = [r for r, _ in drawn]
    assert len(recs[0].t) != len(recs[1].t)
    keys = []
    real = _exported.call

    def spy(name, fn, static, *args):
        if name == "lsq_solve":
            import jax

            leaves = jax.tree_util.tree_leaves(args)
            keys.append((repr(static), tuple(np.shape(x) for x in leaves)))
        return real(name, fn, static, *args)

    monkeypatch.setattr(_exported, "call", spy)
    many = fit_many(recs, rig_of(SC))
    monkeypatch.setattr(_exported, "call", real)
    # every solve of the batch (start, noise refit, glitch rounds) is one program
    assert len(keys) >= 4 and len(set(keys)) <= 2  # with beta held first, and free
    for (rec, truth), res in zip(drawn, many):
        s = res.slip
        assert abs(s.value - truth["slip"]) < 4 * s.std
        assert res.residuals.shape == (2 * (len(res.problem.lug_rows)
                                            + len(res.problem.body_rows)),)
        assert res.problem.rec is rec and 0.8 < res.chi2_per_dof < 1.25
    # (against the one-by-one fits: benchmarks/bench_batch.py, 0.02 standard errors)
    # the result is a whole FitResult: the model as a function works on it
    pr = many[1].predict([0.6, 0.9], markers="C1")
    rec = recs[1]
    sel = rec.marker_index == list(rec.markers).index("C1")
    assert np.allclose(pr.x[0], np.interp([0.6, 0.9], rec.t[sel], rec.x[sel]), atol=0.2)
