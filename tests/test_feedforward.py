"""The servo feedforward (app/sim/feedforward.py): the inverse of the servo's tracking law."""

from __future__ import annotations

import math

import numpy as np
import pytest

from app.config import ConfigError, ServoConfig, assignment_override, merge_overrides
from app.scenarios import load_scenario
from app.sim.feedforward import (
    ServoFeedforward,
    send,
    servo_feedforward,
    servo_feedforward_enabled,
)
from app.sim.servo import UR10eServo, tracking_gains

DT = 0.002
Q0 = np.array([0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0])
MAX_STEP = 0.95 * DT * np.array(ServoConfig().speed_limits_radps)
SERVOJ = ServoConfig(model="servoj", lookahead_time_s=0.03, gain=1200.0)


def _smooth(n: int = 3000, cutoff_hz: float = 1.0, rms_rad: float = 0.05) -> np.ndarray:
    """A smooth random joint trajectory from rest: white noise through three first-order
    low-passes of ``cutoff_hz`` (peak speed 0.42 rad/s, a fifth of the joint's limit)."""
    x = np.random.default_rng(7).standard_normal(n)
    a = 1.0 - math.exp(-2.0 * math.pi * cutoff_hz * DT)
    for _ in range(3):
        y, out = 0.0, np.empty(n)
        for k in range(n):
            y += a * (x[k] - y)
            out[k] = y
        x = out
    return rms_rad * (x - x[0]) / x.std()


def _follow(cfg: ServoConfig, q_d: np.ndarray, feedforward: bool) -> tuple[np.ndarray, UR10eServo]:
    """Joint 1 after each servo step, the desired trajectory ``q_d`` (joint 1, around Q0)
    sent as it is or through the feedforward."""
    servo = UR10eServo(cfg, DT, Q0)
    ff = ServoFeedforward(*tracking_gains(cfg), DT, MAX_STEP, Q0)
    q = np.empty(len(q_d))
    for k, x in enumerate(q_d):
        target = Q0.copy()
        target[0] += x
        servo.step(ff.setpoint(target) if feedforward else target)
        q[k] = servo.state.q_rad[0] - Q0[0]
    return q, servo


@pytest.mark.parametrize("cfg", [SERVOJ, ServoConfig(model="servoj", lookahead_time_s=0.1,
                                                     gain=600.0), ServoConfig()])
def test_with_the_feedforward_the_arm_follows_a_smooth_trajectory(cfg):
    """Eq. FF inverts q̈ = k_p (sp − q) − k_d q̇: the arm follows q_d, one step after it is
    sent (the step's result is the next cycle's position; the link's one-cycle delay and
    the backward differences make up the rest), within 0.3 mrad over a 6 s, 0.05 rad rms
    trajectory (0.3 mm at the UR10e's reach). Sent as it is, servoj at 0.03 s / 1200 trails
    by 13 mrad (over 40 times more), at 0.1 s / 600 by 33 mrad; the 50 Hz default servo by
    2.6 mrad (its feedforward, off by default, gives 0.01)."""
    q_d = _smooth()
    with_ff, servo = _follow(cfg, q_d, feedforward=True)
    without, _ = _follow(cfg, q_d, feedforward=False)
    err_with = np.abs(with_ff - q_d).max()
    err_without = np.abs(without - q_d).max()
    assert not servo.stopped
    assert err_with < 3e-4
    assert err_without > 8.0 * err_with
    if cfg.model == "servoj":
        assert err_without > 40.0 * err_with


def test_the_feedforward_makes_a_ramp_trail_by_nothing_whatever_the_lookahead():
    """On a ramp q̇_d is exact and q̈_d zero: the lookahead's lag T q̇ is sent ahead, so the
    arm's lag is the same at lookahead 0.03 and 0.2 s (without: 16 and 101 cycles)."""
    ramp = 0.2 * DT * np.arange(1500)
    for lookahead_s in (0.03, 0.2):
        cfg = ServoConfig(model="servoj", lookahead_time_s=lookahead_s, gain=1200.0)
        q, _ = _follow(cfg, ramp, feedforward=True)
        assert q[-1] == pytest.approx(ramp[-1], abs=1e-9)
        q, _ = _follow(cfg, ramp, feedforward=False)
        assert (ramp[-1] - q[-1]) / (0.2 * DT) == pytest.approx(lookahead_s / DT, abs=0.01)


