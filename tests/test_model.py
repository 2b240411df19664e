"""The track model against the contract: the paper's numbers, the path table, gradients."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fitlug.model import CATALOG, belt_length, predict, reference_slip, stadium
from fitlug.model._physics import physical, slip_params_from_physical
from fitlug.model.effects import Ctx
from fitlug.sim import Scenario, truth_params
from fitlug.sim._simulate import _truth_layout
from reference_jit import jit_reference


def test_reference_paper_eq1():
    # s = (n - 1) dl' / L with n = 8, dl' = 1.4 mm, L = 127 mm -> 0.07716 (the paper)
    # (7 x 1.4 / 127 = 0.0771654...: the paper truncates to 0.07716)
    assert abs(float(reference_slip(8, 1.4, 127.0)) - 0.07716) < 1e-5
    assert math.floor(reference_slip(8, 1.4, 127.0) * 1e5) / 1e5 == 0.07716
    # and the FE model's dl' = 1.3 mm
    assert math.isclose(reference_slip(8, 1.3, 127.0), 7 * 1.3 / 127.0)


def test_slip_law_identities():
    # s0 = 2 m C_rr g / (k n L) = (n - 1) dl' / L with dl' = 2F / (k n (n - 1))
    m, crr, k, n, L = 10.0, 0.1, 0.25, 8, 127.0
    s0, beta = slip_params_from_physical(k, crr, m, n=n, L=L)
    F = m * crr * 9.81
    dl = 2 * F / (k * n * (n - 1))
    assert math.isclose(s0, (n - 1) * dl / L, rel_tol=1e-12)
    ph = physical(s0, beta, n=n, L=L, mass_kg=m)
    assert math.isclose(ph["stiffness_N_per_mm"], k, rel_tol=1e-12)
    assert math.isclose(ph["rolling_resistance"], crr, rel_tol=1e-12)
    assert math.isclose(ph["delta_l_mm"], dl, rel_tol=1e-12)


def test_stadium_table_points_and_continuity():
    R, D, e = 25.0, 120.0, 3.0
    P = float(belt_length(R, D))
    ctx = Ctx(R=R, D=D, e=e, P=P, pitch=P / 22)
    u = jnp.array([0.0, D / 2, D + math.pi * R / 2, D + math.pi * R + D / 2,
                   2 * D + math.pi * R + math.pi * R / 2])
    x, y, seg = stadium(u, ctx)
    expect = [(D / 2, -e), (0.0, -e), (-D / 2 - (R + e), R), (0.0, 2 * R + e),
              (D / 2 + (R + e), R)]
    np.testing.assert_allclose(np.c_[x, y], expect, atol=1e-12)
    assert list(np.asarray(seg)) == [0, 0, 1, 2, 3]
    # continuous across every segment join and across the wrap at P
    for b in (D, D + math.pi * R, 2 * D + math.pi * R, P):
        xa, ya, _ = stadium(jnp.array([b - 1e-9, b + 1e-9]), ctx)
        assert abs(float(xa[1] - xa[0])) < 1e-6 and abs(float(ya[1] - ya[0])) < 1e-6


def _small_layout(effects):
    sc = Scenario(duration_s=1.2, rest_s=0.1, ramp_s=0.4, travel_mm=100, lug_markers=3)
    t = np.arange(0, 1.2, 0.05)
    nl = sc.lug_markers
    lay, br = _truth_layout(sc, np.repeat(t, nl), np.tile(np.arange(nl), len(t)),
                            np.repeat(t, 2), np.tile(np.arange(2), len(t)))
    lay = lay.with_effects(effects)
    p = truth_params(sc, lay, br)
    p["beta"] = jnp.asarray(2e-4)  # make the acceleration term matter
    values = {"ripple_a": 0.01, "ripple_b": -0.004, "runout_a": 0.02, "runout_b": 0.01,
              "bounce_A": 0.05, "bounce_B": 1e-3, "bounce_phi": 0.3, "slide_mu": 4.0,
              "sag_d": 0.5, "sink_z": 0.3, "sink_us": 20.0, "lens_k1": 2e-7, "lens_cx": 10.0,
              "lens_cy": 20.0, "depth_eps": 0.01, "depth_cx": 5.0, "depth_cy": 2.0,
              "tilt_theta": 0.01, "drop_dt": 0.01, "drop_tstar": 0.52,
              "shear_h": 0.3, "shear_tau": 0.03, "memory_lambda": 0.8, "link_pitch": 18.0}
    for e in effects:
        for k in CATALOG[e].defaults:
            p[k] = jnp.asarray(values[k])
    return lay, p


@pytest.mark.parametrize("effects", [(), *[(e,) for e in CATALOG]])
def test_gradients_match_finite_differences(effects):
    lay, p = _small_layout(effects)
    names = [k for k in p if k not in {k for e in effects for k in CATALOG[e].fixed_in_fit}]

    def f(flat):
        q = dict(p)
        i = 0
        for k in names:
            n = int(np.size(p[k]))
            q[k] = flat[i:i + n].reshape(np.shape(p[k]))
            i += n
        return jnp.concatenate(predict(q, lay))

    flat = jnp.concatenate([jnp.ravel(p[k]) for k in names])
    J = jit_reference(jax.jacfwd(f))(flat)
    rng = np.random.default_rng(0)
    scale = np.abs(np.asarray(flat)) * 1e-6 + 1e-7
    for _ in range(3):
        d = rng.normal(size=flat.shape) * scale
        fd = (f(flat + d) - f(flat - d)) / 2
        ad = J @ d
        err = np.max(np.abs(np.asarray(fd - ad)))
        # a wrong derivative is off by O(1); FD truncation here is ~1e-6 relative
        assert err <= 1e-5 * (np.max(np.abs(np.asarray(ad))) + 1e-9) + 1e-10, (effects, err)


def _random_problem(effects, seed):
    """The small layout with random observations and weights: (lay, p, obs, packing,
    fixed, flat), the effects' fixed-in-fit parameters held."""
    from fitlug.fit._residuals import Packing

    lay, p = _small_layout(effects)
    n_l, n_b = lay.lug_t.shape[0], lay.body_t.shape[0]
    rng = np.random.default_rng(seed)
    obs = {"lug_x": jnp.asarray(rng.normal(size=n_l)), "lug_y": jnp.asarray(rng.normal(size=n_l)),
           "lug_w": jnp.asarray(rng.uniform(50, 200, n_l)),
           "body_x": jnp.asarray(rng.normal(size=n_b)),
           "body_y": jnp.asarray(rng.normal(size=n_b)),
           "body_w": jnp.asarray(rng.uniform(50, 200, n_b))}
    fixed_names = {k for e in effects for k in CATALOG[e].fixed_in_fit}
    packing = Packing.of(p, [k for k in p if k not in fixed_names])
    fixed = {k: v for k, v in p.items() if k in fixed_names}
    return lay, p, obs, packing, fixed, packing.pack(p)


