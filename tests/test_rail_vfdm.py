"""The VFDM on the rail's 7-joint chain (app.sim.rail_vfdm): the posture term makes the rail
carry a ramp along it and leaves one across it to the arm; the carriage stops at its travel
end within its limits; the set-points pass the rail's servo with no protective stop.

The tracking figure is the virtual chain's TCP against the target (what the VFDM hands the
servos); the 6-joint VFDM's on the same ramp is the yardstick (0.66 mm at the ramp's start).
"""

from __future__ import annotations

import numpy as np
import pytest

from app.config import RailConfig, VfdmConfig
from app.sim.rail import chain_jacobian, chain_tcp_pose, null_vector, rail_joint_acceleration
from app.sim.rail_servo import RailServo
from app.sim.rail_vfdm import RailVfdm
from app.sim.rotations import rotvec_to_matrix
from app.sim.vfdm import JointLimits
from tests import oracle

DT = 0.002
HOME = np.array([0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0])
T_F_C = np.eye(4)
T_F_C[2, 3] = 0.07


def ramp(rail, direction_B, speed_mps, duration_s, vfdm_cfg=None):
    """Drive the chain from the home posture (carriage at 0) along a ramp of the TCP target;
    returns (set-points (n, 7), target positions (n, 3), TCP error norms (n,), solver)."""
    vf = RailVfdm(vfdm_cfg or VfdmConfig(), rail, np.eye(4), T_F_C,
                  np.concatenate([[0.0], HOME]), HOME)
    T0 = vf.tcp_pose()
    sps, targets, errs = [], [], []
    for k in range(int(round(duration_s / DT))):
        T = T0.copy()
        T[:3, 3] += np.asarray(direction_B) * speed_mps * k * DT
        q = vf.solve(T)
        sps.append(q)
        targets.append(T[:3, 3])
        errs.append(np.linalg.norm(chain_tcp_pose(vf.arm, q)[:3, 3] - T[:3, 3]))
    return np.array(sps), np.array(targets), np.array(errs), vf


def test_a_ramp_along_the_rail_is_carried_by_the_rail():
    """0.2 m/s along the rail for 3 s: the carriage follows with the null-space lag
    T = m (d / ((1 − d) h)) / k_s · dt / (N h) (app/sim/rail.py), the arm stays within
    0.05 rad of its posture, and the TCP within the 6-joint VFDM's 0.66 mm."""
    rail = RailConfig()
    v, dur = 0.2, 3.0
    sps, targets, errs, vf = ramp(rail, [1.0, 0.0, 0.0], v, dur)
    travel = targets[-1, 0] - targets[0, 0]
    assert sps[-1, 0] > 0.98 * travel
    assert np.abs(sps[:, 1:] - HOME).max() < 0.05
    assert errs.max() < 0.7e-3
    # the steady lag against the formula, with m and k_s at the posture
    q = np.concatenate([[0.0], HOME])
    n = null_vector(chain_jacobian(vf.arm, q))
    n /= n[0]
    H = np.linalg.inv(np.array([rail_joint_acceleration(vf.arm, q, e) for e in np.eye(7)]).T)
    cfg, d = VfdmConfig(), VfdmConfig().damping
    k_s = rail.posture_stiffness_Nm_per_rad * n[1:] @ n[1:]
    T = (n @ H @ n) * d / ((1 - d) * cfg.internal_dt_s) / k_s \
        * DT / (cfg.iterations * cfg.internal_dt_s)
    lag = targets[-1, 0] - targets[0, 0] - sps[-1, 0]
    assert lag == pytest.approx(v * T, rel=0.1)


def test_without_the_posture_term_the_arm_carries_the_ramp_alone():
    rail = RailConfig(posture_stiffness_Nm_per_rad=0.0)
    sps, targets, errs, _ = ramp(rail, [1.0, 0.0, 0.0], 0.2, 1.5)
    assert abs(sps[-1, 0]) < 0.02 * (targets[-1, 0] - targets[0, 0])
    assert np.abs(sps[:, 1:] - HOME).max() > 0.3
    assert errs.max() < 0.7e-3


def test_a_ramp_across_the_rail_is_carried_by_the_arm():
    """0.2 m/s across the rail for 2 s (0.4 m): the arm moves (its posture by ~0.5 rad), the
    carriage by under a quarter of the ramp (the posture term moves it only as far as that
    eases the arm)."""
    sps, targets, errs, _ = ramp(RailConfig(), [0.0, 1.0, 0.0], 0.2, 2.0)
    assert np.abs(sps[:, 0]).max() < 0.25 * np.linalg.norm(targets[-1] - targets[0])
    assert np.abs(sps[:, 1:] - HOME).max() > 0.3
    assert errs.max() < 0.7e-3


