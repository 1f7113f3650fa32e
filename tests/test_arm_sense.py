"""The fused sensor path (app/sim/arm_sense.py) against its stages called one by one."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from app.config import merge_overrides
from app.scenarios import load_scenario
from app.sim.frames import Bodies
from app.sim.ft_sensor import NORMALS_BLOCK
from app.sim.rig import ArmRig, build_rig
from app.sim.rotations import make_transform, quat_to_matrix


def _calibrated(overrides: dict) -> tuple[ArmRig, np.ndarray]:
    """A collision rig at rest, its sensor calibrated (as prepare() does), and R_W_R."""
    cfg = merge_overrides(load_scenario("collision"), overrides)
    T_W_R = make_transform(quat_to_matrix(cfg.lab.r_attitude_wxyz), cfg.lab.r_origin_m)
    rig = build_rig(0, cfg.robots[0], cfg, T_W_R, np.random.default_rng(0))
    rig.q_start_rad = rig.servo.state.q_rad.copy()
    rig.calibrate(np.array([rig.rest_reading() for _ in range(50)]))
    return rig, T_W_R[:3, :3]


def _fields(rig: ArmRig, out) -> list:
    """Everything the sensor path returns or writes."""
    s, p = rig.sensor, rig.processor
    return [out.force_R_N, out.torque_B_Nm, out.wrench_S, rig.last_raw_S,
            rig.last_processed, rig.v_W_prev, s._ring, s._head, s._held_for, s.age_cycles,
            s._calls, s.rng.bit_generator.state["state"]["state"], s._normals_at,
            s._normals, p._state_S,
            p._contact_state_S, p._gate_was_open, p.reading_age_cycles, p._poses,
            p._pose_at]


def _drive(rig: ArmRig, R_W_R: np.ndarray, cycles: int) -> tuple[list[bool], float]:
    """The rig and a deep copy taking the stages, sensing the same wrenches (a contact
    that rises and falls, pulses of torque) on the arm as it moves, the gate opening and
    closing; asserts that every field stays bit-identical. Returns the gates and the
    largest force the chain handed over [N]."""
    staged = copy.deepcopy(rig)
    rng = np.random.default_rng(7)
    rate = np.array([0.3, -0.2, 0.4, 0.2, -0.3, 0.5])
    gates, peak_N = [], 0.0
    for k in range(cycles):
        for r in (rig, staged):  # the arm moves: the FK poses and velocities change
            r.servo.step(r.q_start_rad + rate * k * r.servo.dt_s)
        _, T_W_C, v_W, _ = rig.mockup_state_W()
        wrench = np.zeros(6)
        if 20 <= k < 60:  # a contact, then its end
            wrench[:3] = 40.0 * np.sin(np.pi * (k - 20) / 40) * np.array([0.6, -0.3, 0.74])
            wrench[3:] = rng.normal(0.0, 0.5, 3)
        gate = 15 <= k < 70 or 90 <= k < 95
        gates.append(gate)
        a = rig.sense(wrench, T_W_C, v_W, R_W_R, rig.servo.dt_s, k == 0, gate)
        _, T_W_C2, v_W2, _ = staged.mockup_state_W()
        b = staged.sense_in_stages(wrench, T_W_C2, v_W2, R_W_R, staged.servo.dt_s, k == 0,
                                   gate)
        for x, y in zip(_fields(rig, a), _fields(staged, b), strict=True):
            np.testing.assert_array_equal(x, y, err_msg=f"cycle {k}")
        peak_N = max(peak_N, float(np.linalg.norm(a.force_R_N)))
    return gates, peak_N


@pytest.mark.parametrize("overrides", [
    {},  # the collision's chain: a contact filter at 1 kHz beside the 30 Hz one
    {"wrench": {"contact_lowpass_hz": None, "deadband_mode": "soft",
                "inertial_compensation": False}},
    {"wrench": {"payload_compensation": False}, "sensor": {"delay_cycles": 0}},
    {"sensor": {"delay_cycles": 3}},
])
def test_the_fused_sensor_path_is_the_stages_to_the_last_bit(overrides):
    gates, peak_N = _drive(*_calibrated(overrides), 110)
    assert any(gates) and not all(gates)
    assert peak_N > 20.0  # the contact came through


def test_the_fused_sensor_path_draws_the_stages_noise_across_blocks():
    # the fused path hands out the sensor's block of normals itself: through the end of
    # a block, a reset of the sensor (its ring refilled) and a gate that opens and closes
    rig, R_W_R = _calibrated({})
    _drive(rig, R_W_R, NORMALS_BLOCK - 40)
    assert rig.sensor._normals_at == 10  # 50 calibration readings, then the cycles
    rig.sensor.reset()
    _drive(rig, R_W_R, 100)


def test_a_sensor_slower_than_the_loop_or_on_the_body_takes_the_stages():
    # the fused call holds no reading and shifts no wrench to a face: were it taken for
    # these sensors, it would fail (a held reading) or differ from the stages (the face)
    slow, R_W_R = _calibrated({"sensor": {"sample_rate_hz": 125.0}})
    assert slow.sensor.every_cycles == 4.0
    _drive(slow, R_W_R, 40)
    body, R_W_R = _calibrated({"sensor": {"placement": "mockup"}})
    assert body.T_C_S is not None
    _drive(body, R_W_R, 40)


def test_the_packed_constants_follow_a_new_calibration_and_a_replicates_redraw():
    # the fused path reads the sensor's and the chain's constants from one buffer each: a
    # replicate's redraw (app/runs/uncertainty.py) assigns a new noise and a new
    # calibration, and the next fused cycle must read those, as the stages do
    from app.runs.uncertainty import SensorNoise, _draw, _redraw
    from app.sim.loop import Emulator

    em = Emulator(merge_overrides(load_scenario("collision"),
                                  {"wrench": {"calibration_s": 0.1}}), mode="hil")
    em.prepare()
    for _ in range(20):
        em.step()
    twin, kept = em.copy_state(), em.copy_state()
    noise = [SensorNoise(np.array([3.0, 2.0, 4.0, 0.3, 0.2, 0.1]), np.full(6, 0.5))
             for _ in em.arms]
    draw = _draw(noise, np.random.default_rng(11))
    for e in (em, twin):
        _redraw(e, noise, draw)
    for arm, (_, bias_error_S) in zip(em.arms, draw, strict=True):
        np.testing.assert_array_equal(arm.sensor.constants[10:16], noise[0].sd_S)
        np.testing.assert_array_equal(arm.processor.constants[5:11],
                                      arm.processor.calibration.bias_S)
        np.testing.assert_array_equal(
            arm.processor.calibration.bias_S,
            kept.arms[arm.index].processor.calibration.bias_S + bias_error_S)
    wrench = np.array([12.0, -7.0, 30.0, 0.4, -0.2, 0.3])
    R_W_R, dt_s = em.R_W_R, em.dt_s
    differs = False
    for k in range(30):
        for arm, staged, old in zip(em.arms, twin.arms, kept.arms, strict=True):
            _, T_W_C, v_W, _ = arm.mockup_state_W()
            a = arm.sense(wrench, T_W_C, v_W, R_W_R, dt_s, False, k >= 10)
            b = staged.sense_in_stages(wrench, T_W_C, v_W, R_W_R, dt_s, False, k >= 10)
            c = old.sense(wrench, T_W_C, v_W, R_W_R, dt_s, False, k >= 10)
            for x, y in zip(_fields(arm, a), _fields(staged, b), strict=True):
                np.testing.assert_array_equal(x, y, err_msg=f"cycle {k}")
            differs |= not np.array_equal(arm.last_raw_S, old.last_raw_S)
            differs |= not np.array_equal(a.wrench_S, c.wrench_S)
    assert differs  # the redraw changed what the fused path read


def test_a_packed_attribute_refuses_a_value_of_the_wrong_shape_and_keeps_its_own():
    rig, _ = _calibrated({})
    before = rig.sensor.constants.copy()
    with pytest.raises(ValueError, match=r"expected shape \(6,\), got shape \(3,\)"):
        rig.sensor.noise_std_S = np.ones(3)
    with pytest.raises(ValueError, match=r"expected a number, got shape \(2,\)"):
        rig.sensor.mass_kg = [1.0, 2.0]
    np.testing.assert_array_equal(rig.sensor.constants, before)
    rig.sensor.range_S = np.arange(1.0, 7.0)  # an assignment writes the buffer
    np.testing.assert_array_equal(rig.sensor.constants[16:22], np.arange(1.0, 7.0))


@pytest.mark.parametrize("overrides", [
    {},  # one call (app/sim/arm_sense.py sense_rows)
    {"sensor": {"placement": "mockup"}},  # the stages, their output put in the rows
])
def test_sense_rows_writes_what_sense_returns_into_its_satellites_rows_only(overrides):
    """ArmRig.sense_rows on the cycle's (N, ...) arrays of three bodies, against
    ArmRig.sense on the rig's own rows, on a deep copy: the same force and torque to the
    last bit in the satellite's rows of force_R and torque_B, every other row untouched,
    and the rig left in the same state, through a contact and the gate's opening."""
    rig, R_W_R = _calibrated(overrides)
    rig.satellite = 2  # (not the first row: a kernel writing row 0 would fail here)
    other = copy.deepcopy(rig)
    s = rig.satellite
    rng = np.random.default_rng(5)
    rate = np.array([0.3, -0.2, 0.4, 0.2, -0.3, 0.5])
    moved = 0.0
    for k in range(80):
        for r in (rig, other):
            r.servo.step(r.q_start_rad + rate * k * r.servo.dt_s)
        _, T_W_C, v_W, w_W = rig.mockup_state_W()
        bodies = Bodies(rng.normal(size=(3, 4, 4)), rng.normal(size=(3, 3)),
                        rng.normal(size=(3, 3)))
        bodies.T_W_C[s], bodies.v_W[s], bodies.w_W[s] = T_W_C, v_W, w_W
        wrench_W = rng.normal(0.0, 5.0, (3, 6))
        if 20 <= k < 50:
            wrench_W[s, :3] += 30.0 * np.array([0.6, -0.3, 0.74])
        force_R, torque_B = rng.normal(size=(3, 3)), rng.normal(size=(3, 3))
        before = force_R.copy(), torque_B.copy()
        gate = 15 <= k < 60
        rig.sense_rows(wrench_W, bodies, R_W_R, rig.servo.dt_s, k == 0, gate, force_R,
                       torque_B)
        _, T_W_C2, v_W2, _ = other.mockup_state_W()
        out = other.sense(wrench_W[s].copy(), T_W_C2, v_W2, R_W_R, other.servo.dt_s, k == 0,
                          gate)
        assert force_R[s].tobytes() == out.force_R_N.tobytes(), k
        assert torque_B[s].tobytes() == out.torque_B_Nm.tobytes(), k
        rest = [i for i in range(3) if i != s]
        assert force_R[rest].tobytes() == before[0][rest].tobytes()
        assert torque_B[rest].tobytes() == before[1][rest].tobytes()
        for x, y in zip(_fields(rig, out)[3:], _fields(other, out)[3:], strict=True):
            np.testing.assert_array_equal(x, y, err_msg=f"cycle {k}")
        moved = max(moved, float(np.linalg.norm(force_R[s])))
    assert moved > 20.0  # the contact came through


def test_sense_rows_refuses_a_satellite_outside_the_cycles_arrays():
    """A rig whose satellite is no row of the cycle's arrays: an IndexError, and the
    arrays' rows as they were (the kernel reads and writes nothing outside them)."""
    rig, R_W_R = _calibrated({})
    _, T_W_C, v_W, w_W = rig.mockup_state_W()
    bodies = Bodies(T_W_C[None].copy(), v_W[None].copy(), w_W[None].copy())
    for s in (1, 3, -1):
        rig.satellite = s
        force_R, torque_B = np.ones((1, 3)), np.ones((1, 3))
        with pytest.raises(IndexError, match="not a row of the cycle's arrays"):
            rig.sense_rows(np.zeros((1, 6)), bodies, R_W_R, rig.servo.dt_s, False, False,
                           force_R, torque_B)
        assert (force_R == 1.0).all() and (torque_B == 1.0).all()
