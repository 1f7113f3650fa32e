"""Simulated UR10e position servo: tracking, limits, transport delay, protective stops."""

from __future__ import annotations

import math

import numpy as np
import pytest

from app.config import RobotConfig, ServoConfig
from app.sim.servo import SafetyBox, UR10eServo, reason_of, safety_box_for_robot
from app.sim.ur10e import SPEED_LIMITS_RADPS, T_F_C_from_config, T_W_B_from_config, tcp_pose_B
from tests import oracle

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
    robot = RobotConfig(name="r", satellite="s", base_position_m=(0.0, 0.0, 0.5))
    box = safety_box_for_robot(robot)
    p0 = box.tcp_position_W(Q0)
    assert box.contains(Q0)
    tight = SafetyBox(p0 - 0.05, p0 + 0.05, box.chain)
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
    assert not tight.contains(sp)
    assert accepted > 10  # the earlier set-points were inside and accepted


def test_safety_box_uses_base_pose_and_mounting():
    robot = RobotConfig(name="r", satellite="s", base_position_m=(0.3, -0.2, 1.0),
                        base_attitude_wxyz=(0.0, 1.0, 0.0, 0.0),
                        mockup_offset_m=(0.01, 0.02, 0.1),
                        mockup_attitude_wxyz=(0.9, 0.1, -0.3, 0.2))
    box = safety_box_for_robot(robot)
    np.testing.assert_array_equal(box.p_min_W_m, robot.safety_box_min_m)
    np.testing.assert_array_equal(box.p_max_W_m, robot.safety_box_max_m)
    T_W_B, T_F_C = T_W_B_from_config(robot), T_F_C_from_config(robot)
    arm = oracle.PinArm(T_F_C)
    rng = np.random.default_rng(0)
    for q in [Q0, *rng.uniform(-2 * math.pi, 2 * math.pi, (300, 6))]:
        np.testing.assert_allclose(box.tcp_position_W(q), (T_W_B @ tcp_pose_B(q, T_F_C))[:3, 3],
                                   rtol=0, atol=1e-12)
        np.testing.assert_allclose(box.tcp_position_W(q), (T_W_B @ arm.tcp_pose(q))[:3, 3],
                                   rtol=0, atol=1e-12)
    floor = RobotConfig(name="r", satellite="s", safety_box_min_m=(-1.5, -1.5, 0.5))
    q_low = Q0.copy()
    q_low[1] = 0.3  # upper arm tilted down: TCP below z = 0.5 m
    assert safety_box_for_robot(floor).contains(Q0)
    assert not safety_box_for_robot(floor).contains(q_low)


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




def test_stop_codes_name_the_reason():
    assert reason_of(0) == ""
    for j in range(1, 7):
        assert reason_of(j) == f"joint {j} position limit"
        assert reason_of(6 + j) == f"joint {j} speed limit"
    assert reason_of(13) == "TCP left safety volume"


# --- the compiled servo against the reference servo (tests/oracle.py) ------------------------
#
# Same arithmetic in the same order (the kernel spells out np.clip/np.sign as branches);
# only the safety-box TCP comes from a different FK (Pinocchio), ~1e-16 apart, far from
# any box face on these runs. State compared at 1e-12 (measured: identical).


def _assert_same(fast, ref):
    s = fast.state
    np.testing.assert_allclose(s.q_rad, ref.q, rtol=0, atol=1e-12)
    np.testing.assert_allclose(s.qd_radps, ref.qd, rtol=0, atol=1e-12)
    np.testing.assert_allclose(s.qdd_radps2, ref.qdd, rtol=0, atol=1e-12)
    assert (s.stopped, s.reason) == (ref.stopped, ref.reason)
    assert (fast.stopped, fast.reason) == (ref.stopped, ref.reason)


