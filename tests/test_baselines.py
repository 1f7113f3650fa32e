"""Baseline IK solvers, and VFDM vs the pseudo-inverse on paths through singularities.

Set-points are judged as a real UR10e would see them at 500 Hz: the implied joint speed
``(q_k - q_{k-1}) / dt`` against the data-sheet limits, and how often a joint's motion
reverses (oscillation).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from app.config import VfdmConfig
from app.sim.rotations import matrix_to_rotvec, rotvec_to_matrix
from app.sim.ur10e import (
    SPEED_LIMITS_RADPS,
    fk_joints,
    joint_placements,
    tcp_jacobian_B,
    tcp_pose_B,
)
from app.sim.vfdm import Vfdm, pose_error
from benchmarks.baselines import DampedLeastSquaresIK, JacobianTransposeIK, PseudoInverseIK
from tests import oracle

DT = 0.002
Q0 = np.array([0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0])
T_F_C = np.eye(4)
T_F_C[:3, 3] = (0.0, 0.0, 0.07)


def run(solver, q_start, path):
    """Feed a target path; returns set-points (incl. start) and position errors."""
    solver.reset(q_start)
    qs, err = [np.array(q_start, dtype=float)], []
    for T in path:
        q = solver.solve(T)
        qs.append(q)
        err.append(np.linalg.norm(T[:3, 3] - tcp_pose_B(q, T_F_C)[:3, 3]))
    return np.array(qs), np.array(err)


def speed_ratio(qs):
    """Largest implied joint speed as a fraction of the joint's limit."""
    return float((np.abs(np.diff(qs, axis=0)) / DT / SPEED_LIMITS_RADPS).max())


def reversals(qs):
    """Per joint: sign changes of the set-point velocity, ignoring speeds < 5 % of limit."""
    qd = np.diff(qs, axis=0) / DT
    out = []
    for j in range(6):
        moving = qd[np.abs(qd[:, j]) > 0.05 * SPEED_LIMITS_RADPS[j], j]
        out.append(int(np.count_nonzero(np.diff(np.sign(moving)))))
    return out


def newton_ik(T, q_guess, n=50):
    q = np.array(q_guess, dtype=float)
    for _ in range(n):
        q += np.linalg.solve(tcp_jacobian_B(q, T_F_C), pose_error(T, tcp_pose_B(q, T_F_C)))
    return q


# --- paths -------------------------------------------------------------------------------


def wrist_near_miss_path(w_radps=0.1, miss_rad=0.002, duration_s=4.0):
    """Tilt the tool through the wrist singularity, passing it at ``miss_rad``.

    Around a posture with q5 = 0 (joints 4 and 6 aligned) the target rotates at ``w``
    about the joint-5 axis while being tilted by ``miss_rad`` about the axis the wrist
    cannot turn about there. Exact IK must flip joints 4 and 6 by ~pi within about
    ``miss / w`` seconds: peak speed ~ w / miss (50 rad/s here).
    """
    q_sing = np.array([0.2, -1.3, 1.6, -1.8, 0.0, 0.3])
    R, p = np.empty((6, 3, 3)), np.empty((6, 3))
    fk_joints(q_sing, *joint_placements(), R, p)
    z4, z5 = R[3][:, 2], R[4][:, 2]  # the axes of joints 4 and 5
    b = np.cross(z5, z4)
    b /= np.linalg.norm(b)
    T_mid = tcp_pose_B(q_sing, T_F_C)
    path = []
    n = int(duration_s / DT)
    for k in range(n + 1):
        t = (k / n - 0.5) * duration_s
        T = T_mid.copy()
        T[:3, :3] = rotvec_to_matrix(w_radps * t * z5 + miss_rad * b) @ T_mid[:3, :3]
        path.append(T)
    q_start = newton_ik(path[0], q_sing + np.array([0, 0, 0, 0, -w_radps * duration_s / 2, 0]))
    return q_start, path


def elbow_overreach_path(speed_mps=0.05, beyond_m=0.02, hold_s=0.5):
    """Straight line to the stretched-elbow pose (q3 = 0) and ``beyond_m`` past it."""
    q_start = np.array([0.2, -1.2, 0.3, -1.2, -1.57, 0.0])
    q_stretched = q_start.copy()
    q_stretched[2] = 0.0
    Ta, Tb = tcp_pose_B(q_start, T_F_C), tcp_pose_B(q_stretched, T_F_C)
    d = Tb[:3, 3] - Ta[:3, 3]
    length = np.linalg.norm(d) + beyond_m
    d *= length / np.linalg.norm(d)
    rv = matrix_to_rotvec(Tb[:3, :3] @ Ta[:3, :3].T)
    n = int(length / speed_mps / DT)
    path = []
    for k in range(n + 1 + int(hold_s / DT)):
        s = min(k / n, 1.0)
        T = Ta.copy()
        T[:3, 3] += s * d
        T[:3, :3] = rotvec_to_matrix(min(s * length / np.linalg.norm(d), 1.0) * rv) @ Ta[:3, :3]
        path.append(T)
    return q_start, path


@pytest.fixture(scope="module")
def wrist():
    return wrist_near_miss_path()


@pytest.fixture(scope="module")
def elbow():
    return elbow_overreach_path()


# --- baselines on an easy target ------------------------------------------------------------