def test_a_jump_in_the_desired_joints_is_spread_within_the_speed_limit():
    """A 0.05 rad jump would make Eq. FF ask 0.05 (1 + T/dt + 1/(gain dt²)) rad in one
    cycle (10 rad, a protective stop); each set-point step is held within the limit and
    the arm gets there without a stop."""
    cfg = SERVOJ
    servo = UR10eServo(cfg, DT, Q0)
    ff = ServoFeedforward(*tracking_gains(cfg), DT, MAX_STEP, Q0)
    target = Q0.copy()
    target[2] += 0.05
    sp_prev = Q0.copy()
    for _ in range(1500):
        sp = ff.setpoint(target)
        assert np.all(np.abs(sp - sp_prev) <= MAX_STEP + 1e-15)
        sp_prev = sp
        servo.step(sp)
    assert not servo.stopped
    assert servo.state.q_rad[2] == pytest.approx(target[2], abs=1e-6)


def _collision(*assignments: str):
    cfg = load_scenario("collision")
    for a in assignments:
        cfg = merge_overrides(cfg, assignment_override(a))
    return cfg


def test_the_feedforward_is_on_with_servoj_and_the_compensation_only():
    """None: on with servoj (the collision scenario's compensation is enabled), off with the
    second-order servo; an explicit setting wins; nothing without the compensation."""
    assert servo_feedforward_enabled(_collision('servo.model="servoj"'))
    assert not servo_feedforward_enabled(_collision())
    assert servo_feedforward_enabled(_collision("compensation.servo_feedforward=true"))
    assert not servo_feedforward_enabled(
        _collision('servo.model="servoj"', "compensation.servo_feedforward=false"))
    assert servo_feedforward(_collision('servo.model="servoj"', "compensation.enabled=false"),
                             Q0) is None


def test_a_feedforward_setting_without_the_compensation_is_refused():
    with pytest.raises(ConfigError, match="servo_feedforward is set but enabled is false: it "
                       r"would have no effect \(set enabled = true, or leave "
                       r"servo_feedforward out\)"):
        _collision("compensation.enabled=false", "compensation.servo_feedforward=true")


def _follow_corrected(cfg: ServoConfig, q_d: np.ndarray, correction_hz: float) -> np.ndarray:
    """Joint 1 after each servo step, ``q_d`` sent through Eq. FC with the arm's reported
    joints (the servo's state after its last step)."""
    servo = UR10eServo(cfg, DT, Q0)
    speed = np.array(cfg.speed_limits_radps)
    ff = ServoFeedforward(*tracking_gains(cfg), DT, MAX_STEP, Q0, 2.0 * math.pi * correction_hz,
                          cfg.delay_cycles, cfg.accel_limit_radps2, speed)
    q = np.empty(len(q_d))
    for k, x in enumerate(q_d):
        target = Q0.copy()
        target[0] += x
        st = servo.state
        servo.step(ff.setpoint(target, st.q_rad, st.qd_radps))
        q[k] = servo.state.q_rad[0] - Q0[0]
    assert not servo.stopped
    return q


def _acceleration_steps() -> np.ndarray:
    """At rest, then 2 rad/s² for 0.1 s from t = 0.5 s, then a steady 0.2 rad/s: the
    desired acceleration jumps twice, as a contact's force does at its onset and end."""
    t = DT * np.arange(1000)
    return 0.5 * 2.0 * np.clip(t - 0.5, 0.0, 0.1) ** 2 + 0.2 * np.clip(t - 0.6, 0.0, None)


@pytest.mark.parametrize("cfg", [SERVOJ, ServoConfig(model="servoj", lookahead_time_s=0.1,
                                                     gain=600.0)])
