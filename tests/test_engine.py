"""The contact-dynamics engine (fitlug.sim.engine) against physics it must obey.

The engine is a test source for the model, so its own figures are checked here against laws
that owe nothing to fitlug's model: Newton's second law on the chassis at cruise, the power
the motor gives against what the belt delivers, the chain's travel per wheel radian, the
stick of the lug tips, and the brush law (a stuck lug's shear grows by s per unit of belt
travel). One coarse but stable case (125 us step, 200 mm/s), about 10-15 s on one core.
"""

from __future__ import annotations

import json
import math

import pytest

pytest.importorskip("mujoco")


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    from fitlug.sim.engine import EngineCase, simulate_engine

    case = EngineCase(name="test", timestep_s=125e-6, v_belt_mm_s=200.0, rest_s=0.1,
                      ramp_s=0.5, cruise_s=2.4, settle_s=0.3)
    out = tmp_path_factory.mktemp("engine")
    truth = simulate_engine(case, str(out), seed=3)
    return case, truth, out


def test_force_balance_at_cruise(run):
    # at cruise (mean acceleration ~0) the ground's horizontal push on the tips and the
    # lug springs' push on the chain both equal the rolling resistance plus the drawbar
    case, tr, _ = run
    load = case.c_rr * tr["rig"]["mass_kg"] * 9.81 + case.drawbar_pull_N
    assert tr["traction_ground_N"] == pytest.approx(load, rel=0.03)
    assert tr["traction_springs_N"] == pytest.approx(load, rel=0.05)


def test_power(run):
    # the motor gives at least what the belt delivers (F v_belt = towing + the slip's loss)
    # and the rest is lost to the chain's impacts on the wheels and the contacts' creep
    _, tr, _ = run
    ratio = tr["power_motor_W"] / tr["power_traction_W"]
    assert 0.98 < ratio < 1.5


def test_chain_travels_p_over_2asin_per_wheel_radian(run):
    # a polygon chain on a wheel of pitch radius R travels p / (2 asin(p / 2R)) per radian;
    # the wheel drives it by friction, so the chain may creep a little behind, never ahead
    case, tr, _ = run
    r_eff = case.link_pitch_mm / (2 * math.asin(case.link_pitch_mm / (2 * case.wheel_radius_mm)))
    assert tr["v_wheel_times_r_eff_mm_s"] == pytest.approx(case.v_belt_mm_s, rel=0.01)
    ratio = tr["v_belt_mm_s"] / tr["v_wheel_times_r_eff_mm_s"]
    assert 0.97 < ratio < 1.003
    assert case.r_eff_mm == pytest.approx(r_eff)


def test_slip_is_a_slip_and_steady(run):
    _, tr, _ = run
    assert 0.005 < tr["slip"] < 0.2
    per = tr["slip_per_contact_period"]
    assert len(per) >= 2
    assert max(per) - min(per) < 0.25 * tr["slip"]


def test_tips_hold_still_on_the_ground(run):
    # over the middle of each contact the pitch line drifts rearward by s * travel; a
    # lug tip that sticks stays put (well under a fifth of that)
    _, tr, _ = run
    assert tr["contact_episodes"] >= 3
    assert abs(tr["tip_drift_in_contact_mm"]) < 0.2 * tr["pitch_line_stall_in_contact_mm"]
    assert tr["tip_contacts_at_friction_limit"] < 0.05


def test_brush_law_shear_grows_by_the_slip(run):
    # a stuck lug's shear grows by the slip per unit belt travel: (n-1) dl'/L = s where the
    # lugs stick; compared over the same stretches of time
    _, tr, _ = run
    assert tr["slip_from_shear_growth"] == pytest.approx(tr["slip_over_the_same_contacts"],
                                                         rel=0.15)
    # and the rearmost lug carries more than the brush's s*L: it also shears as its link
    # turns up round the rear wheel
    assert tr["liftoff_shear_mm"] > tr["slip"] * tr["rig"]["L_mm"]


def test_lugs_in_contact_and_the_rig(run):
    _, tr, _ = run
    n = tr["rig"]["n"]
    assert n == round(tr["wheel_distance_mm"] / tr["rig"]["lug_pitch_mm"]) + 1
    assert n - 2 <= tr["lugs_in_contact"]["min"] <= tr["lugs_in_contact"]["max"] <= n + 1


def test_recording_reads_back(run):
    from fitlug.io import read_rig, read_trajectories

    case, tr, out = run
    rec = read_trajectories(str(out / "trajectories.csv"))
    assert set(rec.markers) == {"B01", "B02", "B03", "B04", "C1", "C2"}
    rig = read_rig(str(out / "rig.toml"))
    assert rig.load_bearing_length_mm == tr["rig"]["L_mm"]
    assert rig.lugs_in_contact == tr["rig"]["n"]
    truth = json.loads((out / "truth.json").read_text())
    assert truth["slip"] == pytest.approx(tr["slip"])
    assert truth["settings"]["k_N_per_mm"] == case.k_N_per_mm
