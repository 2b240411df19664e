"""The slip's memory (lug_memory) and a chain's polygon (chain_polygon), against truth
the model did not produce: a time-stepped brush of discrete lugs written here from the
physics (each lug's shear grows by the belt's slip displacement while it is on the ground;
the lugs in contact carry the load), closed-form steady states, and the geometry of a
chain of rigid links (chords of the hinge circle)."""

import jax.numpy as jnp
import numpy as np
import pytest

from fitlug.model import make_layout
from fitlug.model._model import integrate
from fitlug.model._path import stadium
from fitlug.model.effects import Ctx
from fitlug.model.effects._lug_memory import belt_travel


def _profile(t):
    """A smooth start from rest (0.3 s at rest, 1 s ramp to 150 mm/s), then cruise."""
    x = np.clip((t - 0.3) / 1.0, 0.0, 1.0)
    v = 150.0 * x * x * (3 - 2 * x)
    a = np.where((t > 0.3) & (t < 1.3), 150.0 * 6 * x * (1 - x), 0.0)
    return v, a


def _discrete_brush(t_end, dt, Lam, s_qs_of, n_lugs=400):
    """psi(t) of a brush of n_lugs lugs, one every Lam / n_lugs mm of belt, that hold on
    the ground over the last Lam of belt travel: sum of the shears / n_lugs =
    s_qs Lam / 2 at every step (the load shared), each step's slip displacement added to
    every lug in contact, a lug that touches down starting unsheared."""
    gap = Lam / n_lugs
    t = np.arange(0.0, t_end + dt / 2, dt)
    v, a = _profile(t)
    X = np.concatenate([[0.0], np.cumsum((v[1:] + v[:-1]) / 2 * dt)])
    s_qs = s_qs_of(a)
    # at rest before t = 0 the lugs carry the steady shear profile of the slip s_qs(0)
    d = s_qs[0] * np.arange(n_lugs) * gap  # shear s (psi - psi_touch) at psi = 0
    psi = np.zeros_like(t)
    next_touch = gap  # belt travel of the next lug's touch-down
    for i in range(1, len(t)):
        # every lug in contact takes the step's slip displacement delta; delta so that the
        # lugs carry the load: mean(d + delta) = s_qs Lam / 2 (after lugs come and go)
        target = s_qs[i] * Lam / 2.0 * n_lugs
        delta = (target - d.sum()) / len(d)
        d = d + delta
        psi[i] = psi[i - 1] + (X[i] - X[i - 1]) + delta
        while psi[i] >= next_touch:  # a lug touches down at the front, the rearmost lifts
            d = np.concatenate([[0.0], d[:-1]])
            next_touch += gap
    return t, X, psi


def test_memory_follows_a_brush_of_discrete_lugs():
    Lam, s0, beta = 125.0, 0.03, 2e-4
    law = lambda a: s0 + beta * a  # noqa: E731
    t, X, psi_ref = _discrete_brush(3.0, 1e-4, Lam, law, n_lugs=1600)
    h = 0.005
    tg = np.arange(0.0, 3.0 + h / 2, h)
    v, a = _profile(tg)
    Xg = np.interp(tg, t, X)
    psi, dpsi = belt_travel(jnp.asarray(Xg), jnp.asarray(law(a)), Lam, h)
    ref = np.interp(tg, t, psi_ref)
    # the slip displacement S = psi - X (10 mm at 3 s) agrees to 15 micrometres (the
    # brush's discreteness: 36 um with 400 lugs, 10 um with 1600, converging as 1/n)
    assert np.max(np.abs(np.asarray(psi) - ref)) < 0.015
    # and it is not the instantaneous law's: the memory shows after the ramp
    inst = np.concatenate([[0.0], np.cumsum(h * (v[1:] / (1 - law(a[1:]))
                                                 + v[:-1] / (1 - law(a[:-1]))) / 2)])
    assert np.max(np.abs(inst - ref)) > 0.3
    # at cruise, long after the ramp, the slip is the steady s0
    s = 1.0 - v / np.asarray(dpsi)
    late = tg > 2.7
    assert abs(np.mean(s[late]) - s0) < 2e-3