def test_the_carriage_stops_at_its_travel_end_and_the_arm_takes_the_rest():
    """Travel ends at 0.3 m, the ramp goes 0.5 m: the carriage brakes within its limits
    and stays at 0.3 m; its set-points pass the servo with no protective stop; the arm
    carries the last 0.2 m with the TCP on target."""
    rail = RailConfig(travel_m=(-1.0, 0.3))
    sps, targets, errs, _ = ramp(rail, [1.0, 0.0, 0.0], 0.2, 2.5)
    assert sps[:, 0].max() <= 0.3 and sps[-1, 0] == pytest.approx(0.3, abs=1e-6)
    step = np.diff(np.concatenate([[0.0], sps[:, 0]])) / DT
    assert np.abs(step).max() <= rail.speed_limit_mps
    assert np.abs(np.diff(np.concatenate([[0.0], step]))).max() / DT \
        <= rail.accel_limit_mps2 * (1 + 1e-9)
    servo = RailServo(rail, DT, 0.0)
    for sp in sps[:, 0]:
        servo.step(sp)
    assert not servo.stopped
    assert np.abs(sps[-1, 1:] - HOME).max() > 0.2  # the arm has moved off its posture
    assert errs.max() < 0.7e-3


def _moving_target(T0, k):
    """A target that moves and turns smoothly, with a jump every 100 cycles (the clamps)."""
    T = T0.copy()
    T[:3, 3] += 0.3 * np.array([np.sin(0.01 * k), np.cos(0.013 * k) - 1.0,
                                0.5 * np.sin(0.007 * k)])
    T[:3, :3] = rotvec_to_matrix([0.4 * np.sin(0.01 * k), 0.1, -0.2 * np.sin(0.02 * k)]) \
        @ T0[:3, :3]
    if k % 100 >= 70:
        T[:3, 3] += (0.3, -0.2, 0.1)
    return T


PD_CASES = {
    "PD damped, error scale": VfdmConfig(kd_lin=0.3, kd_rot=0.02, error_scale=1.7,
                                         damping=0.3),
    "PD reset": VfdmConfig(velocity_mode="reset", kd_lin=0.5, kd_rot=0.05),
    "P only": VfdmConfig(),
}


@pytest.mark.parametrize("name", list(PD_CASES))
def test_the_pd_law_with_the_posture_term_equals_the_pinocchio_reference(name):
    """Eq. 13's D term on the 7-joint chain as on the 6-joint arm: the set-points, speeds and
    last error of every cycle of a 200-cycle run (moving, turning, jumping target; a reset
    half-way) equal tests/oracle.py RefRailVfdm's (Pinocchio's ABA and CRBA, the posture
    term by the projector written out), with the servos' limits out of the way. The D term
    is no bystander: without it the run differs by millimetres."""
    cfg = PD_CASES[name]
    rail = RailConfig(axis_W=(0.48, -0.6, 0.64), travel_m=(-50.0, 50.0),
                      speed_limit_mps=1e6, accel_limit_mps2=1e5)
    free = JointLimits(np.full(6, 1e6), 1e9, DT)
    q0 = np.concatenate([[0.0], HOME])
    fast = RailVfdm(cfg, rail, np.eye(4), T_F_C, q0, HOME, free)
    ref = oracle.RefRailVfdm(cfg, rail, T_F_C, q0, HOME)
    p_only = RailVfdm(VfdmConfig(**{**cfg.model_dump(), "kd_lin": 0.0, "kd_rot": 0.0}), rail,
                      np.eye(4), T_F_C, q0, HOME, free)
    T0 = fast.tcp_pose()
    speed, apart = 1e-2, 0.0
    for k in range(200):
        if k == 100:
            for v in (fast, ref, p_only):
                v.reset(q0 + 0.05)
        T = _moving_target(T0, k)
        q = fast.solve(T)
        np.testing.assert_allclose(q, ref.solve(T), rtol=0, atol=1e-10)
        speed = max(speed, np.abs(ref.qd).max())
        np.testing.assert_allclose(fast.qd, ref.qd, rtol=0, atol=1e-9 * speed)
        np.testing.assert_allclose(fast.last_error, ref.last_error, rtol=0, atol=1e-11)
        apart = max(apart, np.abs(p_only.solve(T) - q).max())
    if cfg.kd_lin:
        assert apart > 1e-3
