"""The fitted model as a function (issue 27, item 4): FitResult.predict and slip_at.

Truth: the simulator's own model at its known parameters, evaluated at instants between
the frames (the fit never saw them); the bands against central finite differences of the
prediction along the covariance's factor; the robot at rest after the run (extrapolation
must hold it still, not run away as the bare spline did: v = -6.9e9 mm/s at t = 100 s)."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest

import fitlug
from fitlug.fit import _predict
from fitlug.model import kinematics, predict
from fitlug.sim import Scenario, rig_of, simulate, truth_params
from fitlug.sim._simulate import _truth_layout

SC = Scenario(duration_s=1.5, travel_mm=150, rest_s=0.2, ramp_s=0.4)


@pytest.fixture(scope="module")
def fitted():
    rec, _ = simulate(SC, 5)
    return fitlug.fit(rec, rig_of(SC))


T_POS = np.linspace(0.013, 1.47, 83)  # not on the 1/fps frame grid
T_SLIP = np.linspace(0.45, 1.05, 41)  # the end of the ramp up, cruise, the start of braking


@pytest.fixture(scope="module")
def truth():
    """The simulator's model at its known parameters: positions at T_POS, s at T_SLIP."""
    x, y, _ = _truth_at(T_POS)
    s = _truth_at(T_SLIP)[2]
    return x, y, s


def _truth_at(t):
    nl, nb = SC.lug_markers, len(SC.body_markers)
    lay, br = _truth_layout(SC, np.repeat(t, nl), np.tile(np.arange(nl), len(t)),
                            np.repeat(t, nb), np.tile(np.arange(nb), len(t)))
    p = truth_params(SC, lay, br)
    lx, ly, bx, by = (np.asarray(a) for a in predict(p, lay))
    T = len(t)
    x = np.r_[lx.reshape(T, nl).T, bx.reshape(T, nb).T]
    y = np.r_[ly.reshape(T, nl).T, by.reshape(T, nb).T]
    return x, y, np.asarray(kinematics(p, lay, jnp.asarray(t))["s"])


def test_predict_between_frames_matches_the_simulators_truth_within_its_band(fitted, truth):
    t = T_POS
    pr = fitted.predict(t)
    assert pr.markers == tuple(f"B{i + 1:02d}" for i in range(SC.lug_markers)) + ("C1", "C2")
    assert pr.roles[0] == "lug" and pr.roles[-1] == "body" and pr.x.shape == (12, 83)
    x, y, _ = truth
    zx, zy = (pr.x - x) / pr.x_std, (pr.y - y) / pr.y_std
    # errors of the fit, not of the noise (std ~1e-3 mm against 0.02-0.05 mm noise)
    assert np.max(pr.x_std) < 5e-3 and np.max(np.abs(pr.x - x)) < 0.02
    assert np.sqrt(np.mean(zx ** 2)) < 3 and np.sqrt(np.mean(zy ** 2)) < 3
    df = pr.to_dataframe()
    assert len(df) == 12 * 83 and df.loc[df.marker == "C2", "y_mm"].to_numpy() == \
        pytest.approx(pr["C2"]["y"])


def test_slip_at_matches_the_truth_and_is_undefined_at_rest(fitted, truth):
    b = fitted.slip_at(T_SLIP)
    s_true = truth[2]
    assert np.all(np.isfinite(b.value))
    # within the band where the acceleration is smooth (cruise); where the profile's
    # acceleration jumps (ramp ends) the speed spline's knots smooth it: a bias of ~1e-3
    # that the statistical band does not carry (documented in slip_at)
    cruise = (T_SLIP > 0.64) & (T_SLIP < 0.86)
    z = (b.value - s_true)[cruise] / b.std[cruise]
    assert np.sqrt(np.mean(z ** 2)) < 3
    assert np.max(np.abs(b.value - s_true)) < 3e-3
    assert np.ptp(s_true) > 0.05  # the window does see the slip change with acceleration
    lo, hi = b.ci95
    assert np.all(lo < b.value) and np.all(b.value < hi)
    rest = fitted.slip_at([0.05, 1.45])
    assert np.all(np.isnan(rest.value))  # the robot stands: no slip to speak of


def _fd_std(res, f, h=0.5):
    """Central differences of f along the columns of the covariance's Cholesky factor."""
    L = np.linalg.cholesky(res.cov + 1e-30 * np.eye(len(res.flat)))
    var = 0.0
    for k in range(L.shape[1]):
        up = dataclasses.replace(res, flat=res.flat + h * L[:, k])
        dn = dataclasses.replace(res, flat=res.flat - h * L[:, k])
        var = var + ((f(up) - f(dn)) / (2 * h)) ** 2
    return np.sqrt(var)


def test_bands_equal_finite_differences(fitted):
    t = np.array([0.3, 0.7, 1.2])
    pr = fitted.predict(t, markers=["B03", "C1"])
    sd = _fd_std(fitted, lambda r: r.predict(t, markers=["B03", "C1"]).x)
    np.testing.assert_allclose(pr.x_std, sd, rtol=2e-3)
    sb = _fd_std(fitted, lambda r: r.slip_at(t).value)
    np.testing.assert_allclose(fitted.slip_at(t).std, sb, rtol=2e-3)


def test_times_outside_the_recording_are_refused_unless_asked(fitted):
    with pytest.raises(ValueError, match=r"outside the recording \(0\.\.1\.49 s\).*extrapolate"):
        fitted.predict([100.0])
    with pytest.raises(ValueError, match="outside the recording"):
        fitted.slip_at([-1.0, 0.5])
    with pytest.raises(ValueError, match="unknown marker.*'B99'.*fitted markers: B01"):
        fitted.predict([0.5], markers=["B99"])
    # the robot stands still after the run: extrapolated (speed held at the fit's edge),
    # the truth, where it stopped, stays inside a band that widens with the distance
    pr = fitted.predict([1.49, 3.0, 100.0], markers="C1", extrapolate=True)
    x_stop = pr.x[0, 0]
    assert np.all(np.isfinite(pr.x)) and np.all(np.abs(pr.x[0] - x_stop) < 3 * pr.x_std[0] + 1e-9)
    assert pr.x_std[0, 0] < pr.x_std[0, 1] < pr.x_std[0, 2] < 1e3


def test_one_compiled_program_serves_other_times_and_markers(fitted):
    _predict._positions.clear_cache()
    _predict._slip.clear_cache()
    fitted.predict(np.linspace(0.1, 1.4, 50))
    fitted.predict(np.linspace(0.2, 1.3, 777), markers=["B01", "C2"])
    fitted.predict([0.5], markers="C1")
    fitted.slip_at(np.linspace(0.2, 1.3, 10))
    fitted.slip_at(np.linspace(0.2, 1.3, 40))
    assert _predict._positions._cache_size() == 1 and _predict._slip._cache_size() == 1
