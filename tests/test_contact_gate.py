"""Contact gate and pair fusion (app/sim/contact_gate.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

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
                             np.array([True, True, True]), np.zeros(3, dtype=bool))
    assert fused == [(0, 1)]
    est = 0.5 * (_forces()[1] - _forces()[0])
    np.testing.assert_allclose(f[1], est)
    np.testing.assert_allclose(f[0], -est)
    np.testing.assert_array_equal(f[2], _forces()[2])  # not touching: untouched


@pytest.mark.parametrize("case", ["hand on one", "one not carried", "partners differ",
                                  "one gate closed"])
def test_no_fusion_when_the_pair_is_not_alone(case):
    open_ = np.array([True, True, True])
    nearest = np.array([1, 0, 1])
    carried = np.array([True, True, True])
    hand = np.zeros(3, dtype=bool)
    if case == "hand on one":
        hand[1] = True
    elif case == "one not carried":
        carried[0] = False
    elif case == "partners differ":
        nearest = np.array([1, 2, 0])  # a ring: no two are each other's nearest
    else:
        open_[1] = False
    f = _forces()
    assert fuse_pair_forces(f, open_, nearest, carried, hand) == []
    np.testing.assert_array_equal(f, _forces())
