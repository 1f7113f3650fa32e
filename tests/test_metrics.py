"""Collision metrics (app/metrics.py): what the mockups went through, against closed forms."""

from __future__ import annotations

import numpy as np
import pytest

from app.config import merge_overrides
from app.headless import run_scenario
from app.scenarios import load_scenario


@pytest.fixture(scope="module")
def ideal():
    return run_scenario(load_scenario("collision"), mode="ideal", duration_s=6.0)


@pytest.fixture(scope="module")
def hil():
    return run_scenario(load_scenario("collision"), mode="hil", duration_s=6.0)


def test_ideal_contact_energy_is_the_kinetic_energy_the_impact_lost(ideal):
    coll = ideal.metrics["collision"]
    e, m_red, v0 = coll["restitution"], 0.5, 0.16
    assert coll["contact_energy_J"] == pytest.approx(0.5 * m_red * v0**2 * (1 - e * e),
                                                     rel=1e-3)


def test_ideal_true_impulse_is_what_the_ods_received_and_the_momentum_change(ideal):
    coll = ideal.metrics["collision"]
    for name in ("sat1", "sat2"):
        np.testing.assert_allclose(coll["true_impulse_Ns"][name], coll["impulse_Ns"][name],
                                   rtol=0, atol=1e-12)
    j = np.array(coll["true_impulse_Ns"]["sat2"])
    assert j[0] == pytest.approx(0.5 * 0.16 * (1 + coll["restitution"]), rel=1e-3)
    assert coll["true_impulse_ratio"] == {"sat1": 1.0, "sat2": 1.0}
    assert coll["restitution_error"] == 0.0


def test_ideal_peak_force_and_duration_of_the_hunt_crossley_impact(ideal):
    from scipy.integrate import solve_ivp

    k = 1 / (1 / 500.0 + 1 / 2e4)
    c = (20.0 / 500.0 + 0.5 / 2e4) * k

    def rhs(_t, s):
        return [s[1], -max(0.0, k * s[0] * (1 + c * s[1])) / 0.5 if s[0] > 0 else 0.0]

    def apart(_t, s):
        return s[0]

    apart.terminal, apart.direction = True, -1
    sol = solve_ivp(rhs, (0, 1), [0.0, 0.16], rtol=1e-10, atol=1e-14, events=apart,
                    dense_output=True, max_step=1e-4)
    t = np.linspace(0, sol.t_events[0][0], 4000)
    d, dd = sol.sol(t)
    peak = np.max(np.maximum(0.0, k * d * (1 + c * dd)))
    coll = ideal.metrics["collision"]
    assert coll["peak_force_N"] == pytest.approx(peak, rel=0.01)
    # the force lasts until it reaches zero (no pull): within two 2 ms cycles of the ODE's
    last_force = t[np.nonzero(k * d * (1 + c * dd) > 0)[0][-1]]
    assert abs(coll["contact_duration_s"] - last_force) <= 2 * 0.002


def test_a_contact_under_the_deadband_is_named_unless_the_gate_lifts_it(ideal):
    coll = ideal.metrics["collision"]
    assert coll["peak_force_N"] < 4.0
    assert coll["warnings"] == []  # the scenario's contact gate lifts the deadband
    gateless = merge_overrides(load_scenario("collision"), {"wrench": {"contact_gate": False}})
    named = run_scenario(gateless, mode="ideal", duration_s=6.0).metrics["collision"]
    assert named["warnings"] == [
        f"the ideal contact peaks at {coll['peak_force_N']:.1f} N, under the F/T force "
        "deadband of 4 N: the sensor cannot see it whole"]
    cfg = merge_overrides(gateless, {"wrench": {"deadband_force_N": 0.0}})
    quiet = run_scenario(cfg, mode="ideal", duration_s=6.0).metrics["collision"]
    assert quiet["warnings"] == []


def test_hil_metrics_compare_the_actual_mockups_with_the_ideal_run(hil, ideal):
    coll, ref = hil.metrics["collision"], ideal.metrics["collision"]
    ja, jb = (np.array(coll["true_impulse_Ns"][n]) for n in ("sat1", "sat2"))
    np.testing.assert_allclose(ja + jb, 0.0, atol=1e-12)  # action and reaction on the mockups
    assert coll["restitution_ideal"] == ref["restitution"]
    assert coll["restitution_error"] == pytest.approx(
        (coll["restitution"] - ref["restitution"]) / ref["restitution"])
    assert coll["true_impulse_ratio"]["sat2"] == pytest.approx(
        np.linalg.norm(jb) / np.linalg.norm(ref["true_impulse_Ns"]["sat2"]))
    assert coll["contact_energy_J"] > 0.0  # a dissipative contact absorbs energy
    # the sensor noise's impulse over the ideal contact, on both satellites (1 kg each)
    dv = 5.0 / 3.0 * np.sqrt(ref["contact_duration_s"] * 0.002) * np.sqrt(2.0)
    spread = dv / (ref["approach_speed_mps"] * ref["restitution"])
    assert ref["approach_speed_mps"] == pytest.approx(0.16, rel=1e-3)
    assert coll["warnings"] == [
        f"the F/T noise (1.7 N per sample) adds about {dv * 1e3:.1f} mm/s to the satellites' "
        f"relative velocity over the {1e3 * ref['contact_duration_s']:.0f} ms contact: one "
        f"run's restitution is uncertain by up to about ±{100 * spread:.0f} %"]