@pytest.mark.parametrize("effects", [(), tuple(CATALOG)])
def test_structured_jacobian_equals_forward_mode(effects):
    """fitlug.fit's Jacobian (kinematic columns through the sampled X and psi) is exact."""
    from fitlug.fit._residuals import jacobian, residuals

    lay, p, obs, packing, fixed, flat = _random_problem(effects, 1)
    # jitted: op by op, jacfwd of the whole catalog dispatched for 22 s on every run; one
    # program is compiled once and then read from the persistent cache
    J_fwd = np.asarray(jit_reference(jax.jacfwd(lambda f: residuals(packing.unpack(f, fixed),
                                                                      lay, obs)))(flat))
    J = np.asarray(jacobian(flat, fixed, lay, obs, packing))
    assert J.shape == J_fwd.shape
    tol = 1e-10 * np.max(np.abs(J_fwd), axis=0) + 1e-12
    assert np.all(np.abs(J - J_fwd) <= tol), (effects, np.max(np.abs(J - J_fwd) - tol))


@pytest.mark.parametrize("effects", [(), ("lug_shear",)])
def test_lm_linearisation_matches_finite_differences(effects):
    """The least squares' residual function (fit/_lsq.py) is differentiated by the
    structured Jacobian (a custom JVP): what the LM materialises (jacfwd of it) is that
    Jacobian, and each of its columns matches central finite differences of the plain
    residuals (a wrong column is off by O(1) of its size; the differences' truncation and
    rounding here are ~1e-8 of it). The base model, and lug_shear, where sigma0 goes
    forward with the rest; every effect's structured Jacobian against jacfwd, and jacfwd
    against finite differences, are the two tests above."""
    from fitlug.fit._lsq import _with_structured_jacobian
    from fitlug.fit._residuals import jacobian, residuals

    lay, p, obs, packing, fixed, flat = _random_problem(effects, 2)
    r_lm = jax.jit(_with_structured_jacobian(fixed, lay, obs, packing))
    r = jax.jit(lambda f: residuals(packing.unpack(f, fixed), lay, obs))
    np.testing.assert_array_equal(np.asarray(r_lm(flat)), np.asarray(r(flat)))
    J_lm = np.asarray(jax.jit(jax.jacfwd(r_lm))(flat))
    J = np.asarray(jax.jit(lambda f: jacobian(f, fixed, lay, obs, packing))(flat))
    size = np.max(np.abs(J_lm), axis=0) + 1e-9 * np.max(np.abs(J_lm))  # a column may be 0
    assert np.max(np.abs(J_lm - J) / size) < 1e-13  # the same matrix (to XLA's fusions)
    # each column's step moves the residuals by 1e-6 of their largest (rounding ~1e-10 of
    # the column, truncation ~h^2: 1e-8 here), but is at most 1e-4 of the parameter (or 1e-4
    # in its units): a near-zero column (lug_shear's first knot, 1e-14 of the largest)
    # would otherwise take a step of ~6e-3, where the residuals are far from linear in it
    x = np.asarray(flat)
    size = np.max(np.abs(J_lm), axis=0)
    size = np.maximum(size, 1e-6 * np.max(size))  # a column may be 0 (a knot left unread)
    h = np.minimum(1e-6 * np.max(np.abs(np.asarray(r(flat)))) / size,
                   1e-4 * np.maximum(np.abs(x), 1.0))
    E = np.diag(h)
    fd = np.stack([(np.asarray(r(flat + E[j])) - np.asarray(r(flat - E[j]))) / (2 * h[j])
                   for j in range(len(x))], axis=1)
    err = np.max(np.abs(fd - J_lm), axis=0) / size
    assert np.max(err) < 1e-6, (effects, packing.names, float(np.max(err)), int(np.argmax(err)))


