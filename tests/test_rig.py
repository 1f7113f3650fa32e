"""One arm rig (app/sim/rig.py): FK of the servo state, F/T sensing, VFDM command, start-up."""

from __future__ import annotations

import numpy as np
import pytest

from app.config import merge_overrides
from app.scenarios import load_scenario
from app.sim.orbital import OrbitalSimulator
from app.sim.rig import ArmRig, build_rig
from app.sim.rotations import (
    invert_transform,
    make_transform,
    matrix_to_rotvec,
    quat_to_matrix,
    rotvec_to_matrix,
    rotvec_to_quat,
)
from app.sim.ur10e import flange_pose_B, tcp_jacobian_B, tcp_pose_B

R_ATTITUDE = rotvec_to_quat(np.array([0.1, -0.15, 0.5]))  # R turned in the lab


@pytest.fixture(scope="module")
def free_floating():
    return merge_overrides(load_scenario("free-floating-scripted"),
                           {"lab": {"r_attitude_wxyz": list(R_ATTITUDE)}})


def _T_W_R(cfg) -> np.ndarray:
    return make_transform(quat_to_matrix(cfg.lab.r_attitude_wxyz), cfg.lab.r_origin_m)


def _rig(cfg, index: int = 0, seed: int = 0) -> ArmRig:
    return build_rig(index, cfg.robots[index], cfg, _T_W_R(cfg), np.random.default_rng(seed))


def _calibrated(cfg, settle_cycles: int = 250) -> ArmRig:
    """A rig resting at its home posture, its sensor calibrated there (as prepare() does)."""
    rig = _rig(cfg)
    rig.q_start_rad = rig.servo.state.q_rad.copy()
    rig.vfdm.reset(rig.q_start_rad + 0.1)  # wherever the virtual arm was ...
    rig.calibrate(np.array([rig.rest_reading() for _ in range(settle_cycles)]))
    np.testing.assert_array_equal(rig.vfdm.q_rad, rig.servo.state.q_rad)  # ... it starts here
    return rig


# --- forward kinematics of the servo state ----------------------------------------------------


def test_mockup_state_is_one_fk_per_servo_state_and_is_the_arm_kinematics(free_floating):
    rig = _rig(free_floating)
    q0 = rig.servo.state.q_rad.copy()
    first = rig.mockup_state_W()
    again = rig.mockup_state_W()
    assert all(a is b for a, b in zip(first, again, strict=True))  # cached, not recomputed
    rate = np.array([0.3, -0.2, 0.4, 0.2, -0.3, 0.5])  # rad/s: a ramp the servo accepts
    for k in range(1, 31):
        rig.servo.step(q0 + rate * k * rig.servo.dt_s)
    assert not rig.servo.stopped
    moved = rig.mockup_state_W()
    assert all(a is not b for a, b in zip(first, moved, strict=True))
    assert rig.mockup_state_W()[1] is moved[1]
    T_W_F, T_W_C, v_W, w_W = moved
    q, qd = rig.servo.state.q_rad, rig.servo.state.qd_radps
    assert np.abs(qd).min() > 1e-2
    T_W_B, T_F_C = rig.T_W_B, rig.T_F_C
    np.testing.assert_allclose(T_W_F, T_W_B @ flange_pose_B(q), atol=1e-12)
    np.testing.assert_allclose(T_W_C, T_W_B @ tcp_pose_B(q, T_F_C), atol=1e-12)
    twist_B = tcp_jacobian_B(q, T_F_C) @ qd
    np.testing.assert_allclose(v_W, T_W_B[:3, :3] @ twist_B[:3], atol=1e-12)
    np.testing.assert_allclose(w_W, T_W_B[:3, :3] @ twist_B[3:], atol=1e-12)
    # a reset to a new state (new object, same numbers) is seen as a new state too
    rig.servo.reset(q0)
    np.testing.assert_allclose(rig.mockup_state_W()[1], first[1], atol=1e-15)
    np.testing.assert_array_equal(rig.mockup_state_W()[2], 0.0)


