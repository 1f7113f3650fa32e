"""Contact gate and pair fusion (app/sim/contact_gate.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from app.config import DEFAULT_MATERIALS, merge_overrides
from app.scenarios import load_scenario
from app.sim.contact import BoxContactModel
from app.sim.contact_gate import (
    CHI2_THRESHOLD,
    ContactGate,
    contact_pairs,
    fuse_pair_forces,
    hold_cycles_for,
    newton_consistent,
)
from app.sim.ft_sensor import lowpass_alpha
from app.sim.hand import Push
from app.sim.loop import Emulator

INF = math.inf


def test_the_gate_opens_on_touch_or_on_a_close_approach_only():
    gate = ContactGate(3, margin_m=0.002, hold_cycles=0)
    nearest = np.array([1, 0, -1])
    assert not gate.update(np.array([0.01, 0.01, INF]), nearest).any()  # far
    # closing in within the margin: open; the third body is alone
    np.testing.assert_array_equal(gate.update(np.array([0.0015, 0.0015, INF]), nearest),
                                  [True, True, False])
    # within the margin but moving apart: closed (hold 0)
    assert not gate.update(np.array([0.0018, 0.0018, INF]), nearest).any()
    # touching, even without moving: open
    assert gate.update(np.array([-1e-4, -1e-4, INF]), nearest)[:2].all()
    assert gate.update(np.array([-1e-4, -1e-4, INF]), nearest)[:2].all()


def test_the_gate_holds_open_while_the_delayed_force_arrives():
    gate = ContactGate(2, margin_m=0.001, hold_cycles=3)
    nearest = np.array([1, 0])
    gate.update(np.array([-1e-3, -1e-3]), nearest)  # touching
    opened = [bool(gate.update(np.array([0.01, 0.01]), nearest)[0]) for _ in range(5)]
    assert opened == [True, True, True, False, False]
    np.testing.assert_array_equal(gate.partner, [1, 0])  # who opened it is remembered


def test_hold_covers_the_sensor_delay_and_the_filter_decay():
    alpha = lowpass_alpha(30.0, 500.0)
    n = hold_cycles_for(1, alpha)
    assert (1 - alpha) ** (n - 1) <= 0.05 < (1 - alpha) ** (n - 2)
    assert hold_cycles_for(2, 1.0) == 3  # no filter: the delay and one cycle


def test_a_bad_margin_is_refused():
    with pytest.raises(ValueError, match="margin_m must be >= 0, got -0.1"):
        ContactGate(2, -0.1, 1)


def _forces():
    return np.array([[-3.0, 0.4, 0.1], [2.6, 0.2, -0.3], [1.0, 1.0, 1.0]])


def test_two_carried_mockups_touching_each_other_get_one_estimate():
    f = _forces()
    pairs = contact_pairs(np.array([True, True, False]), np.array([1, 0, -1]),
                          np.ones(3, dtype=bool), np.array([True, True, True]))
    assert pairs == [(0, 1)]
    fuse_pair_forces(f, pairs)
    est = 0.5 * (_forces()[1] - _forces()[0])
    np.testing.assert_allclose(f[1], est)
    np.testing.assert_allclose(f[0], -est)
    np.testing.assert_array_equal(f[2], _forces()[2])  # not touching: untouched


@pytest.mark.parametrize("case", ["one not carried", "partners differ",
                                  "one gate closed", "a third body near one"])
def test_no_pair_when_the_two_are_not_alone(case):
    open_ = np.array([True, True, True])
    nearest = np.array([1, 0, 1])
    alone = np.ones(3, dtype=bool)
    carried = np.array([True, True, True])
    if case == "a third body near one":
        alone[1] = False
    elif case == "one not carried":
        carried[0] = False
    elif case == "partners differ":
        nearest = np.array([1, 2, 0])  # a ring: no two are each other's nearest
    else:
        open_[1] = False
    assert contact_pairs(open_, nearest, alone, carried) == []


def test_newton_consistency_is_a_chi_square_test_against_the_noise():
    """F_a + F_b against Σ_a + Σ_b: equal and opposite within the noise passes, a push
    on one does not; the threshold is the χ²(3) quantile."""
    cov = np.diag([0.25, 0.25, 1.0])  # σ 0.5, 0.5, 1 N
    f_a = np.array([-3.0, 0.1, 0.2])
    assert newton_consistent(f_a, -f_a, cov)
    # just inside / outside the threshold along z (σ 1 N): χ² = s²
    inside, outside = math.sqrt(CHI2_THRESHOLD) - 0.01, math.sqrt(CHI2_THRESHOLD) + 0.01
    assert newton_consistent(f_a, -f_a + [0.0, 0.0, inside], cov)
    assert not newton_consistent(f_a, -f_a + [0.0, 0.0, outside], cov)
    # the same sum along x, where the noise is half as large: refused
    assert not newton_consistent(f_a, -f_a + [inside, 0.0, 0.0], cov)
    # a noiseless pair: trusted to 1 mN (COV_FLOOR_N2), no better
    assert newton_consistent(f_a, -f_a + [1e-3, 0.0, 0.0], np.zeros((3, 3)))
    assert not newton_consistent(f_a, -f_a + [1e-2, 0.0, 0.0], np.zeros((3, 3)))


def _boxes_in_a_row(gap_m: float):
    """Three 0.2 m cubes along x, the middle one ``gap_m`` from each neighbour."""
    model = BoxContactModel([(0.2, 0.2, 0.2)] * 3, [DEFAULT_MATERIALS["sponge"]] * 3)
    poses = []
    for x in (-0.2 - gap_m, 0.0, 0.2 + gap_m):
        T = np.eye(4)
        T[0, 3] = x
        poses.append(T)
    return model, poses


def test_a_body_pressed_between_two_others_is_not_fused():
    """Box 1 touches boxes 0 and 2: its sensor measures both contacts' sum, so handing its
    satellite the estimate of one pair would break the momentum the contacts exchange."""
    model, poses = _boxes_in_a_row(-5e-4)
    clearance, nearest, crowd = model.clearances(poses, 0.001)
    np.testing.assert_array_equal(crowd, [1, 2, 1])
    assert clearance[1] == pytest.approx(-5e-4, abs=1e-9)
    gate = ContactGate(3, 0.001, hold_cycles=2)
    open_ = gate.update(clearance, nearest, crowd)
    assert open_.all()
    np.testing.assert_array_equal(gate.alone, [True, False, True])  # 1 is near two bodies
    assert contact_pairs(open_, gate.partner, gate.alone, np.ones(3, dtype=bool)) == []
    # 1.5 mm apart on one side (beyond the margin): the other pair is alone and fused again
    poses[2][0, 3] += 0.002
    clearance, nearest, crowd = model.clearances(poses, 0.001)
    np.testing.assert_array_equal(crowd, [1, 1, 0])
    open_ = gate.update(clearance, nearest, crowd)
    assert contact_pairs(open_, gate.partner, gate.alone, np.ones(3, dtype=bool)) == [(0, 1)]


def _push_while_touching(noise: bool) -> tuple[dict, list[bool]]:
    """The collision (passivity layer off: it treats the environment as passive and would
    spread an operator's push over both satellites), 20 ms into the contact the operator
    pushes the sponge's mockup sideways, 15 N for 10 ms. (The ODS y impulse of each
    satellite from the push on, whether the loop fused the pair each cycle.)"""
    cfg = merge_overrides(load_scenario("collision"), {"passivity": {"enabled": False}})
    if not noise:
        cfg = merge_overrides(cfg, {"sensor": {"noise_force_N": 0.0, "noise_torque_Nm": 0.0}})
    em = Emulator(cfg)
    em.prepare()
    while not em.interaction.contact_active:  # the test may look; the loop does not
        em.step()
    for _ in range(10):
        em.step()
    start = em.cycles
    em.post(Push(satellite=1, force_R_N=(0.0, 15.0, 0.0), duration_s=0.01))
    fused = []
    for _ in range(40):
        em.step()
        fused.append(bool(em.consistent_pairs))
    assert em.status == "running"
    rows, ix = em.telemetry.rows(), em.telemetry.index
    return {s: rows[start:, ix[f"sat{s}_fy_N"]].sum() * em.dt_s for s in (1, 2)}, fused


@pytest.mark.parametrize("noise", [False, True])
def test_a_push_on_one_mockup_during_the_contact_reaches_its_satellite(noise):
    """The sensors disagree with Newton's third law by the push: the pair is not fused,
    nor projected on the (frictionless) contact's normal, and the pushed satellite gets
    the 0.15 N s sideways (with the data sheet's noise, within what the noise of the
    unfused cycles explains); the other one nothing. Fusing
    regardless would have split it between the two; the projection would have dropped
    it."""
    impulse_y, fused = _push_while_touching(noise)
    assert fused[0] and not any(fused[1:6])  # the push arrives a cycle late (sensor delay)
    if noise:  # each satellite's own noise over the 5 unfused cycles: σ 0.0075 N s
        assert impulse_y[2] == pytest.approx(0.15, abs=3 * 0.0075)
        assert abs(impulse_y[1]) < 3 * 0.0075
    else:
        assert impulse_y[2] == pytest.approx(0.15, rel=1e-3)
        assert abs(impulse_y[1]) < 1e-6


def _gate_state(gate: ContactGate) -> tuple:
    return (list(gate._previous), list(gate._hold), gate.partner.tolist(),
            gate.alone.tolist())


def test_update_apart_is_update_with_no_body_within_the_margin():
    """Through approach, touch, a crowd, the hold counting down and free flight again (at
    rest, before and after): on every cycle in which no body is within the margin,
    update_apart gives the outputs and leaves the state update gives with every clearance
    inf and nothing nearest."""
    general, fast = ContactGate(3, 0.002, hold_cycles=3), ContactGate(3, 0.002, hold_cycles=3)
    nobody = (np.full(3, INF), np.full(3, -1), np.zeros(3, dtype=np.int64))
    cycles = [None, (np.array([0.0015, 0.0015, INF]), np.array([1, 0, -1]), [1, 1, 0]),
              None, None,  # the hold counts down in free flight
              (np.array([-1e-4, -2e-4, 0.001]), np.array([1, 2, 1]), [1, 2, 1]),  # a crowd
              None, (np.array([0.0019, 0.0019, INF]), np.array([1, 0, -1]), [1, 1, 0]),
              None, None, None, None, None]
    held_far = 0  # free-flight cycles in which a gate was still held open
    for inputs in cycles:
        if inputs is None:
            expected, got = general.update(*nobody), fast.update_apart()
            held_far += bool(expected.any())
        else:
            expected = general.update(inputs[0], inputs[1], np.array(inputs[2]))
            got = fast.update(inputs[0], inputs[1], np.array(inputs[2]))
        assert got.dtype == expected.dtype and got.tolist() == expected.tolist()
        assert _gate_state(fast) == _gate_state(general)
    assert held_far == 6  # 2 after the approach, 1 after the crowd, 3 at the end
    assert fast._at_rest  # the last cycles took update_apart's shortest way, at rest


def test_the_loop_s_free_flight_shortcut_gives_what_the_general_path_gives():
    """The collision through its contact and the gates' hold after it, cycle by cycle:
    the loop with the bounding-sphere shortcuts (BoxContactModel.apart) and the loop
    measuring every pair (apart never true) record the same telemetry bit for bit and
    keep the same gate state and contact kinematics."""
    emulators = [Emulator(load_scenario("collision")) for _ in range(2)]
    general = emulators[1]
    general.lab_geometry.apart = lambda T_W_C, within_m=0.0: False
    for em in emulators:
        em.prepare()
    free_cycles = contact_cycles = 0
    for _ in range(1700):
        free = emulators[0].lab_geometry.apart(emulators[0].bodies_W().T_W_C,
                                               emulators[0].gate.margin_m)
        for em in emulators:
            em.step()
        free_cycles += free
        contact_cycles += emulators[0].interaction.contact_active
        fast = emulators[0]
        assert _gate_state(fast.gate) == _gate_state(general.gate)
        assert fast._contact_kinematics == general._contact_kinematics
        assert fast.interaction.touching == general.interaction.touching
        assert fast.interaction.contact_active == general.interaction.contact_active
    assert not general.lab_geometry.apart(general.bodies_W().T_W_C)  # still the general path
    rows = [em.telemetry.rows() for em in emulators]
    assert rows[0].tobytes() == rows[1].tobytes()
    assert free_cycles > 1000 and contact_cycles > 30
