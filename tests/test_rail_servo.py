"""The rail's carriage servo (app.sim.rail_servo): delay, second-order tracking against its
closed-form ramp lag, limits, and the protective stops with their reasons."""

from __future__ import annotations

import math

import numpy as np
import pytest

from app.config import RailConfig
from app.sim.rail_servo import RailServo

DT = 0.002
RAIL = RailConfig(travel_m=(-1.0, 1.0))


def cosine_move(A_m, T_s, n_hold=500):
    """Set-points from 0 to A_m in T_s, s = A/2 (1 − cos(π t / T)), then held."""
    t = np.arange(int(round(T_s / DT)) + 1) * DT
    return np.concatenate([A_m / 2 * (1 - np.cos(np.pi * t / T_s)), np.full(n_hold, A_m)])


def run(servo, sps):
    out = []
    for sp in sps:
        st = servo.step(sp)
        out.append((st.s_m, st.v_mps, st.a_mps2, st.stopped))
    return np.array(out)


@pytest.mark.parametrize("delay", [0, 1, 3])
def test_tracks_a_smooth_move_with_the_second_order_lag_and_the_delay(delay):
    """Without velocity feedforward a critically damped second-order response trails a ramp
    by 2ζ/ω; the transport delay adds its cycles, and the cycle's own Euler step takes one
    off (the state read after a cycle has moved v·dt on the set-point of that cycle): at the
    move's mid-point (speed at its peak, acceleration zero) the carriage lags by
    v (2ζ/ω + (d − 1)·dt). It ends on the set-point, within the limits."""
    cfg = RAIL.model_copy(update={"delay_cycles": delay, "velocity_feedforward": False})
    servo = RailServo(cfg, DT, 0.0)
    A, T = 0.5, 2.0  # peak 0.39 m/s and 0.62 m/s², inside 1 m/s and 1 m/s²
    sps = cosine_move(A, T)
    x = run(servo, sps)
    assert not x[:, 3].any()
    mid = int(round(T / 2 / DT))
    v_peak = A / 2 * math.pi / T
    w = 2 * math.pi * cfg.bandwidth_hz
    expected = v_peak * (2 * cfg.damping_ratio / w + (delay - 1) * DT)
    assert sps[mid] - x[mid, 0] == pytest.approx(expected, rel=5e-3)  # the move curves
    assert x[-1, 0] == pytest.approx(A, abs=1e-6)
    assert np.abs(x[:, 1]).max() <= cfg.speed_limit_mps
    assert np.abs(x[:, 2]).max() <= cfg.accel_limit_mps2 * (1 + 1e-12)


@pytest.mark.parametrize("delay", [0, 1, 3])
def test_velocity_feedforward_leaves_the_delay_alone(delay):
    """With the set-points' speed fed forward the loop follows a ramp with no error of its
    own: the lag at the mid-point is v (d − 1)·dt, to 2 % of a cycle's travel (the
    default drive: velocity_feedforward = true)."""
    cfg = RAIL.model_copy(update={"delay_cycles": delay})
    assert cfg.velocity_feedforward
    x = run(RailServo(cfg, DT, 0.0), sps := cosine_move(0.5, 2.0))
    v_peak = 0.25 * math.pi / 2.0
    assert sps[500] - x[500, 0] == pytest.approx(v_peak * (delay - 1) * DT,
                                                 abs=0.02 * v_peak * DT)
    assert not x[:, 3].any() and x[-1, 0] == pytest.approx(0.5, abs=1e-6)


def test_the_set_point_acts_after_the_delay():
    servo = RailServo(RAIL.model_copy(update={"delay_cycles": 3}), DT, 0.2)
    x = run(servo, [0.2 + 1e-6] * 5)
    assert (x[:3, 0] == 0.2).all() and x[3, 0] > 0.2


@pytest.mark.parametrize("sps, reason", [
    ([0.5, 1.2], "rail travel end"),
    ([0.5, math.nan], "rail travel end"),
    ([0.5, 0.5 + 0.0021], "rail speed limit"),      # 1.05 m/s in one cycle
    ([0.5, 0.5 + 1e-5], "rail acceleration limit"),  # 0.005 m/s from rest in 2 ms: 2.5 m/s²
])
def test_a_set_point_beyond_a_limit_stops_the_carriage_and_says_why(sps, reason):
    cfg = RAIL.model_copy(update={"delay_cycles": 0, "speed_limit_mps": 1.0,
                                  "accel_limit_mps2": 1.0})
    servo = RailServo(cfg, DT, 0.5)
    servo.step(sps[0])
    assert not servo.stopped
    st = servo.step(sps[1])
    assert st.stopped and st.reason == reason
    s = st.s_m
    run(servo, [0.0] * 10)  # set-points ignored once stopped
    assert servo.state.s_m == pytest.approx(s, abs=1e-12) and servo.state.reason == reason
    servo.reset()
    assert not servo.stopped and servo.state.s_m == s


def test_a_stopped_carriage_brakes_at_the_acceleration_limit():
    cfg = RAIL.model_copy(update={"delay_cycles": 0})
    servo = RailServo(cfg, DT, 0.0)
    sps = cosine_move(0.6, 2.0)[:500]  # stop at t = 1 s, mid-move at 0.47 m/s
    x = run(servo, sps)
    v0 = x[-1, 1]
    servo.step(2.0)  # beyond the travel
    assert servo.state.reason == "rail travel end"
    x = run(servo, [0.0] * 400)
    stop = np.argmax(x[:, 1] == 0.0)
    assert x[stop:, 1].max() == 0.0  # at rest, stays there
    assert stop * DT == pytest.approx(v0 / cfg.accel_limit_mps2 - DT, abs=2 * DT)
    np.testing.assert_array_less(np.abs(x[:, 2]), cfg.accel_limit_mps2 * (1 + 1e-12))
