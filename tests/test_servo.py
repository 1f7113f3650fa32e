"""Simulated UR10e position servo: tracking, limits, transport delay, protective stops."""

from __future__ import annotations

import math

import numpy as np
import pytest

from app.config import RobotConfig, ServoConfig
from app.sim.servo import SafetyBox, UR10eServo, safety_box_for_robot
from app.sim.ur10e import SPEED_LIMITS_RADPS, UR10e

DT = 0.002
Q0 = np.array([0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0])
EPS = 1e-9


def aggressive_setpoints(n=3000, seed=1):
    """Set-points whose velocity jumps between +-0.95 x limit every few cycles."""
    rng = np.random.default_rng(seed)
    sp, out = Q0.copy(), []
    vel = np.zeros(6)
    for k in range(n):
        if k % 7 == 0:
            vel = rng.choice([-0.95, 0.95], size=6) * SPEED_LIMITS_RADPS
        sp = sp + vel * DT
        out.append(sp.copy())
    return out


@pytest.mark.parametrize("delay", [0, 1, 3])
def test_never_exceeds_speed_or_acceleration_limits(delay):
    cfg = ServoConfig(delay_cycles=delay, bandwidth_hz=50.0)
    servo = UR10eServo(cfg, DT, Q0)
    q_prev, qd_prev = Q0.copy(), np.zeros(6)
    peak_qd, peak_qdd = np.zeros(6), 0.0
    for sp in aggressive_setpoints():
        s = servo.step(sp)
        assert not s.stopped, s.reason
        qd_fd = (s.q_rad - q_prev) / DT
        qdd_fd = (s.qd_radps - qd_prev) / DT
        assert np.all(np.abs(qd_fd) <= SPEED_LIMITS_RADPS + EPS)
        assert np.all(np.abs(qdd_fd) <= cfg.accel_limit_radps2 + EPS)
        assert np.allclose(qd_fd, s.qd_radps) and np.allclose(qdd_fd, s.qdd_radps2)
        peak_qd = np.maximum(peak_qd, np.abs(s.qd_radps))
        peak_qdd = max(peak_qdd, float(np.abs(s.qdd_radps2).max()))
        q_prev, qd_prev = s.q_rad.copy(), s.qd_radps.copy()
    # the sequence really pushes the limits
    assert peak_qdd == pytest.approx(cfg.accel_limit_radps2)
    assert np.all(peak_qd > 0.5 * SPEED_LIMITS_RADPS)


def test_second_order_step_response_and_delay():
    cfg = ServoConfig(delay_cycles=2, bandwidth_hz=10.0, accel_limit_radps2=1e3)
    servo = UR10eServo(cfg, DT, Q0)
    sp = Q0 + 0.002  # small step: implied speed 1 rad/s, within limits
    traj = [servo.step(sp).q_rad[0] for _ in range(400)]
    assert traj[0] == Q0[0] and traj[1] == Q0[0]  # transport delay: 2 cycles
    assert traj[2] != Q0[0]
    assert traj[-1] == pytest.approx(sp[0], abs=1e-7)  # settles on the set-point
    assert max(traj) <= sp[0] + 1e-6  # critically damped: no overshoot
    # half-way after ~1.68 / (2 pi f) s for a critically damped 2nd-order step
    t_half = (np.argmax(np.array(traj) >= Q0[0] + 0.001) - 2) * DT
    assert t_half == pytest.approx(1.68 / (2 * math.pi * 10.0), rel=0.15)


def test_speed_limit_stop_names_the_joint():
    servo = UR10eServo(ServoConfig(delay_cycles=0), DT, Q0)
    sp = Q0.copy()
    sp[2] += 0.01  # 5 rad/s > 180 deg/s
    s = servo.step(sp)
    assert s.stopped and s.reason == "joint 3 speed limit"


def test_speed_just_below_limit_is_accepted():
    servo = UR10eServo(ServoConfig(delay_cycles=0), DT, Q0)
    sp = Q0 + 0.999 * SPEED_LIMITS_RADPS * DT
    assert not servo.step(sp).stopped