def _layout(effects):
    return make_layout(breaks=np.linspace(0.0, 3.0, 12), t_lo=0.0, t_hi=3.0, fps=100.0,
                       lug_t=np.linspace(0.1, 2.9, 50), lug_i=np.zeros(50, int),
                       body_t=np.linspace(0.1, 2.9, 50), body_j=np.zeros(50, int),
                       n_lug=1, n_body=1, n_belt=22, effects=effects)


def _params(lay, **extra):
    from fitlug.model import default_params

    K = lay.n_coef
    p = {"v": jnp.linspace(0.0, 150.0, K), "s0": jnp.asarray(0.04), "beta": jnp.asarray(1e-4),
         "R": jnp.asarray(25.0), "D": jnp.asarray(127.0), "e": jnp.asarray(3.0),
         "x_off": jnp.asarray(0.0), "y_off": jnp.asarray(0.0), "sigma0": jnp.zeros(1),
         "cx": jnp.zeros(1), "cy": jnp.zeros(1)}
    p.update(default_params(lay))
    p.update({k: jnp.asarray(v) for k, v in extra.items()})
    return p


def test_memory_identity_and_steady_state():
    base, mem = _layout(()), _layout(("lug_memory",))
    n0 = integrate(_params(base), base)
    n1 = integrate(_params(mem), mem)  # lambda at its default: today's model
    for a, b in zip(n0, n1):
        assert np.array_equal(np.asarray(a), np.asarray(b))
    n2 = integrate(_params(mem, memory_lambda=1.0), mem)
    assert np.max(np.abs(np.asarray(n2[1]) - np.asarray(n0[1]))) > 0.05


def test_chain_polygon_geometry():
    R, D, e, c = 24.415, 125.7, 5.0, 18.36
    P = 2 * D + 2 * np.pi * R
    base = Ctx(R=R, D=D, e=e, P=P, pitch=P / 22)
    poly = base._replace(link=jnp.asarray(c))
    u = jnp.linspace(0.0, P, 4001)
    x0, y0, _ = stadium(u, base)
    x1, y1, seg = stadium(u, base._replace(link=jnp.asarray(1e-5)))
    assert np.array_equal(np.asarray(x1), np.asarray(x0))  # a belt below 1 um
    x, y, seg = (np.asarray(a) for a in stadium(u, poly))
    # straight runs: the marker e out from the pitch line, as on a belt
    on_bottom = (np.asarray(u) > c) & (np.asarray(u) < D - c)
    assert np.allclose(y[on_bottom], -e)
    # a link seated on the rear wheel is a chord of the hinge circle of radius Rh, where
    # the belt travels R per radian: its middle sits Rh cos(c / 2R) from the centre and
    # the marker e further out
    Rh = (c / 2) / np.sin(c / (2 * R))
    mid_rear = (np.asarray(u) > D + c) & (np.asarray(u) < D + np.pi * R - c)
    r = np.hypot(x[mid_rear] + D / 2, y[mid_rear] - Rh)
    assert np.allclose(r, Rh * np.cos(c / (2 * R)) + e, atol=1e-9)
    assert 2 * Rh * np.sin(c / (2 * R)) == pytest.approx(c)  # a link is a chord of pitch c
    # and the marker's path has no jump anywhere (the kinks at the arcs' ends are
    # continuous in position)
    step = np.hypot(np.diff(x), np.diff(y))
    assert step.max() < 3 * (P / 4000) * (Rh + e) / Rh


def test_memory_is_chunked_only_at_its_identity():
    """Long recordings' time blocks need local kinematics: a memory of a contact length
    is not local, the identity is."""
    from fitlug.fit._chunks import chunkable
    from fitlug.fit._residuals import Packing

    lay = _layout(("lug_memory",))
    for lam, ok in ((0.0, True), (0.8, False)):
        p = _params(lay, memory_lambda=lam)
        assert chunkable(p, lay, Packing.of(p, list(p))) is ok
