"""Contact gate and pair fusion (app/sim/contact_gate.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from app.config import DEFAULT_MATERIALS
from app.sim.contact import BoxContactModel
from app.sim.contact_gate import ContactGate, fuse_pair_forces, hold_cycles_for
from app.sim.ft_sensor import lowpass_alpha

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
    fused = fuse_pair_forces(f, np.array([True, True, False]), np.array([1, 0, -1]),
                             np.ones(3, dtype=bool), np.array([True, True, True]),
                             np.zeros(3, dtype=bool))
    assert fused == [(0, 1)]
    est = 0.5 * (_forces()[1] - _forces()[0])
    np.testing.assert_allclose(f[1], est)
    np.testing.assert_allclose(f[0], -est)
    np.testing.assert_array_equal(f[2], _forces()[2])  # not touching: untouched


@pytest.mark.parametrize("case", ["hand on one", "one not carried", "partners differ",
                                  "one gate closed", "a third body near one"])
def test_no_fusion_when_the_pair_is_not_alone(case):
    open_ = np.array([True, True, True])
    nearest = np.array([1, 0, 1])
    alone = np.ones(3, dtype=bool)
    carried = np.array([True, True, True])
    hand = np.zeros(3, dtype=bool)
    if case == "a third body near one":
        alone[1] = False
    elif case == "hand on one":
        hand[1] = True
    elif case == "one not carried":
        carried[0] = False
    elif case == "partners differ":
        nearest = np.array([1, 2, 0])  # a ring: no two are each other's nearest
    else:
        open_[1] = False
    f = _forces()
    assert fuse_pair_forces(f, open_, nearest, alone, carried, hand) == []
    np.testing.assert_array_equal(f, _forces())


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
    f = _forces()
    assert fuse_pair_forces(f, open_, gate.partner, gate.alone, np.ones(3, dtype=bool),
                            np.zeros(3, dtype=bool)) == []
    np.testing.assert_array_equal(f, _forces())
    # 1.5 mm apart on one side (beyond the margin): the other pair is alone and fused again
    poses[2][0, 3] += 0.002
    clearance, nearest, crowd = model.clearances(poses, 0.001)
    np.testing.assert_array_equal(crowd, [1, 1, 0])
    open_ = gate.update(clearance, nearest, crowd)
    assert fuse_pair_forces(f, open_, gate.partner, gate.alone, np.ones(3, dtype=bool),
                            np.zeros(3, dtype=bool)) == [(0, 1)]
