"""Issue 43, item 2: shapes in buckets. The programs on bucketed shapes (weightless samples,
unread parameters and grid nodes added: fitlug.fit._buckets) give the unpadded ones'
numbers to 1e-10, a fit lands within its solver's tolerance of the unpadded fit, and a
recording of a new length in a bucket already seen compiles nothing."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np

from fitlug.model._buckets import bucket
from fitlug.sim import Scenario, rig_of, simulate

SHORT = dict(travel_mm=150, rest_s=0.2, ramp_s=0.4)


def test_buckets_are_few_and_at_most_a_quarter_larger():
    sizes = [bucket(n) for n in range(1, 20001)]
    assert all(b >= n for n, b in zip(range(1, 20001), sizes))
    assert all(b <= 1.25 * n for n, b in zip(range(4, 20001), sizes[3:]))
    assert np.all(np.diff(sizes) >= 0)
    for k in range(15):  # at most four sizes per octave
        assert len({b for b in sizes if 2 ** k <= b < 2 ** (k + 1)}) <= 4


def _marginal(res):
    from fitlug.posterior._marginal import _Marginal, slip_law_parameters

    marg = _Marginal(res, slip_law_parameters(res), batch=4)
    pts = marg.theta_hat + np.array([[0.0, 0.0], [2.0, 0.0], [0.0, -2.0]]) * marg._sd0
    return marg, marg.exact_chi2(pts)


def test_padded_programs_give_the_unpadded_numbers(monkeypatch):
    """On a recording whose every size is padded (1 400 -> 1 536 lug samples, 41 -> 48
    knots, 291 -> 320 grid nodes): the same fit's posterior marginal (Gaussian limit and
    exact chi^2) and report arrays to 1e-10 with and without the padding; the least
    squares to its solver's tolerance (the Levenberg-Marquardt path, whose steps end
    within 1e-6 of a unit column, takes other steps when the sums' rounding changes):
    chi^2 to 1e-10, each parameter within 1e-5 of its standard error."""
    from fitlug.fit import build_problem, fit_problem
    from fitlug.fit._buckets import sizes
    from fitlug.report._state import state_arrays

    sc = Scenario(duration_s=1.4, **SHORT)
    prob = build_problem(simulate(sc, 5)[0], rig_of(sc))
    sz = sizes(prob.lay)
    assert sz["n_lug_samples"] > prob.lay.lug_t.shape[0] and sz["n_coef"] > prob.lay.n_coef
    assert sz["n_grid"] > prob.lay.grid.shape[0]
    fits, same = {}, {}
    for off in ("1", "0"):
        monkeypatch.setenv("FITLUG_NO_BUCKETS", off)
        fits[off] = fit_problem(prob)
        same[off] = (*_marginal(fits["1"]), state_arrays(fits["1"])[0])
    r0, r1 = fits["1"], fits["0"]
    assert abs(r0.chi2 - r1.chi2) < 1e-10 * r0.chi2
    se0, se1 = np.sqrt(np.diag(r0.cov)), np.sqrt(np.diag(r1.cov))
    assert np.max(np.abs(r0.flat - r1.flat) / se0) < 1e-5
    assert np.max(np.abs(se0 - se1) / se0) < 1e-8
    (m0, c0, a0), (m1, c1, a1) = same["1"], same["0"]
    assert np.max(np.abs(m0.cov - m1.cov) / np.sqrt(np.outer(np.diag(m0.cov),
                                                              np.diag(m0.cov)))) < 1e-10
    assert np.max(np.abs(c0 - c1)) < 1e-10 * np.max(c0)
    for k in ("lug_model_x", "lug_model_y", "body_model_x", "body_model_y", "lug_u",
              "fine_X", "fine_v", "fine_s", "curve_x", "curve_y"):
        assert a0[k].shape == a1[k].shape, k
        assert np.max(np.abs(a0[k] - a1[k])) <= 1e-10 * max(1.0, np.max(np.abs(a0[k]))), k
    assert np.array_equal(a0["lug_seg"], a1["lug_seg"])


_RUN = """
import json, sys
from fitlug import _progress
seen = []
_progress.watch_compiles(lambda name, s: seen.append(name))
import fitlug.cli as cli
rc = cli.main([sys.argv[1], "--out", sys.argv[2], "-q", "--no-report", "--seed", "1"])
print(json.dumps({"rc": rc, "compiled": seen}))
"""


def test_a_new_length_in_a_seen_bucket_compiles_nothing(tmp_path):
    """Two recordings of one kind, 1.4 s and 1.5 s long (140 and 150 frames, other knots):
    the first run fills an empty cache; the second recording's first run (a new process)
    compiles no program for real: the fit, the detection's tables and the posterior all
    run on the first one's buckets. Each in a process of its own, as a user runs them."""
    from fitlug.fit import build_problem
    from fitlug.fit._buckets import sizes
    from fitlug.sim import write_simulation

    paths, shapes = [], []
    for d in (1.4, 1.5):
        folder = tmp_path / f"rec{d}"
        write_simulation(folder, Scenario(duration_s=d, **SHORT), 5, truth=False)
        paths.append(str(folder / "trajectories.csv"))
        prob = build_problem(paths[-1], str(folder / "rig.toml"))
        shapes.append((prob.lay.grid.shape[0], prob.lay.n_coef, sizes(prob.lay)))
    assert shapes[0][:2] != shapes[1][:2] and shapes[0][2] == shapes[1][2]
    env = dict(os.environ, FITLUG_CACHE_DIR=str(tmp_path / "cache"))
    env.pop("FITLUG_NO_BUCKETS", None)
    runs = []
    for i, p in enumerate(paths):
        r = subprocess.run([sys.executable, "-c", _RUN, p, str(tmp_path / f"out{i}")],
                           capture_output=True, text=True, env=env, timeout=600)
        assert r.returncode == 0, r.stderr[-2000:]
        runs.append(json.loads(r.stdout.strip().splitlines()[-1]))
    assert runs[0]["rc"] == 0 and runs[1]["rc"] == 0
    assert len(runs[0]["compiled"]) > 5  # the watch sees the first run's compiles
    assert runs[1]["compiled"] == []