def _episodes():
    """Set-point runs that saturate, brake and trip every kind of protective stop."""
    yield "saturation", aggressive_setpoints(600, seed=3)
    ramp = [Q0 + 0.99 * SPEED_LIMITS_RADPS * DT * k for k in range(1, 400)]
    yield "speed saturation", ramp  # low acceleration limit: the arm catches up at max speed
    for j in range(6):
        moving = aggressive_setpoints(60, seed=j)
        jump = moving[-1].copy()
        jump[j] += 1.05 * SPEED_LIMITS_RADPS[j] * DT
        yield f"joint {j + 1} speed limit", moving + [jump] * 300  # brakes to rest
    for j in range(6):
        q = Q0.copy()
        q[j] = (-1) ** j * (2 * math.pi - 0.001)
        beyond = [q + (-1) ** j * 0.0005 * k * np.eye(6)[j] for k in range(1, 8)]
        yield f"joint {j + 1} position limit", [q] * 5 + beyond + [q] * 20
    nan = Q0.copy()
    nan[4] = np.nan
    yield "joint 5 position limit (NaN)", [Q0] * 3 + [nan] * 5
    swing = [Q0 + np.array([0.5 * DT * k, 0, 0, 0, 0, 0]) for k in range(1, 1500)]
    yield "TCP left safety volume", swing


@pytest.mark.parametrize("delay", [0, 1, 3])
def test_step_equals_the_reference_servo(delay):
    """Same state every cycle over saturation, braking, all 13 kinds of stop, a NaN, the
    delay ring wrapping round, and resets (in place and to another posture) after which
    both carry on."""
    robot = RobotConfig(name="r", satellite="s", base_position_m=(0.0, 0.0, 0.5))
    T_W_B, T_F_C = T_W_B_from_config(robot), T_F_C_from_config(robot)
    box = safety_box_for_robot(robot)
    p0 = box.tcp_position_W(Q0)
    tight = SafetyBox(p0 - 0.05, p0 + 0.05, box.chain)
    cfg = ServoConfig(delay_cycles=delay, accel_limit_radps2=5.0)
    reasons, saturated = set(), set()
    after_reset = aggressive_setpoints(100, seed=11)
    for name, setpoints in _episodes():
        q0, safety = Q0, box
        if "position" in name:  # postures far from home: no box in the way
            q0, safety = setpoints[0], None
        elif name.startswith("TCP"):
            safety = tight
        ref_box = None if safety is None else (safety.p_min_W_m, safety.p_max_W_m, T_W_B, T_F_C)
        fast, ref = UR10eServo(cfg, DT, q0, safety), oracle.RefServo(cfg, DT, q0, ref_box)
        for sp in setpoints:
            fast.step(sp)
            ref.step(sp)
            _assert_same(fast, ref)
            if np.any(np.abs(ref.qd) == SPEED_LIMITS_RADPS):
                saturated.add("speed")
            if np.any(np.abs(ref.qdd) >= cfg.accel_limit_radps2 - 1e-9):
                saturated.add("accel")
        reasons.add(ref.reason)
        assert ref.reason == ("" if "saturation" in name else name.split(" (")[0]), name
        fast.reset()  # where it is
        ref.reset()
        _assert_same(fast, ref)
        for _ in range(20):  # hold still
            fast.step(fast.state.q_rad)
            ref.step(ref.q)
            _assert_same(fast, ref)
        fast.reset(Q0)  # to another posture
        ref.reset(Q0)
        for sp in after_reset:
            fast.step(sp)
            ref.step(sp)
            _assert_same(fast, ref)
    assert saturated == {"speed", "accel"}
    assert len(reasons - {""}) == 13  # 6 speed, 6 position limits and the safety box


def test_step_without_a_box_equals_the_reference_servo():
    cfg = ServoConfig(delay_cycles=2, bandwidth_hz=20.0, damping_ratio=0.7)
    fast, ref = UR10eServo(cfg, DT, Q0), oracle.RefServo(cfg, DT, Q0)
    for sp in aggressive_setpoints(1000, seed=9):
        fast.step(sp)
        ref.step(sp)
        _assert_same(fast, ref)


def test_step_hands_out_new_state_arrays_and_leaves_the_old_ones_alone():
    """Callers (the rig's FK cache) rely on it: a step never writes into the arrays that an
    earlier state handed out."""
    servo = UR10eServo(ServoConfig(), DT, Q0)
    before = servo.state
    q, qd, qdd = before.q_rad, before.qd_radps, before.qdd_radps2
    kept = q.copy(), qd.copy(), qdd.copy()
    servo.step(Q0 + 0.001)
    servo.step(Q0 + 0.002)  # the first acts on the delayed (initial) set-point
    after = servo.state
    assert after.q_rad is not q and after.qd_radps is not qd and after.qdd_radps2 is not qdd
    for old, copy in zip((q, qd, qdd), kept, strict=True):
        np.testing.assert_array_equal(old, copy)
    assert not np.array_equal(after.q_rad, q)