def test_mockup_twist_is_the_rate_of_the_mockup_pose(free_floating):
    """v_W and ω_W agree with finite differences of the FK pose along the joint motion."""
    rig = _rig(free_floating)
    q0 = rig.servo.state.q_rad.copy()
    qd = np.array([0.3, -0.2, 0.4, 0.2, -0.3, 0.5])
    h = 1e-6
    T0 = rig.T_W_B @ tcp_pose_B(q0, rig.T_F_C)
    T1 = rig.T_W_B @ tcp_pose_B(q0 + h * qd, rig.T_F_C)
    rig.servo.state.qd_radps = qd  # the state the servo would report moving at qd
    _, T_W_C, v_W, w_W = rig.mockup_state_W()
    np.testing.assert_allclose(T_W_C, T0, atol=1e-12)
    np.testing.assert_allclose(v_W, (T1[:3, 3] - T0[:3, 3]) / h, atol=1e-5)
    np.testing.assert_allclose(w_W, matrix_to_rotvec(T1[:3, :3] @ T0[:3, :3].T) / h, atol=1e-5)


# --- frames ------------------------------------------------------------------------------------


def test_tcp_target_is_inv_T_W_B_T_W_R_T_R_sat():
    cfg = merge_overrides(load_scenario("collision"),
                          {"lab": {"r_attitude_wxyz": list(R_ATTITUDE)}})
    rig = _rig(cfg, index=1)  # the floor arm carries the sponge, satellite 2
    assert rig.satellite == 1
    y = OrbitalSimulator.from_config(cfg).y.copy()
    y[1, :3] = [0.31, -0.07, 0.12]
    y[1, 6:10] = rotvec_to_quat(np.array([0.4, -0.3, 1.1]))
    y[0, :3] = [-0.5, 0.2, 0.0]  # the other satellite plays no part
    robot = cfg.robots[1]
    T_W_B = make_transform(quat_to_matrix(robot.base_attitude_wxyz), robot.base_position_m)
    T_R_sat = make_transform(quat_to_matrix(y[1, 6:10]), y[1, :3])
    expected = invert_transform(T_W_B) @ _T_W_R(cfg) @ T_R_sat
    np.testing.assert_allclose(rig.tcp_target_B(y), expected, atol=1e-12)


# --- sensing -----------------------------------------------------------------------------------


def test_calibrate_zeroes_the_at_rest_reading(free_floating):
    cfg = free_floating
    R_W_R, dt = _T_W_R(cfg)[:3, :3], 1.0 / cfg.loop.rate_hz
    raw = _rig(cfg)
    _, T_W_C, v_W, _ = raw.mockup_state_W()
    out = [raw.sense(np.zeros(6), T_W_C, v_W, R_W_R, dt, first_cycle=k == 0) for k in range(50)]
    # uncalibrated, the mockup's weight (1 kg) reads as a push down, seen in R
    weight_R = R_W_R.T @ [0.0, 0.0, -9.81]
    np.testing.assert_allclose(out[-1].force_R_N, weight_R, atol=3.0)
    rig = _calibrated(cfg)
    _, T_W_C, v_W, _ = rig.mockup_state_W()
    for k in range(200):
        out = rig.sense(np.zeros(6), T_W_C, v_W, R_W_R, dt, first_cycle=k == 0)
        np.testing.assert_array_equal(out.force_R_N, 0.0)  # noise stays in the deadband
        np.testing.assert_array_equal(out.torque_B_Nm, 0.0)
    cal = rig.processor.calibration
    assert cal.mass_kg == cfg.satellites[0].mass_kg
    np.testing.assert_allclose(cal.com_F_m, rig.T_F_C[:3, 3])
    # the estimated bias is the sensor's, within its noise averaged over 250 readings
    np.testing.assert_allclose(cal.bias_S, rig.sensor.bias_S, atol=0.5)


