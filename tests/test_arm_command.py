"""The fused command path (app/sim/arm_command.py) against its stages called one by one."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from app.config import merge_overrides
from app.scenarios import load_scenario
from app.sim.arm_command import ArmCommand
from app.sim.orbital import OrbitalSimulator
from app.sim.rig import ArmRig, build_rig
from app.sim.rotations import make_transform, matrix_to_quat, quat_to_matrix, rotvec_to_matrix
from app.sim.servo import SafetyBox


def _rig(overrides: dict) -> ArmRig:
    cfg = merge_overrides(load_scenario("collision"), overrides)
    T_W_R = make_transform(quat_to_matrix(cfg.lab.r_attitude_wxyz), cfg.lab.r_origin_m)
    return build_rig(0, cfg.robots[0], cfg, T_W_R, np.random.default_rng(0))


def _state(rig: ArmRig) -> list:
    """Everything the command path writes (the VFDM's, the servo's) and the forward
    kinematics of the new joint state (the fused call's, or computed here)."""
    v, s = rig.vfdm, rig.servo
    return [v.q_rad, v.qd_radps, v._e_prev, v._has_prev, v._step_prev, v._ff, v._R_prev,
            v._p_prev, v.last_error, v.last_scale, s.state.q_rad, s.state.qd_radps,
            s.state.qdd_radps2, s.state.stopped, s.state.reason, s._ring, s._slot,
            s._sp_prev, *rig.mockup_state_W()]


def _ods_state(rig: ArmRig, T_B_C: np.ndarray) -> np.ndarray:
    """An ODS state (2, 13) whose satellite ``rig.satellite`` is at the TCP pose T_B_C
    (to rounding: what matters is that both rigs get the same state)."""
    T_R_C = np.linalg.inv(rig.T_B_R) @ T_B_C
    y = np.zeros((2, 13))
    y[:, 6] = 1.0
    y[rig.satellite, 0:3] = T_R_C[:3, 3]
    y[rig.satellite, 6:10] = matrix_to_quat(T_R_C[:3, :3])
    return y


def _drive(rig: ArmRig, cycles: int, speed_mps: float, spin_radps: float,
           towards: bool = False) -> tuple:
    """The fused rig and a deep copy taking the stages, both sent along the same target
    path (a line from the home TCP pose and a spin about a tilted axis; ``towards``: as
    the satellite's pose in an ODS state, :meth:`ArmRig.command_towards`); asserts that
    every written field and the new FK stay bit-identical. Returns the two rigs."""
    staged = copy.deepcopy(rig)
    T0 = rig.vfdm.tcp_pose()
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    dt = rig.servo.dt_s
    for k in range(cycles):
        T = T0.copy()
        T[:3, 3] += np.array([1.0, -0.4, 0.3]) * speed_mps * k * dt
        T[:3, :3] = rotvec_to_matrix(axis * spin_radps * k * dt) @ T0[:3, :3]
        if towards:
            y = _ods_state(rig, T)
            rig.command_towards(y)
            staged.command_in_stages(staged.tcp_target_B(y))
        else:
            rig.command(T)
            staged.command_in_stages(T)
        st = rig.servo.state  # the fused call left the new state's FK in the cache
        assert rig._state_key[0] is st.q_rad and rig._state_key[1] is st.qd_radps
        assert staged._state_key is None or staged._state_key[0] is not staged.servo.state.q_rad
        for a, b in zip(_state(rig), _state(staged), strict=True):
            np.testing.assert_array_equal(a, b, err_msg=f"cycle {k}")
    return rig, staged


TOWARDS = pytest.mark.parametrize("towards", [False, True], ids=["target", "towards"])


@TOWARDS
def test_the_fused_command_is_the_stages_to_the_last_bit(towards):
    rig, _ = _drive(_rig({}), 300, 0.05, 0.2, towards)
    assert isinstance(rig._fused, ArmCommand)  # the fused path ran
    assert rig.vfdm.last_scale == 1.0 and not rig.servo.stopped


@TOWARDS
def test_the_fused_command_is_the_stages_with_sync_reset_and_pd_and_no_delay(towards):
    overrides = {"vfdm": {"sync_to_measured": True, "velocity_mode": "reset",
                          "kd_lin": 0.5, "kd_rot": 0.1},
                 "servo": {"delay_cycles": 0}}
    rig, _ = _drive(_rig(overrides), 200, 0.05, 0.2, towards)
    assert len(rig.servo._ring) == 0


@TOWARDS
def test_the_fused_command_is_the_stages_when_limits_act_and_the_arm_stops(towards):
    # a target far faster than the joints may go: the VFDM scales its steps down
    rig, _ = _drive(_rig({}), 60, 3.0, 4.0, towards)
    assert rig.vfdm.last_scale < 1.0
    # a safety box 1 cm around the TCP: the controller stops the arm, which then brakes
    rig = _rig({})
    box = rig.servo.safety
    p_W = box.tcp_position_W(rig.servo.state.q_rad)
    rig.servo.safety = SafetyBox(p_W - 0.01, p_W + 0.01, box.chain)
    rig, _ = _drive(rig, 80, 0.5, 0.0, towards)
    assert rig.servo.stopped and rig.servo.reason == "TCP left safety volume"
    assert np.all(np.abs(rig.servo.state.qd_radps) < 1e-3)  # braked to rest since


@pytest.mark.parametrize("fields", ["vfdm", "servo"])
@TOWARDS
def test_a_replaced_vfdm_or_servo_is_what_the_fused_command_drives(fields, towards):
    rig = _rig({})

    def command():
        T = rig.vfdm.tcp_pose()
        rig.command_towards(_ods_state(rig, T)) if towards else rig.command(T)

    command()
    old = rig._fused
    setattr(rig, fields, copy.deepcopy(getattr(rig, fields)))
    q_before = rig.servo.state.q_rad
    command()
    assert rig._fused is not old and getattr(rig._fused, fields) is getattr(rig, fields)
    assert rig.servo.state.q_rad is not q_before  # the servo in the rig stepped


def test_commanding_towards_the_ods_state_is_commanding_its_tcp_target():
    cfg = load_scenario("collision")
    rig = _rig({})
    staged = copy.deepcopy(rig)
    ods = OrbitalSimulator.from_config(cfg)
    push = np.zeros((len(cfg.satellites), 3))
    push[rig.satellite] = [3.0, -1.0, 2.0]  # N: the satellite drifts off and turns
    for k in range(200):
        ods.step(push, 0.2 * push, rig.servo.dt_s)
        rig.command_towards(ods.y)
        staged.command_in_stages(staged.tcp_target_B(ods.y))
        for a, b in zip(_state(rig), _state(staged), strict=True):
            np.testing.assert_array_equal(a, b, err_msg=f"cycle {k}")
    assert np.linalg.norm(rig.vfdm.last_error[:3]) > 0.0  # it had somewhere to go