@pytest.mark.parametrize(
    ("p", "v", "expected"),
    [
        ((0.0, 0.0, 1.0), (0.1, 0.0, 0.0), 15.0),  # 1.5 m to the +x wall at 0.1 m/s
        ((0.0, 0.0, 1.0), (0.0, 0.0, -0.5), 1.9),  # 0.95 m down to the floor at 0.5 m/s
        ((1.0, -1.0, 1.0), (0.25, -0.1, 0.0), 2.0),  # the first wall it meets: +x in 2 s
        ((0.0, 0.0, 1.0), (0.0, 0.0, 0.0), math.inf),  # at rest: never
        ((2.0, 0.0, 1.0), (-1.0, 0.0, 0.0), 0.0),  # outside already
    ],
)
def test_a_straight_course_leaves_the_box_when_it_meets_the_first_wall(p, v, expected):
    from app.sim.servo import seconds_until_outside

    t = seconds_until_outside(p, v, (-1.5, -1.5, 0.05), (1.5, 1.5, 2.4))
    assert t == pytest.approx(expected, abs=1e-12)


# --- servoj (UR's servoj(q, t, lookahead_time, gain) as a lab streams it) ------------------


def _servoj(lookahead_s: float = 0.03, gain: float = 1200.0, delay: int = 1) -> UR10eServo:
    cfg = ServoConfig(model="servoj", lookahead_time_s=lookahead_s, gain=gain,
                      delay_cycles=delay)
    return UR10eServo(cfg, DT, Q0)


def _stream(servo: UR10eServo, setpoints: np.ndarray) -> np.ndarray:
    """Joint 1 as the lab reads it at the start of each cycle, before sending that cycle's
    set-point (Universal_Robots_Client_Library issue #86 logged both in the same cycle)."""
    q = np.empty(len(setpoints))
    for k, sp in enumerate(setpoints):
        q[k] = servo.state.q_rad[0]
        servo.step(Q0 + sp)
    return q


def _band_limited(n: int = 5000, cutoff_hz: float = 1.0, rms_rad: float = 0.05) -> np.ndarray:
    """A smooth random stream: white noise through two first-order low-passes."""
    x = np.random.default_rng(1).standard_normal(n)
    a = 1.0 - math.exp(-2.0 * math.pi * cutoff_hz * DT)
    for _ in range(2):
        y, out = 0.0, np.empty(n)
        for k in range(n):
            y += a * (x[k] - y)
            out[k] = y
        x = out
    return rms_rad * (x - x[0]) / x.std()  # from rest at the start: no jump


def _xcorr_lag_cycles(command: np.ndarray, motion: np.ndarray, max_lag: int = 150) -> int:
    """The shift of the motion's velocity that best matches the command's (cycles)."""
    a, b = np.diff(command), np.diff(motion)
    return int(np.argmax([a[: len(a) - k] @ b[k:] for k in range(max_lag)]))


@pytest.mark.parametrize(("lookahead_s", "delay"), [(0.03, 1), (0.1, 1), (0.2, 2)])
def test_servoj_trails_a_ramp_by_its_lookahead_plus_the_link(lookahead_s, delay):
    """q̈ = gain (sp − q − T q̇) at rest in a ramp's frame: sp − q = T q̇. Read as the lab
    reads it, the arm trails the command by T + the link's delay, whatever the gain:
    16 cycles (32 ms) at 0.03 s, against the real UR10e's 17 (34 ms, issue #86)."""
    for gain in (300.0, 1200.0, 2000.0):
        speed = 0.2
        ramp = speed * DT * np.arange(1500)
        q = _stream(_servoj(lookahead_s, gain, delay), ramp)
        lag_cycles = (ramp[-1] - (q[-1] - Q0[0])) / (speed * DT)
        assert lag_cycles == pytest.approx(lookahead_s / DT + delay, abs=1e-3)


