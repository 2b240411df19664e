"""Long recordings: a 5 000-frame recording fits in bounded memory and finds the slip.

The fit runs in a fresh interpreter so that its peak resident memory (VmHWM, which
counts JAX's buffers) is the fit's own; the bound is what the chunked normal equations
need (a dense Jacobian of this recording alone, with its jacfwd intermediates, went past
it before). The truth is the simulator's slip, the error bar the fit's own.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

SRC = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "src")
#: the whole child's peak (interpreter, JAX, the simulation and the fit): 0.73 GiB measured
#: on 2026-11-25 (0.45 GiB of it before the fit), so 1 GiB leaves ~35 % of headroom
MEMORY_CAP_BYTES = 1.0 * 1024 ** 3
#: the fit's own growth of the high-water mark over the simulated recording's: 0.28 GiB
#: measured (a dense Jacobian of this recording with its forward-mode intermediates alone
#: went past the old 1.5 GiB cap)
FIT_GROWTH_CAP_BYTES = 0.5 * 1024 ** 3

_CHILD = r"""
import json, resource, sys
import numpy as np
import pytest


def peak_rss():
    # VmHWM: this process image's own high-water mark. ru_maxrss is not: Linux carries the
    # forked parent's RSS into it at exec, and the parent here is a long pytest run.
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


from fitlug.sim import Scenario, simulate, rig_of
from fitlug.fit import fit
from fitlug.fit import _lsq

sc = Scenario(duration_s=10.0, fps=500.0, travel_mm=1080.0, lug_markers=12, lug_spacing=1)
rec, truth = simulate(sc, seed=3)
before = peak_rss()
calls = []
orig = _lsq._solve_chunked
_lsq._solve_chunked = lambda *a, **k: calls.append(1) or orig(*a, **k)
res = fit(rec, rig_of(sc))
peak = peak_rss()
print(json.dumps({"frames": int(np.unique(rec.frame).size), "markers": len(rec.markers),
                  "slip": res.slip.value, "std": res.slip.std, "truth": truth["slip"],
                  "converged": res.converged, "chi2_per_dof": res.chi2_per_dof,
                  "chunked_calls": len(calls), "peak": peak, "before_fit": before}))
