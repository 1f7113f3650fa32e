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


def test_the_d_term_is_refused():
    with pytest.raises(ValueError, match="no D term"):
        RailVfdm(VfdmConfig(kd_lin=1.0), RailConfig(), np.eye(4), T_F_C,
                 np.concatenate([[0.0], HOME]))