@pytest.mark.parametrize(
    "make", [PseudoInverseIK, DampedLeastSquaresIK, JacobianTransposeIK], ids=lambda c: c.__name__
)
def test_baselines_converge_on_reachable_target(make):
    q_goal = Q0 + np.array([0.2, -0.1, 0.15, 0.1, -0.2, 0.3])
    T_goal = tcp_pose_B(q_goal, T_F_C)
    solver = make(T_F_C, Q0)
    for _ in range(400):
        q = solver.solve(T_goal)
    e = pose_error(T_goal, tcp_pose_B(q, T_F_C))
    assert np.linalg.norm(e) < 1e-4


def test_pseudo_inverse_is_newton_step():
    q_goal = Q0 + 0.05
    T_goal = tcp_pose_B(q_goal, T_F_C)
    q1 = PseudoInverseIK(T_F_C, Q0).solve(T_goal)
    assert np.abs(q1 - q_goal).max() < 1e-2  # one full step lands close
    assert np.abs(q1 - Q0).max() > 0.04


def test_baseline_updates_are_the_textbook_formulas():
    """One solve against the formulas on the Pinocchio oracle's TCP Jacobian and pose error
    (pin.log3), over random postures. Same maths on inputs 1e-16 apart: 1e-12 for J^T and
    DLS (whose 6x6 system has condition ≤ σ_max²/λ² ≈ 2e3); the pseudo-inverse amplifies
    input rounding by up to cond(J), so its bound is 100·cond(J)·eps relative."""
    arm = oracle.PinArm(T_F_C)
    rng = np.random.default_rng(0)
    eps = np.finfo(float).eps
    for q in rng.uniform(-2 * np.pi, 2 * np.pi, (300, 6)):
        T_goal = tcp_pose_B(q + rng.normal(scale=0.05, size=6), T_F_C)
        J, T = arm.tcp_jacobian(q), arm.tcp_pose(q)
        e = np.concatenate([T_goal[:3, 3] - T[:3, 3], pin.log3(T_goal[:3, :3] @ T[:3, :3].T)])
        dq = JacobianTransposeIK(T_F_C, q, alpha=0.3).solve(T_goal) - q
        np.testing.assert_allclose(dq, 0.3 * J.T @ e, rtol=0, atol=1e-12)
        dq = DampedLeastSquaresIK(T_F_C, q, damping=0.05).solve(T_goal) - q
        np.testing.assert_allclose(dq, J.T @ np.linalg.solve(J @ J.T + 0.0025 * np.eye(6), e),
                                   rtol=0, atol=1e-12)
        dq = PseudoInverseIK(T_F_C, q, gain=0.7).solve(T_goal) - q
        want = 0.7 * np.linalg.pinv(J) @ e
        bound = 100 * np.linalg.cond(J) * eps * np.linalg.norm(want) + 1e-12
        assert np.linalg.norm(dq - want) <= bound


# --- singular paths -------------------------------------------------------------------------


def test_wrist_path_really_passes_the_singularity(wrist):
    q_start, path = wrist
    assert abs(q_start[4]) > 0.15
    qs, _ = run(PseudoInverseIK(T_F_C), q_start, path)
    assert np.abs(qs[:, 4]).min() < 0.005  # exact IK skims q5 = 0


@pytest.mark.parametrize("mode", ["damped", "reset"])
def test_vfdm_crosses_wrist_singularity_within_speed_limits(wrist, mode):
    q_start, path = wrist
    qs, err = run(Vfdm(VfdmConfig(velocity_mode=mode), T_F_C), q_start, path)
    assert speed_ratio(qs) < 1.0  # measured 0.62 (damped), 0.45 (reset)
    assert max(reversals(qs)) <= 2  # one smooth reversal of joints 4/6, no chatter
    assert np.sign(qs[0, 4]) != np.sign(qs[-1, 4])  # q5 = 0 passes
    assert err.max() < 1e-3  # position still within 1 mm (measured 0.4 mm)


def test_pseudo_inverse_exceeds_speed_limits_at_wrist_singularity(wrist):
    q_start, path = wrist
    qs, _ = run(PseudoInverseIK(T_F_C), q_start, path)
    assert speed_ratio(qs) > 5.0  # measured ~17x the joint-4 limit


@pytest.mark.parametrize("mode", ["damped", "reset"])
def test_vfdm_stays_calm_at_elbow_overreach(elbow, mode):
    q_start, path = elbow
    qs, err = run(Vfdm(VfdmConfig(velocity_mode=mode), T_F_C), q_start, path)
    assert speed_ratio(qs) < 1.0  # measured 0.13 (damped), 0.12 (reset)
    assert max(reversals(qs)) <= 2
    assert abs(qs[-1, 2]) < 0.01  # ends stretched out, as close as it can get
    assert err[-1] < 0.02  # the target is 2 cm out of reach (measured 6.4 mm)


def test_pseudo_inverse_blows_up_at_elbow_overreach(elbow):
    q_start, path = elbow
    qs, _ = run(PseudoInverseIK(T_F_C), q_start, path)
    assert speed_ratio(qs) > 100.0  # measured ~9e4
    assert max(reversals(qs)) > 20  # chatters around the singular posture


def test_damped_least_squares_is_a_fair_competitor(wrist, elbow):
    """With lambda = 0.05 DLS also stays within the limits on both paths (but lags more)."""
    for q_start, path in (wrist, elbow):
        qs, _ = run(DampedLeastSquaresIK(T_F_C), q_start, path)
        assert speed_ratio(qs) < 1.0  # measured 0.47 (wrist), 0.12 (elbow)