def test_effects_are_identity_at_defaults():
    lay0, p0 = _small_layout(())
    base = np.concatenate([np.asarray(a) for a in predict(p0, lay0)])
    for e, cls in CATALOG.items():
        lay = lay0.with_effects((e,))
        p = dict(p0)
        p.update({k: jnp.asarray(v) for k, v in cls.defaults.items()})
        out = np.concatenate([np.asarray(a) for a in predict(p, lay)])
        np.testing.assert_allclose(out, base, atol=1e-9, err_msg=e)


def test_speed_modulation_integrates_the_ode():
    # v -> v (1 + eps sin(psi / R + phi)): X(t) from the model vs a brute-force Euler
    # integration of dX/dt = v0 (1 + m(psi)), dpsi/dt = v / (1 - s(a)).
    lay, p = _small_layout(("wheel_runout",))
    from fitlug.model import integrate

    X, psi, _, _ = integrate(p, lay)
    g = np.asarray(lay.grid)
    from fitlug.model._spline import design

    br = np.asarray(lay.breaks)
    h = 1e-5
    tt = np.arange(g[0], g[-1], h)
    v0 = design(tt, br) @ np.asarray(p["v"])
    a0 = design(tt, br, 1) @ np.asarray(p["v"])
    R = float(p["R"])
    a_, b_ = float(p["runout_a"]), float(p["runout_b"])
    s0, beta = float(p["s0"]), float(p["beta"])
    Xe, pe = 0.0, 0.0
    Xs, Ps = [0.0], [0.0]
    dpsi = v0[0] / (1 - s0)
    for k in range(len(tt) - 1):
        th = pe / R
        m = a_ * np.sin(th) + b_ * np.cos(th)
        dm = (a_ * np.cos(th) - b_ * np.sin(th)) / R
        v = v0[k] * (1 + m)
        a = a0[k] * (1 + m) + v0[k] * dm * dpsi
        dpsi = v / (1 - (s0 + beta * a))
        Xe += v * h
        pe += dpsi * h
        Xs.append(Xe)
        Ps.append(pe)
    i0 = np.searchsorted(tt, 0.0)
    Xs, Ps = np.array(Xs) - Xs[i0], np.array(Ps) - Ps[i0]
    np.testing.assert_allclose(np.interp(g[5:-5], tt, Xs), np.asarray(X)[5:-5], atol=2e-3)
    np.testing.assert_allclose(np.interp(g[5:-5], tt, Ps), np.asarray(psi)[5:-5], atol=2e-3)