def test_servoj_cross_correlation_delay_is_about_17_cycles_and_moves_with_its_knobs():
    """A smooth 1 Hz random stream at 2 ms: the cross-correlation of command and motion
    gives 20 cycles at lookahead 0.03 s and gain 1200 (the real UR10e: 17; asserted within
    3); a longer lookahead lags more, a higher gain less (the second-order response
    rings less and faster); today's second-order servo lags 3."""
    command = _band_limited()
    lag = {(t, g): _xcorr_lag_cycles(command, _stream(_servoj(t, g), command) - Q0[0])
           for t, g in [(0.03, 1200.0), (0.03, 600.0), (0.03, 2000.0), (0.1, 1200.0),
                        (0.2, 1200.0)]}
    assert abs(lag[(0.03, 1200.0)] - 17) <= 3
    assert lag[(0.03, 600.0)] > lag[(0.03, 1200.0)] > lag[(0.03, 2000.0)]
    assert lag[(0.2, 1200.0)] > lag[(0.1, 1200.0)] > lag[(0.03, 1200.0)]
    second_order = UR10eServo(ServoConfig(), DT, Q0)
    assert _xcorr_lag_cycles(command, _stream(second_order, command) - Q0[0]) <= 5


def test_servoj_step_rings_as_its_damping_ratio_says_and_answers_faster_with_gain():
    """A small step (within the speed limit): overshoot exp(−πζ/√(1−ζ²)) with
    ζ = T √gain / 2 (0.52 at 0.03 s and 1200: 14 %); the half-rise comes sooner with a
    higher gain and later with a longer lookahead."""
    step = np.where(np.arange(1000) >= 10, 0.004, 0.0)

    def response(t, g):
        return _stream(_servoj(t, g), step) - Q0[0]

    def half_rise(q):
        return int(np.argmax(q >= 0.002)) - 10

    zeta = 0.03 * math.sqrt(1200.0) / 2.0
    overshoot = math.exp(-math.pi * zeta / math.sqrt(1.0 - zeta**2))
    q = response(0.03, 1200.0)
    assert q.max() / 0.004 - 1.0 == pytest.approx(overshoot, abs=0.015)
    assert q[-1] == pytest.approx(0.004, abs=1e-7)
    assert half_rise(response(0.03, 2000.0)) < half_rise(q) < half_rise(response(0.03, 600.0))
    assert half_rise(response(0.06, 1200.0)) > half_rise(q)
    assert response(0.2, 1200.0).max() <= 0.004 + 1e-9  # ζ = 3.5: no overshoot


def test_servoj_keeps_the_limits_and_the_protective_stops():
    servo = _servoj()
    setpoints = aggressive_setpoints(n=1000)
    for sp in setpoints:
        s = servo.step(sp)
        assert not s.stopped, s.reason
        assert np.all(np.abs(s.qd_radps) <= SPEED_LIMITS_RADPS + EPS)
        assert np.all(np.abs(s.qdd_radps2) <= servo.cfg.accel_limit_radps2 + EPS)
    jump = setpoints[-1].copy()
    jump[2] += 0.1  # 50 rad/s implied
    servo.step(jump)
    servo.step(jump)  # one cycle of transport delay
    assert servo.stopped and servo.reason == "joint 3 speed limit"


@pytest.mark.parametrize(("servo", "message"), [
    ({"model": "servoj", "lookahead_time_s": 0.02},
     "servo.lookahead_time_s: 0.02 is outside servoj's lookahead_time range [0.03, 0.2] "
     "(UR script manual)"),
    ({"model": "servoj", "lookahead_time_s": 0.25},
     "servo.lookahead_time_s: 0.25 is outside servoj's lookahead_time range [0.03, 0.2] "
     "(UR script manual)"),
    ({"model": "servoj", "gain": 99},
     "servo.gain: 99.0 is outside servoj's gain range [100, 2000] (UR script manual)"),
    ({"model": "servoj", "gain": 2001},
     "servo.gain: 2001.0 is outside servoj's gain range [100, 2000] (UR script manual)"),
    ({"gain": 300},
     "servo: gain is servoj's; it has no effect with model = 'second-order' (set model = "
     "\"servoj\", or leave gain out)"),
    ({"model": "servo-j"},
     "servo.model: Input should be 'second-order' or 'servoj'"),
])
def test_servoj_settings_out_of_urs_ranges_are_refused(servo, message):
    from app.config import ConfigError, parse_config
    with pytest.raises(ConfigError) as err:
        parse_config({"servo": servo})
    assert str(err.value) == f"invalid configuration: {message}"


def test_servoj_defaults_are_the_measured_case():
    cfg = ServoConfig(model="servoj")
    assert (cfg.servoj_lookahead_s, cfg.servoj_gain) == (0.03, 1200.0)
    assert ServoConfig(model="servoj", lookahead_time_s=0.2, gain=100).servoj_gain == 100.0