def test_position_limit_stop_names_the_joint():
    q = Q0.copy()
    q[1] = 2 * math.pi - 0.001
    servo = UR10eServo(ServoConfig(delay_cycles=1), DT, q)
    sp = q.copy()
    sp[1] += 0.002  # 1 rad/s: fine for speed, but beyond +2 pi
    assert not servo.step(sp).stopped  # still in the transport delay
    s = servo.step(sp)
    assert s.stopped and s.reason == "joint 2 position limit"


def test_tcp_safety_volume_stop():
    ur = UR10e()
    robot = RobotConfig(name="r", satellite="s", base_position_m=(0.0, 0.0, 0.5))
    box = safety_box_for_robot(robot, ur)
    p0 = box.tcp_position_W(Q0)
    assert box.contains(Q0)
    tight = SafetyBox(p0 - 0.05, p0 + 0.05, box.tcp_position_W)
    servo = UR10eServo(ServoConfig(delay_cycles=0), DT, Q0, safety=tight)
    sp = Q0.copy()
    accepted = 0
    while accepted < 2000:
        sp[0] += 0.5 * DT  # swing the base at 0.5 rad/s
        if servo.step(sp).stopped:
            break
        accepted += 1
    assert servo.reason == "TCP left safety volume"
    assert np.linalg.norm(tight.tcp_position_W(sp) - p0, ord=np.inf) > 0.05
    assert accepted > 10  # the earlier set-points were inside and accepted


def test_safety_box_uses_base_pose_and_mounting():
    ur = UR10e()
    robot = RobotConfig(name="r", satellite="s", base_position_m=(0.3, -0.2, 1.0),
                        mockup_offset_m=(0.0, 0.0, 0.1))
    box = safety_box_for_robot(robot, ur)
    T_F_C = np.eye(4)
    T_F_C[2, 3] = 0.1
    assert np.allclose(box.tcp_position_W(Q0), ur.tcp_pose(Q0, T_F_C)[:3, 3] + (0.3, -0.2, 1.0))
    floor = RobotConfig(name="r", satellite="s", safety_box_min_m=(-1.5, -1.5, 0.5))
    q_low = Q0.copy()
    q_low[1] = 0.3  # upper arm tilted down: TCP below z = 0.5 m
    assert not safety_box_for_robot(floor, ur).contains(q_low)


def test_stopped_arm_decelerates_and_stays_halted_until_reset():
    cfg = ServoConfig(delay_cycles=0)
    servo = UR10eServo(cfg, DT, Q0)
    sp = Q0.copy()
    for _ in range(300):  # get joint 1 moving at 1.5 rad/s
        sp[0] += 1.5 * DT
        servo.step(sp)
    assert servo.state.qd_radps[0] > 1.4
    bad = sp.copy()
    bad[3] += 1.0
    s = servo.step(bad)
    assert s.stopped and s.reason == "joint 4 speed limit"
    qd_prev = s.qd_radps.copy()
    for _ in range(100):  # keep sending (valid) set-points: they are ignored
        sp[0] += 1.5 * DT
        s = servo.step(sp)
        assert np.all(np.abs(s.qd_radps - qd_prev) <= cfg.accel_limit_radps2 * DT + EPS)
        assert np.all(np.abs(s.qd_radps) <= np.abs(qd_prev) + EPS)  # only slows down
        qd_prev = s.qd_radps.copy()
    assert np.all(s.qd_radps == 0.0)
    q_halt = s.q_rad.copy()
    for _ in range(50):
        s = servo.step(q_halt + 0.001)
        assert s.stopped and s.reason == "joint 4 speed limit"
        assert np.array_equal(s.q_rad, q_halt)
    servo.reset()
    assert not servo.stopped and servo.reason == ""
    for _ in range(200):
        s = servo.step(q_halt + 0.001)
    assert not s.stopped
    assert np.allclose(s.q_rad, q_halt + 0.001, atol=1e-6)