"""


def test_5000_frames_fit_in_bounded_memory_and_find_the_slip():
    env = dict(os.environ)
    env["PYTHONPATH"] = SRC + os.pathsep + env.get("PYTHONPATH", "")
    p = subprocess.run([sys.executable, "-c", _CHILD], capture_output=True, text=True,
                       env=env, timeout=600)
    assert p.returncode == 0, p.stderr[-2000:]
    out = json.loads(p.stdout.strip().splitlines()[-1])
    assert out["frames"] == 5000 and out["markers"] == 14
    assert out["chunked_calls"] >= 1  # the long-recording path, not the dense Jacobian
    assert out["converged"] and 0.8 < out["chi2_per_dof"] < 1.2
    assert out["peak"] < MEMORY_CAP_BYTES, f"peak RSS {out['peak'] / 2 ** 20:.0f} MiB"
    grew = out["peak"] - out["before_fit"]
    assert grew < FIT_GROWTH_CAP_BYTES, f"the fit raised the peak by {grew / 2 ** 20:.0f} MiB"
    assert 0 < out["std"] < 1e-3
    assert abs(out["slip"] - out["truth"]) < 3 * out["std"], out
    assert np.isfinite(out["slip"])


def test_chunked_normal_equations_equal_the_dense_jacobians():
    """J^T J and J^T r from time chunks equal those of the exact dense Jacobian (forward
    mode), with every effect the chunked path takes, a later gauge time, missing samples
    and chunks smaller than a frame interval's window."""
    import dataclasses

    import jax
    import jax.numpy as jnp

    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from test_model import _small_layout

    from fitlug.fit._chunks import (blocked_chi2, blocked_residuals, chunk_plan, chunkable,
                                    time_blocks)
    from fitlug.fit._normal import normal_blocks, normal_equations
    from fitlug.fit._residuals import Packing, residuals
    from fitlug.fit._rowchunks import RowChunks
    from fitlug.model.effects import CATALOG

    # (the belt-locked speed modulations, a marker below the pitch line and the slip's
    # memory are not chunkable: fitlug.fit._chunks.chunkable)
    effects = tuple(e for e in CATALOG
                    if e not in ("lug_ripple", "wheel_runout", "lug_shear", "lug_memory"))
    lay, p = _small_layout(effects)
    lay = dataclasses.replace(lay, t_ref=jnp.asarray(0.137))
    n_l, n_b = lay.lug_t.shape[0], lay.body_t.shape[0]
    rng = np.random.default_rng(1)
    obs = {"lug_x": jnp.asarray(rng.normal(size=n_l)), "lug_y": jnp.asarray(rng.normal(size=n_l)),
           "lug_w": jnp.asarray(rng.uniform(50, 200, n_l) * (rng.uniform(size=n_l) > 0.1)),
           "body_x": jnp.asarray(rng.normal(size=n_b)),
           "body_y": jnp.asarray(rng.normal(size=n_b)),
           "body_w": jnp.asarray(rng.uniform(50, 200, n_b))}
    held = {k for e in effects for k in CATALOG[e].fixed_in_fit}
    packing = Packing.of(p, [k for k in p if k not in held])
    fixed = {k: v for k, v in p.items() if k in held}
    flat = packing.pack(p)
    assert chunkable(p, lay, packing)
    # one jitted program for both points (op by op, each jacfwd dispatched for seconds)
    from reference_jit import jit_reference

    jac = jit_reference(jax.jacfwd(lambda f: residuals(packing.unpack(f, fixed), lay, obs)))
    J = np.asarray(jac(flat))
    r = np.asarray(residuals(p, lay, obs))
    A0, g0 = J.T @ J, J.T @ r
    scale = np.sqrt(np.outer(np.diag(A0), np.diag(A0))) + 1e-12 * np.abs(A0).max()
    for chunk in (7, 50, 10 ** 6):
        A, g, chi2 = normal_equations(flat, fixed, lay, obs, packing, chunk_plan(lay, chunk, 8))
        assert np.max(np.abs(np.asarray(A) - A0) / scale) < 1e-8, chunk
        assert np.max(np.abs(np.asarray(g) - g0)) < 1e-10 * np.max(np.abs(g0)), chunk
        assert abs(float(chi2) - r @ r) < 1e-10 * (r @ r)
    # J_a^T J_b of the Jacobians at two parameter vectors (the posterior's step model)
    from fitlug.fit._chunk_prep import _prepare_jit
    from fitlug.fit._normal import contract_cross_jit

    flat_b = flat + 1e-3 * jnp.asarray(rng.normal(size=flat.shape[0])) * jnp.abs(flat)
    Jb = np.asarray(jac(flat_b))
    X0 = J.T @ Jb
    assert np.max(np.abs(X0 - A0) / scale) > 1e-6  # the two Jacobians differ
    plan = chunk_plan(lay, 7, 8)
    X = contract_cross_jit(_prepare_jit(flat, fixed, lay, obs, packing, plan),
                           _prepare_jit(flat_b, fixed, lay, obs, packing, plan), lay,
                           packing, plan)
    assert np.max(np.abs(np.asarray(X) - X0) / scale) < 1e-8
    # the same sums one time block at a time (padded to one shape; the long recordings'
    # bounded-memory pass), blocks smaller than a chunk and spanning several
    for max_rows, chunk in ((len(r) // 4, 7),):
        blocks = time_blocks(lay, obs, max_rows, chunk, 8)
        assert blocks is not None and len(blocks.lays) >= 3
        got = np.sort(np.concatenate(blocks.rows))
        np.testing.assert_array_equal(got[got >= 0], np.arange(len(r)))  # each row once
        A, g, chi2 = normal_blocks(flat, fixed, lay, obs, packing, None, blocks)
        assert np.max(np.abs(A - A0) / scale) < 1e-8, max_rows
        assert np.max(np.abs(g - g0)) < 1e-10 * np.max(np.abs(g0)), max_rows
        assert abs(chi2 - r @ r) < 1e-10 * (r @ r)
        # the residuals and chi^2 of the whole recording, one block's model at a time
        rb = blocked_residuals(flat, fixed, lay, obs, packing, blocks)
        np.testing.assert_allclose(rb, r, rtol=1e-12, atol=1e-12)
        assert abs(blocked_chi2(flat, fixed, lay, obs, packing, blocks) - r @ r) < 1e-10 * (r @ r)
    # the same rows one time chunk at a time (RowChunks: the explanation's long path),
    # also one time block at a time
    for chunk in (9, "blocks"):
        rc = (RowChunks(flat, fixed, lay, obs, packing, chunk_plan(lay, chunk, 8))
              if chunk != "blocks" else
              RowChunks(flat, fixed, lay, obs, packing,
                        blocks=time_blocks(lay, obs, len(r) // 4, 7, 8)))
        if chunk == "blocks":
            assert len(rc._parts) >= 4
            Ab, gb = rc.normal()
            assert np.max(np.abs(Ab - A0) / scale) < 1e-8
            assert np.max(np.abs(gb[:, 0] - g0)) < 1e-10 * np.max(np.abs(g0))
        seen = np.zeros(len(r), int)
        for rows, Jc in rc:
            seen[rows] += 1
            np.testing.assert_allclose(Jc, J[rows], rtol=1e-9, atol=1e-9 * np.abs(J).max())
        assert np.all(seen == 1), chunk
        np.testing.assert_allclose(rc.r, r, rtol=1e-12, atol=1e-12)
        x = rng.normal(size=J.shape[1])
        np.testing.assert_allclose(rc.matvec(x), J @ x, rtol=1e-9,
                                   atol=1e-9 * np.abs(J @ x).max())


@pytest.fixture(scope="module")
def sag_fit():
    """A short recording with a belt sag and its base fit (dense-size, chunkable)."""
    from fitlug.fit import fit
    from fitlug.sim import Scenario, rig_of, simulate

    sc = Scenario(duration_s=1.5, travel_mm=135.0, rest_s=0.2, ramp_s=0.4, lug_markers=4,
                  effects={"belt_sag": {"sag_d": 0.3}})
    rec, truth = simulate(sc, 5)
    return fit(rec, rig_of(sc))


def _both(monkeypatch, fn, block_rows=None):
    """fn() on the dense path, then on the chunked (long-recording) path, there in time
    blocks of `block_rows` residual rows when given."""
    from fitlug.explain import _engine
    from fitlug.fit import _chunks

    monkeypatch.setattr(_engine, "CHUNKED_ENTRIES", 10 ** 15)
    dense = fn()
    monkeypatch.setattr(_engine, "CHUNKED_ENTRIES", 0)
    if block_rows is not None:
        monkeypatch.setattr(_chunks, "BLOCK_ROWS", block_rows)
    return dense, fn()


@pytest.mark.parametrize("store", ["float64", "float32"])
def test_explanation_engine_in_normal_form_equals_the_dense_engine(sag_fit, monkeypatch, store):
    """The engine's Jacobian in normal form (J^T J, J^T r, J^T v over time chunks), its
    screening (a linear effect and frame_drop's t* scan), its fit of
    the sag and the final polish equal the dense engine's: to rounding with the difference
    columns stored in float64 (the algebra), and within what rounding them to float32 (the
    default storage on long recordings, _engine.STORE: 2^-24 relative per entry) can move."""
    from fitlug.explain import _engine
    from fitlug.explain._candidates import screen
    from fitlug.explain._engine import Engine
    from fitlug.explain._final import final_fit
    from fitlug.explain._table import geometry

    assert _engine.STORE == np.float32  # the default the float32 case stands for
    monkeypatch.setattr(_engine, "STORE", np.dtype(store).type)
    # float64: rounding; float32: a relative perturbation of 6e-8 of the stored columns
    # moves J^T r, the screening's Gauss-Newton steps and the LM path (measured: the LM
    # fit's chi^2 5e-9 relative and its parameters 1.1e-6, as it stops within its
    # tolerance at a slightly different point; J^T r 6e-9, the screening 8e-10 and 3e-8;
    # the final polish, on the exact Jacobian, equals the dense one to 1e-11 sigma);
    # the bounds are ~10x the measured
    tol = {"float64": dict(A=1e-8, dchi2=1e-6, start=1e-6, chi2=1e-9, theta=1e-7, flat=1e-6,
                           cov=1e-6, slip=1e-6),
           "float32": dict(A=1e-6, dchi2=1e-5, start=1e-5, chi2=1e-7, theta=1e-5, flat=1e-5,
                           cov=1e-5, slip=1e-5)}[store]

    res = sag_fit
    geo = geometry(res)
    cands = ["belt_sag", "frame_drop"]

    def run():
        eng = Engine(res)
        th = eng.theta0
        r = eng.residuals(th)[0]
        J = eng.jacobian(th, ["sag_d"])
        if isinstance(J, np.ndarray):
            A, g, Jv = J.T @ J, J.T @ r, J.T @ geo.t
        else:
            A, g, Jv = J.A, J.g, J.Jt(geo.t)
        scr = screen(eng, th, r, eng.jacobian(th, []), cands, [], geo)
        out = eng.fit(scr["belt_sag"].theta_start, eng.free_names("belt_sag"))
        fin = final_fit(res, eng, ["belt_sag"], out.theta)
        parts = None if isinstance(J, np.ndarray) else len(J.chunks._parts)
        return eng.chunked, A, g, Jv, scr, out, fin, parts

    d, c = _both(monkeypatch, run, block_rows=len(res.residuals) // 3)  # 3-4 time blocks
    assert not d[0] and c[0] and c[7] >= 3
    for k in (1, 2, 3):
        scale = np.max(np.abs(d[k]))
        np.testing.assert_allclose(c[k], d[k], rtol=tol["A"], atol=1e-10 * scale)
    for e in cands:
        assert c[4][e].label == d[4][e].label
        assert c[4][e].dchi2 == pytest.approx(d[4][e].dchi2, rel=tol["dchi2"], abs=1e-6)
        np.testing.assert_allclose(c[4][e].theta_start, d[4][e].theta_start,
                                   rtol=tol["start"], atol=1e-9)
    assert d[4]["belt_sag"].dchi2 > 1e3  # the sag is seen
    assert c[5].chi2 == pytest.approx(d[5].chi2, rel=tol["chi2"])
    np.testing.assert_allclose(c[5].theta, d[5].theta, rtol=tol["theta"], atol=1e-10)
    fd, fc = d[6], c[6]
    sd = np.sqrt(np.diag(fd.cov))
    assert np.max(np.abs(fc.flat - fd.flat) / sd) < tol["flat"]
    # element by element in units of the two parameters' standard errors (a correlation
    # scale): an off-diagonal element near zero (|rho| ~ 1e-3 between a speed coefficient
    # and a body offset of a drive-through-style layout) differs by 3.5e-6 of itself,
    # well within 1e-6 of its standard-error product
    scale = np.sqrt(np.outer(np.diag(fd.cov), np.diag(fd.cov)))
    np.testing.assert_array_less(np.abs(fc.cov - fd.cov), tol["cov"] * scale + 1e-300)
    assert fc.slip.value == pytest.approx(fd.slip.value, abs=tol["slip"] * fd.slip.std)
    assert _engine.CHUNKED_ENTRIES == 0


def test_robust_errors_and_systematics_check_in_normal_form_equal_the_dense_ones(
        sag_fit, monkeypatch):
    """The robust sandwiches (scores by marker and by time window, over time chunks) and
    the tracker-systematics nuisance fit (J^T J, J^T N with N never formed) equal the
    dense ones."""
    import jax
    import jax.numpy as jnp

    from fitlug.explain._engine import jacobian_of
    from fitlug.fit._result import derived
    from fitlug.explain._robust import _in_time, _sandwich, covariance
    from fitlug.explain._systematics import _nuisance_fit
    from fitlug.explain._table import geometry

    res = sag_fit  # the sag left in: a structured misfit, like an unexplained one
    geo = geometry(res)
    prob = res.problem
    fixed = {k: jnp.asarray(v, float) for k, v in res.params.items()
             if k not in res.packing.names}
    r = np.where(geo.valid, np.asarray(res.residuals), 0.0)

    def run():
        J = jacobian_of(res.flat, fixed, res.packing, prob.lay, prob.obs)
        H = covariance(J)
        return (H, _sandwich(J, r, geo.marker, H), _in_time(J, r, geo.t, geo.t_lo, H)[0],
                _nuisance_fit(res, geo, r))

    d, c = _both(monkeypatch, run, block_rows=len(res.residuals) // 3)
    fixed_j = {k: jnp.asarray(v, float) for k, v in res.params.items()
               if k not in res.packing.names}
    g = np.asarray(jax.grad(lambda f: derived(res.packing.unpack(f, fixed_j), prob.lay,
                                              prob.rig.mass_kg)["slip"])(jnp.asarray(res.flat)))
    sd = np.sqrt(np.outer(np.diag(d[0]), np.diag(d[0])))
    assert np.max(np.abs(c[0] - d[0]) / sd) < 1e-6
    for k in (0, 1, 2):  # the slip's error from each covariance (the sandwiches' entries of
        # directions the data barely fix carry the normal matrix's conditioning, ~1e-3)
        assert np.sqrt(g @ c[k] @ g) == pytest.approx(np.sqrt(g @ d[k] @ g), rel=1e-7), k
        assert np.all(np.diag(c[k]) >= 0)
    (dd, r2d, npd, nqd, covd, JJd), (dc, r2c, npc, nqc, covc, JJc) = d[3], c[3]
    assert (npd, nqd) == (npc, nqc) and nqd > 10
    # the model's covariance with the nuisance carried: the slip's error agrees
    assert np.sqrt(g @ covc @ g) == pytest.approx(np.sqrt(g @ covd @ g), rel=1e-6)
    assert np.sqrt(g @ covd @ g) >= np.sqrt(g @ d[0] @ g) * (1 - 1e-9)  # never narrower
    assert np.max(np.abs(r2c - r2d)) < 1e-6 * np.max(np.abs(r - r2d))
    assert np.sum(r2d ** 2) < 0.9 * np.sum(r ** 2)  # the nuisance carries part of the sag


def test_posterior_exact_chi2_in_bounded_batches_equals_the_dense_one(sag_fit, monkeypatch):
    """The posterior's exact marginal chi^2 on the chunked path, in batches capped so that
    a batch holds at most LARGE_ENTRIES residuals, equals the dense path's (one batch of
    16 with the dense Jacobian) at the linearity check's points, and the chunked normal
    matrix gives the same Gaussian limit."""
    from fitlug.posterior import _marginal
    from fitlug.posterior._marginal import _Marginal, slip_law_parameters

    res = sag_fit
    names = slip_law_parameters(res)
    n_res = len(res.residuals)
    monkeypatch.setattr(_marginal, "LARGE_ENTRIES", 10 ** 15)
    dense = _Marginal(res, names, batch=16)
    monkeypatch.setattr(_marginal, "LARGE_ENTRIES", 3 * n_res)
    chunked = _Marginal(res, names, batch=16)
    assert dense._plan is None and chunked._plan is not None
    assert dense.batch == 16 and chunked.batch == 3  # 3 residual vectors per batch
    # and in time blocks of a quarter of the rows each (batches of 3 blocks' rows)
    from fitlug.fit import _chunks

    monkeypatch.setattr(_marginal, "LARGE_ENTRIES", n_res)
    monkeypatch.setattr(_chunks, "BLOCK_ROWS", n_res // 4)
    blocked = _Marginal(res, names, batch=16)
    assert blocked._blocks is not None and len(blocked._blocks.lays) >= 4
    assert blocked.batch >= 3
    pts = np.vstack([dense.theta_hat, dense.check_points(), dense.theta_hat])
    assert len(pts) % 3  # the last batch padded
    cd = dense.exact_chi2(pts)
    for m in (chunked, blocked, "groups"):
        if m == "groups":  # the thetas' node values a batch at a time (long recordings)
            monkeypatch.setattr(_marginal, "NODE_ENTRIES", 1)
            m = blocked
        cc = m.exact_chi2(pts)
        assert len(cc) == len(pts)
        np.testing.assert_allclose(cc, cd, rtol=1e-9)
        # the chi^2 differences the check uses (a few units) agree far below their size
        assert np.max(np.abs((cc - cc[0]) - (cd - cd[0]))) < 1e-6
        np.testing.assert_allclose(m.cov, dense.cov, rtol=1e-7)


def test_engine_residuals_by_time_blocks_equal_the_whole_batch(sag_fit, monkeypatch):
    """A long recording's engine integrates a full batch once and evaluates the samples by
    time blocks: the same residuals as the whole-recording batch, with effects that map
    the time stamps, bend the path and modulate the speed (the integration's scan)."""
    from fitlug.explain import _engine
    from fitlug.explain._engine import CHUNK, Engine

    res = sag_fit
    eng0 = Engine(res)
    assert eng0.blocks is None and eng0.batch == CHUNK
    n_res = len(res.residuals)
    monkeypatch.setattr(_engine, "BATCH_ENTRIES", n_res)  # whole-recording batch of one
    monkeypatch.setattr(_engine, "BLOCK_ENTRIES", n_res)  # blocks of n_res / CHUNK rows
    eng = Engine(res)
    assert eng.blocks is not None and len(eng.blocks.lays) >= 6 and eng.batch == CHUNK
    th = eng.theta0
    t_mid = float(np.median(np.asarray(res.problem.lay.lug_t)))
    moved = [th, eng.with_values(th, {"sag_d": 0.3}),
             eng.with_values(th, {"drop_dt": 0.004, "drop_tstar": t_mid}),
             eng.with_values(th, {"ripple_a": 0.02, "ripple_b": -0.01, "slide_mu": 0.3})]
    thetas = np.array([m for m in moved for _ in range(3)])  # 12: a batch and a padded one
    R0, R = eng0.residuals(thetas), eng.residuals(thetas)
    assert R.shape == R0.shape == (12, n_res)
    assert np.max(np.abs(R - R0)) < 1e-10 * np.max(np.abs(R0))
    assert np.max(np.abs(R0[3] - R0[0])) > 1.0  # the effects act
    # the difference columns, written block by block on the long path
    specs = [({}, "sag_d"), ({}, "s0"), ({"sag_d": 0.3}, "R"), ({}, "ripple_a"), ({}, "e")]
    F0, F = eng0.fd_columns(specs, th), eng.fd_columns(specs, th)
    assert F.shape == F0.shape == (n_res, len(specs))
    np.testing.assert_allclose(F, F0, rtol=1e-7, atol=1e-7 * np.max(np.abs(F0)))
    assert np.min(np.max(np.abs(F0), axis=0)) > 0  # every column acts


def test_glitch_search_by_time_blocks_equals_the_whole_prediction(sag_fit, monkeypatch):
    """The glitch search's model positions one time block at a time (long recordings)
    equal the whole recording's prediction, and so do its z statistics and flags."""
    import jax.numpy as jnp

    from fitlug.fit import _chunks, _glitches
    from fitlug.model import predict

    prob = sag_fit.problem
    p = {k: jnp.asarray(v, float) for k, v in sag_fit.params.items()}
    whole = [np.asarray(a) for a in predict(p, prob.lay)]
    found = _glitches.find(sag_fit)
    assert _chunks.time_blocks(prob.lay, prob.obs) is None
    monkeypatch.setattr(_chunks, "BLOCK_ROWS", len(sag_fit.residuals) // 4)
    assert len(_chunks.time_blocks(prob.lay, prob.obs).lays) >= 4
    for a, b in zip(_glitches._positions(p, prob.lay, prob.obs), whole):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)
    got = _glitches.find(sag_fit)
    for role in ("lug", "body"):
        np.testing.assert_array_equal(got[role], found[role])
        np.testing.assert_allclose(got["z"][role], found["z"][role], rtol=1e-9, atol=1e-9)
