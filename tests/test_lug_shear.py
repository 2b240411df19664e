"""The marker on the lug (MODEL.md §2's h and tau, fitlug's `lug_shear`).

Truth from tests/independent_sim.py, which steps each lug's shear in time as the text says
it (0 at touch-down, dd/dt = s v_t on the run, dd/dt = -d/tau after lift-off), not as the
model computes it (the running integral of s dpsi read off the integration's nodes)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import independent_sim as isim
from reference_jit import jit_reference
from fitlug import explain, fit
from fitlug.fit._problem import build_problem
from fitlug.fit._residuals import Packing, jacobian, residuals
from fitlug.model import predict

SHORT = dict(duration=3.0, t_acc=(0.3, 1.1), t_dec=(2.0, 2.8), fps=100.0)


@pytest.fixture(scope="module")
def tip_recording():
    """Markers on the lug tips (h = 0), shear relaxing in 40 ms."""
    return isim.make(5, marker_h=0.0, shear_tau=0.04, **SHORT)


def test_identity_at_h_one_and_exact_jacobian():
    rec, rig, _ = isim.make(1, **SHORT)
    prob = build_problem(rec, rig)
    prob_s, p = prob.with_effects(("lug_shear",), prob.p0)
    base = predict(prob.p0, prob.lay)
    with_shear = predict(p, prob_s.lay)
    for a, b in zip(base, with_shear):  # h = 1: today's model exactly
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    # off identity, the structured Jacobian (sigma0 forward with the rest) equals jacfwd
    p = {**p, "shear_h": jnp.asarray(0.3), "shear_tau": jnp.asarray(0.03),
         "s0": jnp.asarray(0.05)}
    free = ["v", "s0", "beta", "R", "D", "x_off", "sigma0", "shear_h", "shear_tau"]
    pk = Packing.of(p, free)
    flat = pk.pack(p)
    fixed = {k: v for k, v in p.items() if k not in pk.names}
    J = np.asarray(jacobian(flat, fixed, prob_s.lay, prob_s.obs, pk))
    J_ref = np.asarray(jit_reference(jax.jacfwd(
        lambda f: residuals(pk.unpack(f, fixed), prob_s.lay, prob_s.obs)))(flat))
    scale = np.max(np.abs(J_ref), axis=0)
    np.testing.assert_allclose(J / scale, J_ref / scale, atol=1e-9)


def test_tip_markers_found_and_fitted(tip_recording):
    """Tip markers stand still in contact: the base model (h = 1) cannot fit them
    (chi2/dof in the thousands). The explanation finds the marker's place on the lug as the
    base model's h and tau (not as left-out physics: verdict none), fits to the noise, and
    holds the slip within 3 sigma of the truth, h and tau as simulated."""
    rec, rig, truth = tip_recording
    base = fit(rec, rig)
    assert base.chi2_per_dof > 50
    ex = explain(base)
    assert ex.verdict == "none" and ex.effects == []
    assert [s.effect for s in ex.base_steps] == ["lug_shear"]
    assert "lug_shear" in ex.final.effects
    assert ex.final.chi2_per_dof < 1.15
    # the base model's misfit at lift-off is no glitch: the final model's rounds give
    # the samples back (the generator has none)
    assert not ex.final.problem.init_info.get("glitches")
    s = ex.final.quantities["slip"]
    assert abs(s.value - truth["slip"]) < 3 * s.std, (s.value, s.std, truth["slip"])
    p = ex.final.effect_params("lug_shear")
    assert abs(p["h"]) < 0.02 and abs(p["tau_s"] - 0.04) < 0.008, p
    mol = ex.to_json()["marker_on_lug"][0]
    assert "on the lug tips" in mol["reading"]


def test_a_drift_in_contact_is_not_claimed_as_the_markers_height_alone():
    """A marker at height h on a lug whose tip slides at r of the creep drifts at
    r + h (1 - r): the engine's crawler at friction 0.16 and 0.12 (data/engine/mu016,
    mu012: markers on the tips, a quarter and two thirds of the tip contacts at the
    friction limit) fitted h 0.49 and 0.71, read as "half-way up the lugs" and "near the
    belt's pitch line". Above the tips the reading names both: the height where the tips
    hold, or the tips sliding; on the tips (where they hold still) it names the tips."""
    from fitlug.explain._explanation import base_reading

    class Res:
        def __init__(self, h):
            self.h = h

        def effect_params(self, eid):
            assert eid == "lug_shear"
            return {"h": self.h, "tau_s": 0.08}

    for h, where in ((0.49, "half-way up the lugs"), (0.71, "near the belt's pitch line"),
                     (0.25, "near the lug tips")):
        s = base_reading(Res(h))
        assert where in s and "tips slide" in s and f"{h:.2f} of the pitch line's creep" in s
    s = base_reading(Res(0.03))
    assert "on the lug tips" in s and "stand still" in s and "slide" not in s
