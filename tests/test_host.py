"""Issue 43: the model evaluated from host code (fitlug.model._host, fit._residuals'
residuals_host) gives the eager functions' numbers, in one compiled program per call site
and bucket of times, not one program per operation."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from fitlug.fit import build_problem
from fitlug.fit._residuals import residuals, residuals_host
from fitlug.model import integrate, kinematics, positions, predict
from fitlug.model import _host
from fitlug.model._model import sampled_from_nodes, speed_basis_values
from fitlug.sim import Scenario, rig_of, simulate


def _problem():
    sc = Scenario(duration_s=1.3, travel_mm=150, rest_s=0.2, ramp_s=0.4)
    prob = build_problem(simulate(sc, 11)[0], rig_of(sc))
    return prob, {k: jnp.asarray(v) for k, v in prob.p0.items()}


def _close(a, b):
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape
    scale = max(1.0, float(np.max(np.abs(b))))
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-12 * scale)


def test_host_evaluations_equal_the_eager_model():
    prob, p = _problem()
    lay = prob.lay
    nodes = integrate(p, lay)
    nodes_h = _host.integrate_host(p, lay)
    for a, b in zip(nodes_h, nodes):
        _close(a, b)
    grid = np.asarray(lay.grid)
    # an odd number of times, in two dimensions: padded to a bucket, cut back, reshaped
    t = np.linspace(grid[0], grid[-1], 2 * 333).reshape(2, 333)
    kin = kinematics(p, lay, t.ravel(), nodes)
    kin_h = _host.kinematics_host(p, lay, t, nodes_h)
    assert set(kin_h) == set(kin)
    for k in kin:
        assert kin_h[k].shape == t.shape and isinstance(kin_h[k], np.ndarray)
        _close(kin_h[k].ravel(), kin[k])
    # without nodes: integrated inside
    _close(_host.kinematics_host(p, lay, t[0])["psi"], kinematics(p, lay, t[0])["psi"])
    sam, sam_h = sampled_from_nodes(p, lay, nodes), _host.sampled_host(p, lay, nodes_h)
    for a, b in zip(sam_h, sam):
        _close(a, b)
    for a, b in zip(_host.positions_host(p, lay, *sam_h), positions(p, lay, *sam)):
        _close(a, b)
    for a, b in zip(_host.predict_host(p, lay), predict(p, lay)):
        _close(a, b)
    for a, b in zip(_host.speed_values_host(lay, p["v"]), speed_basis_values(lay, p["v"])):
        _close(a, b)
    r_h = residuals_host(p, lay, prob.obs)
    assert isinstance(r_h, np.ndarray)
    _close(r_h, residuals(p, lay, prob.obs))


def test_another_number_of_times_in_the_bucket_compiles_nothing():
    prob, p = _problem()
    lay = prob.lay
    nodes = _host.integrate_host(p, lay)
    grid = np.asarray(lay.grid)
    _host.kinematics_host(p, lay, np.linspace(grid[0], grid[-1], 1001), nodes)
    n = _host._kinematics._cache_size()
    for m in (1002, 1017, 1024):  # bucket(1001) = 1024
        out = _host.kinematics_host(p, lay, np.linspace(grid[0], grid[-1], m), nodes)
        assert out["X"].shape == (m,)
    assert _host._kinematics._cache_size() == n
    # a number of times outside the bucket: one program more, not one per operation
    compiled = []
    jax.config.update("jax_log_compiles", True)
    import logging

    class Catch(logging.Handler):
        def emit(self, rec):
            if "Compiling" in rec.getMessage():
                compiled.append(rec.getMessage())

    h = Catch()
    logging.getLogger("jax").addHandler(h)
    try:
        _host.kinematics_host(p, lay, np.linspace(grid[0], grid[-1], 1500), nodes)
    finally:
        logging.getLogger("jax").removeHandler(h)
        jax.config.update("jax_log_compiles", False)
    assert _host._kinematics._cache_size() == n + 1
    assert len(compiled) <= 2, compiled  # the program (and the padding's device copy)