def test_a_push_through_the_com_comes_back_in_R(free_floating):
    cfg = free_floating
    R_W_R, dt = _T_W_R(cfg)[:3, :3], 1.0 / cfg.loop.rate_hz
    rig = _calibrated(cfg)
    _, T_W_C, v_W, _ = rig.mockup_state_W()
    push_R = np.array([15.0, -10.0, 8.0])
    push_W = R_W_R @ push_R
    assert np.linalg.norm(push_W - push_R) > 5.0  # the frames are told apart
    forces, torques = [], []
    for k in range(100):
        out = rig.sense(np.concatenate([push_W, np.zeros(3)]), T_W_C, v_W, R_W_R, dt,
                        first_cycle=k == 0)
        np.testing.assert_array_equal(rig.last_processed, [*out.force_R_N, *out.torque_B_Nm])
        forces.append(out.force_R_N)
        torques.append(out.torque_B_Nm)
    settled = np.array(forces[20:])  # one cycle of delay, then the 30 Hz low-pass
    # through the COM: no moment about it. The sensor's moment r_FC x F (~1.5 N m) is far
    # above the torque deadband, so what is left after the shift to the COM is noise:
    # within the data sheet's torque accuracy (0.5 N m), and about zero on average
    torques = np.array(torques[20:])
    assert np.linalg.norm(torques, axis=1).max() < 0.5
    np.testing.assert_allclose(torques.mean(axis=0), 0.0, atol=0.05)
    # every reading within the data sheet's precision (5 N); their mean much closer, and at
    # full size: the hard deadband does not shrink a push above it
    assert np.linalg.norm(settled - push_R, axis=1).max() < 5.0
    np.testing.assert_allclose(settled.mean(axis=0), push_R, atol=1.0)
    assert np.abs(settled - settled.mean(axis=0)).max() > 0.05  # the noise is there
    # the raw reading holds the mockup's weight as well, in the sensor frame
    T_W_F = rig.mockup_state_W()[0]
    expected_raw_f = T_W_F[:3, :3].T @ (push_W + [0.0, 0.0, -9.81])
    np.testing.assert_allclose(rig.last_raw_S[:3], expected_raw_f + rig.sensor.bias_S[:3],
                               atol=6 * cfg.sensor.noise_force_N)


# --- command -----------------------------------------------------------------------------------


def test_command_drives_the_servo_to_the_vfdm_set_point(free_floating):
    rig = _rig(free_floating)
    q0 = rig.servo.state.q_rad.copy()
    T_start = tcp_pose_B(q0, rig.T_F_C)
    goal = T_start.copy()
    goal[:3, 3] += [0.03, -0.02, 0.04]
    goal[:3, :3] = rotvec_to_matrix([0.05, 0.0, -0.08]) @ T_start[:3, :3]
    d0 = np.linalg.norm(goal[:3, 3] - T_start[:3, 3])
    n_ramp = 100
    for k in range(1, 351):  # ramp the target there in 0.2 s, then hold it
        s = min(1.0, k / n_ramp)
        target = goal.copy()
        target[:3, 3] = T_start[:3, 3] + s * (goal[:3, 3] - T_start[:3, 3])
        target[:3, :3] = rotvec_to_matrix(
            s * matrix_to_rotvec(goal[:3, :3] @ T_start[:3, :3].T)) @ T_start[:3, :3]
        q_before = rig.servo.state.q_rad.copy()
        rig.command(target)
        if k == n_ramp // 2:  # midway the arm has moved towards the goal
            T = tcp_pose_B(rig.servo.state.q_rad, rig.T_F_C)
            assert 0.2 * d0 < np.linalg.norm(T[:3, 3] - T_start[:3, 3]) < 0.7 * d0
    assert not rig.servo.stopped
    np.testing.assert_allclose(rig.servo.state.q_rad, rig.vfdm.q_rad, atol=1e-6)
    assert np.linalg.norm(rig.servo.state.q_rad - q_before) < 1e-6  # at rest
    T = tcp_pose_B(rig.servo.state.q_rad, rig.T_F_C)
    assert np.linalg.norm(T[:3, 3] - goal[:3, 3]) < 1e-4
    assert np.linalg.norm(matrix_to_rotvec(goal[:3, :3] @ T[:3, :3].T)) < 1e-3