def test_the_correction_works_off_what_a_jump_in_acceleration_leaves_in_servoj(cfg):
    """Eq. FF sends last cycle's q̈_d: at each jump of the desired acceleration the arm keeps
    a velocity error of dt Δq̈_d that servoj's slow loop works off over its period (still
    0.03-0.06 mrad 50 ms after the jump); Eq. FC at 16 Hz on the reported joints takes it out
    within a few of its own time constants (under a twentieth 50 ms on), and its worst is
    under a third of Eq. FF's."""
    q_d = _acceleration_steps()
    open_loop = np.abs(_follow(cfg, q_d, feedforward=True)[0] - q_d)
    corrected = np.abs(_follow_corrected(cfg, q_d, 16.0) - q_d)
    after = int(round(0.65 / DT))  # 50 ms after the second jump
    assert corrected.max() < open_loop.max() / 3.0
    assert corrected[after] < open_loop[after] / 20.0


def test_the_correction_leaves_a_stiffer_servo_and_a_smooth_track_alone():
    """The default servo's own 50 Hz loop is faster than 16 Hz: Eq. FF alone, bit for bit;
    on a smooth trajectory servoj with Eq. FC still follows within 0.3 mrad."""
    q_d = _acceleration_steps()
    default = ServoConfig()
    assert np.array_equal(_follow_corrected(default, q_d, 16.0),
                          _follow(default, q_d, feedforward=True)[0])
    smooth = _smooth()
    assert np.abs(_follow_corrected(SERVOJ, smooth, 16.0) - smooth).max() < 3e-4


def test_a_correction_bandwidth_out_of_range_is_refused():
    with pytest.raises(ConfigError, match="compensation.servo_correction_hz: Input should "
                       "be greater than or equal to 0"):
        _collision("compensation.servo_correction_hz=-1")
    with pytest.raises(ConfigError, match="compensation.servo_correction_hz: Input should "
                       "be less than or equal to 50"):
        _collision("compensation.servo_correction_hz=51")


@pytest.mark.parametrize("delay_cycles", [1, 3])
def test_the_reported_joints_are_carried_as_the_servo_itself_moves(delay_cycles):
    """Eq. FC carries the reported joints through the set-points in flight by the servo's
    law: over a random stream of set-points, near the acceleration limit at times, its
    carried state after the last step equals the servo's own state ``delay_cycles`` steps
    later, to rounding (one implementation of the law in the servo, one in the lab's
    model of it: this keeps them the same)."""
    cfg = ServoConfig(model="servoj", lookahead_time_s=0.03, gain=1200.0,
                      delay_cycles=delay_cycles)
    speed = np.array(cfg.speed_limits_radps)
    servo = UR10eServo(cfg, DT, Q0)
    ff = ServoFeedforward(*tracking_gains(cfg), DT, MAX_STEP, Q0, 100.0,
                          cfg.delay_cycles, cfg.accel_limit_radps2, speed)
    rng = np.random.default_rng(3)
    for k in range(200):
        q_d = Q0 + 0.02 * np.sin(0.05 * k) + 0.0002 * rng.standard_normal(6)
        send(servo, ff, q_d)
        assert not servo.stopped
        if k % 40 == 39:  # where the arm will be once what is in flight has reached it
            q_hat, qd_hat = ff._carried(servo.state.q_rad, servo.state.qd_radps)
            probe = UR10eServo(cfg, DT, Q0)
            probe.state = type(servo.state)(servo.state.q_rad.copy(),
                                            servo.state.qd_radps.copy(),
                                            servo.state.qdd_radps2.copy())
            probe._ring[:] = servo._ring
            probe._slot, probe._sp_prev = servo._slot, servo._sp_prev.copy()
            for _ in range(delay_cycles):
                probe.step(probe._sp_prev)  # anything: what it tracks is already in flight
            np.testing.assert_allclose(q_hat, probe.state.q_rad, rtol=0, atol=1e-12)
            np.testing.assert_allclose(qd_hat, probe.state.qd_radps, rtol=0, atol=1e-9)
