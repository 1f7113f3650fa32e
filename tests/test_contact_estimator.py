"""The contact-aware estimator (app/sim/contact_estimator.py): the measured force on the
contact's friction cone, its moment at the contact point; end to end in the collision."""

from __future__ import annotations

import numpy as np
import pytest

from app.config import merge_overrides
from app.runs.headless import run_scenario
from app.scenarios import load_scenario
from app.sim.contact_estimator import cone_projection, contact_wrench_W

N = np.array([1.0, 0.0, 0.0])
NO_NOISE = {"sensor": {"noise_force_N": 0.0, "noise_torque_Nm": 0.0}}


def test_a_push_inside_the_cone_passes_unchanged():
    f = np.array([3.0, 0.5, -0.4])  # |F_t| = 0.64 < 0.3 * 3
    np.testing.assert_allclose(cone_projection(f, N, 0.3), f)


def test_the_tangential_part_is_clamped_to_mu_times_the_normal_part():
    f = np.array([2.0, 3.0, 4.0])  # |F_t| = 5
    out = cone_projection(f, N, 0.25)
    assert out[0] == 2.0
    np.testing.assert_allclose(out[1:], [0.3, 0.4])  # 0.5 N along the same direction
    np.testing.assert_allclose(cone_projection(f, N, 0.0), [2.0, 0.0, 0.0])  # frictionless


def test_a_pull_becomes_zero():
    np.testing.assert_array_equal(cone_projection(np.array([-0.5, 2.0, 0.0]), N, 1.0),
                                  np.zeros(3))


def test_the_torque_is_the_moment_of_the_estimate_at_the_contact_point():
    com = np.array([0.1, 0.2, 0.3])
    f, t = contact_wrench_W(np.array([3.0, 1.0, 0.0]), N, com + [0.1, 0.0, 0.0], com, 0.0)
    np.testing.assert_allclose(f, [3.0, 0.0, 0.0])
    np.testing.assert_allclose(t, np.zeros(3), atol=1e-15)  # through the COM: no torque
    f, t = contact_wrench_W(np.array([3.0, 1.0, 0.0]), N, com + [0.1, 0.02, 0.0], com, 0.5)
    np.testing.assert_allclose(t, np.cross([0.1, 0.02, 0.0], f))


def _collision(*overrides: dict):
    cfg = load_scenario("collision")
    for o in overrides:
        cfg = merge_overrides(cfg, o)
    return cfg


@pytest.fixture(scope="module")
def head_on():
    """seed 0, 4.5 s (the contact is at 3.1 s): noiseless, default noise, default noise
    without the estimator."""
    runs = {}
    for name, over in (("no noise", NO_NOISE), ("noise", {}),
                       ("noise, no estimator", {"wrench": {"contact_estimator": False}})):
        runs[name] = run_scenario(_collision(over), duration_s=4.5, with_ideal=False)
    return runs


def test_a_noiseless_head_on_contact_stays_on_its_normal(head_on):
    coll = head_on["no noise"].metrics["collision"]
    for ratio in coll["off_normal_ratio"].values():
        assert ratio <= 0.01
    assert not any("across the contact's normal" in w for w in coll["warnings"])


def test_the_noise_across_the_normal_no_longer_reaches_the_satellites(head_on):
    """Frictionless: nothing across the normal passes the cone; without the estimator the
    noise integrated over the open gate does (within what the noise explains: no
    warning)."""
    with_ = head_on["noise"].metrics["collision"]
    without = head_on["noise, no estimator"].metrics["collision"]
    assert max(with_["off_normal_ratio"].values()) < 1e-4  # the geometry's normal vs the true
    assert min(without["off_normal_ratio"].values()) > 0.05
    assert not any("across the contact's normal" in w for w in with_["warnings"])


def _spin_gained(run, sat: int) -> float:
    rows, ix = run.emulator.telemetry.rows(), run.emulator.telemetry.index
    w = rows[:, [ix[f"sat{sat}_w{a}_radps"] for a in "xyz"]]
    return float(np.linalg.norm(w[-1] - w[0]))


def test_a_head_on_contact_through_the_coms_does_not_spin_the_cubesat(head_on):
    """Over the 4.5 s the ideal cubesat gains 6e-6 rad/s of spin (gravity gradient); in
    hil it gains no more than 1e-5 with the estimator (the contact's torque is the
    moment of the estimated force at the contact point: none, through the COMs), and
    over 1e-4 rad/s without it (the torque noise through the open gate)."""
    ideal = run_scenario(_collision(), mode="ideal", duration_s=4.5, with_ideal=False)
    assert _spin_gained(ideal, 1) < 1e-5
    assert _spin_gained(head_on["noise"], 1) < 1e-5
    assert _spin_gained(head_on["noise, no estimator"], 1) > 1e-4


def _oblique(mu: float):
    """The collision with both surfaces at friction mu and the satellites sliding past each
    other at 0.1 m/s (they meet centred at the contact, 3.1 s in), without noise."""
    cfg = _collision(NO_NOISE)
    sats = [s.model_copy(update={"position_m": (s.position_m[0], -sign * 0.155, 0.0),
                                 "velocity_mps": (s.velocity_mps[0], sign * 0.05, 0.0)})
            for s, sign in zip(cfg.satellites, (1, -1), strict=True)]
    mats = {k: m.model_copy(update={"friction": mu}) for k, m in cfg.materials.items()}
    return cfg.model_copy(update={"satellites": sats, "materials": mats})


def test_with_friction_the_odss_tangential_impulse_follows_the_ideal_one():
    """μ = 0.3, sliding throughout: the ideal contact's tangential impulse is μ times its
    normal one; the estimator passes the hil run's within 1 % of it (its cone is not a
    frictionless simulation's)."""
    ideal = run_scenario(_oblique(0.3), mode="ideal", duration_s=4.0,
                         with_ideal=False).metrics["collision"]
    hil = run_scenario(_oblique(0.3), duration_s=4.0, with_ideal=False).metrics["collision"]
    j_ideal, j_hil = np.array(ideal["impulse_Ns"]["sat2"]), np.array(hil["impulse_Ns"]["sat2"])
    assert j_ideal[1] == pytest.approx(0.3 * j_ideal[0], rel=2e-3)
    assert j_hil[1] == pytest.approx(j_ideal[1], rel=0.01)
    assert j_hil[0] == pytest.approx(j_ideal[0], rel=0.01)


def test_the_torque_is_the_array_cross_product_bit_for_bit():
    """r × f on plain floats gives np.cross's products and differences to the last bit."""
    rng = np.random.default_rng(33)
    for _ in range(2000):
        force, point, com = rng.normal(0.0, 5.0, 3), *rng.normal(0.0, 0.3, (2, 3))
        normal = rng.normal(size=3)
        normal /= np.linalg.norm(normal)
        f, t = contact_wrench_W(force, normal, point, com, 0.3)
        assert t.tobytes() == np.cross(point - com, f).tobytes()