# --- start-up ----------------------------------------------------------------------------------


def test_solve_start_posture_reaches_a_reachable_target_and_not_an_unreachable_one(
        free_floating):
    rig = _rig(free_floating)
    vfdm_q, servo_q = rig.vfdm.q_rad.copy(), rig.servo.state.q_rad.copy()
    target = rig.tcp_target_B(OrbitalSimulator.from_config(free_floating).y)
    q, err = rig.solve_start_posture(target, max_steps=10_000)
    assert q is not None and err < 1e-5
    T = tcp_pose_B(q, rig.T_F_C)
    assert np.linalg.norm(T[:3, 3] - target[:3, 3]) < 1e-5
    assert np.linalg.norm(matrix_to_rotvec(target[:3, :3] @ T[:3, :3].T)) < 1e-4
    # it ran on a copy of the virtual model: the rig's own VFDM and servo did not move
    np.testing.assert_array_equal(rig.vfdm.q_rad, vfdm_q)
    np.testing.assert_array_equal(rig.servo.state.q_rad, servo_q)
    far = target.copy()
    far[:3, 3] += [3.0, 0.0, 0.0]  # beyond the UR10e's 1.3 m reach
    q, err = rig.solve_start_posture(far, max_steps=300)
    assert q is None
    # the true distance left, not the clamped error the VFDM works on (max_error_lin_m)
    assert err > free_floating.vfdm.max_error_lin_m + 0.5
    assert err < 3.0 + 1e-9


def test_move_to_brings_the_arm_to_rest_at_the_goal(free_floating):
    rig = _rig(free_floating)
    target = rig.tcp_target_B(OrbitalSimulator.from_config(free_floating).y)
    q, _ = rig.solve_start_posture(target, max_steps=10_000)
    rig.move_to(q, 1.0 / free_floating.loop.rate_hz)
    assert not rig.servo.stopped
    np.testing.assert_allclose(rig.servo.state.q_rad, q, atol=1e-9)
    np.testing.assert_allclose(rig.servo.state.qd_radps, 0.0, atol=1e-9)


def test_sync_to_measured_starts_each_cycle_from_the_measured_joints(free_floating):
    """[vfdm] sync_to_measured: the virtual arm takes the servo's joint positions first,
    so the set-point is the one a VFDM started there would give."""
    cfg = merge_overrides(free_floating, {"vfdm": {"sync_to_measured": True}})
    rig = _rig(cfg)
    for _ in range(3):  # the servo lags the VFDM: the two differ
        target = tcp_pose_B(rig.servo.state.q_rad, rig.T_F_C)
        target[:3, 3] += [0.01, 0.0, 0.0]
        rig.command(target)
    assert np.abs(rig.vfdm.q_rad - rig.servo.state.q_rad).max() > 1e-5
    twin = _rig(cfg).vfdm
    twin.q_rad[:] = rig.servo.state.q_rad
    twin.qd_radps[:] = rig.vfdm.qd_radps
    twin._step_prev[:] = rig.vfdm._step_prev
    twin._has_prev[:] = rig.vfdm._has_prev  # and the last target (the feedforward)
    twin._R_prev[:], twin._p_prev[:] = rig.vfdm._R_prev, rig.vfdm._p_prev
    target[:3, 3] += [0.001, 0.0, 0.0]
    expected = twin.solve(target)
    rig.command(target)
    np.testing.assert_array_equal(rig.vfdm.q_rad, expected)


# --- the sensor on the mockup body ([sensor] placement = "mockup") ---------------------------


def test_on_the_body_the_sensor_measures_the_contact_wrench_at_its_face(free_floating):
    """Between the body and a face at (0.1, 0.05, 0) in the body frame, carrying only the
    face: an off-centre push comes back as its force in R and its moment about the COM in
    body axes (noise off), and the raw reading is that push in the body axes, its moment
    about the face, plus the face's weight alone."""
    cfg = merge_overrides(free_floating, {"sensor": {
        "placement": "mockup", "face_mass_kg": 0.05, "face_position_m": [0.1, 0.05, 0.0],
        "noise_force_N": 0.0, "noise_torque_Nm": 0.0}})
    R_W_R, dt = _T_W_R(cfg)[:3, :3], 1.0 / cfg.loop.rate_hz
    rig = _calibrated(cfg)
    assert (rig.carried_mass_kg, rig.mockup_mass_kg) == (0.05, 1.0)
    _, T_W_C, v_W, _ = rig.mockup_state_W()
    R_W_C = T_W_C[:3, :3]
    force_W = np.array([6.0, -3.0, 4.0])
    arm_C = np.array([0.1, 0.05, 0.0])  # the push acts at the face's centre
    torque_C_W = np.cross(R_W_C @ arm_C, force_W)
    for k in range(200):
        out = rig.sense(np.concatenate([force_W, torque_C_W]), T_W_C, v_W, R_W_R, dt,
                        first_cycle=k == 0)
    np.testing.assert_allclose(out.force_R_N, R_W_R.T @ force_W, atol=1e-9)
    np.testing.assert_allclose(out.torque_B_Nm, R_W_C.T @ torque_C_W, atol=1e-9)
    weight_S = R_W_C.T @ (0.05 * np.array(cfg.lab.gravity_mps2))
    np.testing.assert_allclose(rig.last_raw_S[:3],
                               R_W_C.T @ force_W + weight_S + rig.sensor.bias_S[:3], atol=1e-9)
    # through the face's centre: no moment about the sensor's origin
    np.testing.assert_allclose(rig.last_raw_S[3:], rig.sensor.bias_S[3:], atol=1e-9)


def _worst_force_before_contact(*assignments: str, until_s: float | None = None) -> float:
    """The largest force component the ODS receives before the mockups touch (or, with
    ``until_s``, over that first stretch only)."""
    from app.config import assignment_override
    from app.sim.loop import Emulator
    cfg = load_scenario("collision")
    for a in ("compensation.enabled=false", "wrench.contact_gate=false",
              "wrench.fuse_pair_contact=false", "passivity.enabled=false",
              "sensor.noise_force_N=0", "sensor.noise_torque_Nm=0",
              "wrench.deadband_force_N=0", "wrench.deadband_torque_Nm=0", *assignments):
        cfg = merge_overrides(cfg, assignment_override(a))
    em = Emulator(cfg)
    em.prepare()
    worst = 0.0
    while not em.contact_active and em.t_s < (until_s or 5.0):
        em.step()
        assert em.status == "running"
        worst = max(worst, float(np.abs(em.applied_force_R).max()))
    assert until_s or em.contact_active
    return worst


def test_on_the_body_no_compensation_of_the_mockup_is_needed():
    """The arms accelerate the mockups from rest to 0.08 m/s, then carry them to the
    contact, noise and deadband off. At the flange without payload and inertial
    compensation the ODS receives the mockup's load (its weight, 9.8 N on 1 kg, and its
    m·a); on the body, with a face of no mass, it receives nothing before the contact;
    with a 50 g face, that face's load, some twentieth of the mockup's (its mass's share;
    the flange's run also pushes its satellite off harder); and nothing once the chain
    compensates the face (as it does by default)."""
    off = ["wrench.payload_compensation=false", "wrench.inertial_compensation=false"]
    # the arms take the mockups from rest to 0.08 m/s in the first cycles; without
    # compensation what the ODS receives pushes the satellites off: the first 0.3 s only
    at_flange = _worst_force_before_contact(*off, until_s=0.3)
    assert at_flange > 9.8
    bare_face = _worst_force_before_contact(*off, 'sensor.placement="mockup"',
                                            "sensor.face_mass_kg=0")
    assert bare_face < 1e-12
    face = _worst_force_before_contact(*off, 'sensor.placement="mockup"', until_s=0.3)
    assert 0.4 < face < at_flange / 15.0  # 50 g against 1 kg (measured: 0.47 N, 15 N)
    compensated = _worst_force_before_contact('sensor.placement="mockup"')
    assert compensated < 1e-9
