"""Frame transformations of the loop (app.sim.frames) against app.sim.rotations' NumPy.

Same formulas (quaternion to matrix, Shepperd's method), the kernels spelled out term by
term: 1e-12 on O(1) results (measured ≤ 1e-15).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from app.sim.frames import matrix_to_quat_into, ods_states_W, satellite_pose
from app.sim.rotations import (
    invert_transform,
    make_transform,
    matrix_to_quat,
    matrix_to_rotvec,
    quat_mul,
    quat_to_matrix,
    rotvec_to_matrix,
    rotvec_to_quat,
)

ATOL = 1e-12


def random_transform(rng, spread=1.0):
    return make_transform(rotvec_to_matrix(rng.normal(size=3)), spread * rng.normal(size=3))


def ods_state(rng, n):
    """n satellites: positions, velocities, unit quaternions (w ≥ 0), inertial rates."""
    y = np.zeros((n, 13))
    y[:, 0:3] = rng.normal(size=(n, 3))
    y[:, 3:6] = rng.normal(scale=0.1, size=(n, 3))
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q *= np.where(q[:, :1] < 0.0, -1.0, 1.0)
    y[:, 6:10] = q
    y[:, 10:13] = rng.normal(scale=0.1, size=(n, 3))
    return y


def test_satellite_pose_is_T_A_R_times_T_R_S():
    rng = np.random.default_rng(0)
    out = np.empty((4, 4))
    for _ in range(200):
        T_A_R = random_transform(rng)
        y = ods_state(rng, 4)
        for i in range(4):
            satellite_pose(T_A_R, y, i, out)
            T_R_S = make_transform(quat_to_matrix(y[i, 6:10]), y[i, 0:3])
            np.testing.assert_allclose(out, T_A_R @ T_R_S, rtol=0, atol=ATOL)
            np.testing.assert_array_equal(out[3], [0.0, 0.0, 0.0, 1.0])


def test_tcp_target_in_the_base_frame():
    """DESIGN.md: T_B_C* = inv(T_W_B) · T_W_R · T_R_sat, with T_A_R = inv(T_W_B) · T_W_R."""
    rng = np.random.default_rng(1)
    T_W_B = make_transform(quat_to_matrix([0.0, 1.0, 0.0, 0.0]), [0.85, 0.1, 2.0])
    T_W_R = make_transform(rotvec_to_matrix([0.0, 0.0, 0.4]), [0.4, 0.0, 1.0])
    y = ods_state(rng, 2)
    T_B_C, T_W_S = np.empty((4, 4)), np.empty((4, 4))
    for i in range(2):
        satellite_pose(invert_transform(T_W_B) @ T_W_R, y, i, T_B_C)
        satellite_pose(T_W_R, y, i, T_W_S)
        np.testing.assert_allclose(T_W_B @ T_B_C, T_W_S, rtol=0, atol=ATOL)
        T_R_S = make_transform(quat_to_matrix(y[i, 6:10]), y[i, 0:3])
        np.testing.assert_allclose(T_B_C, np.linalg.inv(T_W_B) @ T_W_R @ T_R_S, rtol=0,
                                   atol=ATOL)


def test_ods_states_in_the_lab():
    """Every satellite's pose in W and its COM velocity rotated from R into W."""
    rng = np.random.default_rng(2)
    for n in (1, 2, 5):
        for _ in range(100):
            T_W_R = random_transform(rng)
            y = ods_state(rng, n)
            T_W_S, v_W = np.empty((n, 4, 4)), np.empty((n, 3))
            ods_states_W(T_W_R, y, T_W_S, v_W)
            for i in range(n):
                T_R_S = make_transform(quat_to_matrix(y[i, 6:10]), y[i, 0:3])
                np.testing.assert_allclose(T_W_S[i], T_W_R @ T_R_S, rtol=0, atol=ATOL)
                np.testing.assert_allclose(v_W[i], T_W_R[:3, :3] @ y[i, 3:6], rtol=0, atol=ATOL)


def test_identity_lab_pose_gives_the_ods_state_itself():
    rng = np.random.default_rng(3)
    y = ods_state(rng, 3)
    T_W_S, v_W = np.empty((3, 4, 4)), np.empty((3, 3))
    ods_states_W(np.eye(4), y, T_W_S, v_W)
    np.testing.assert_array_equal(T_W_S[:, :3, 3], y[:, 0:3])
    np.testing.assert_array_equal(v_W, y[:, 3:6])


def _rotations(rng):
    """Random rotations, and ones that drive every branch of Shepperd's method: positive
    trace, and each diagonal element the largest with the trace ≤ 0 (angles near π)."""
    out = [np.eye(3), np.diag([-1.0, -1.0, 1.0]), np.diag([1.0, -1.0, -1.0])]  # π about z, x
    out += [rotvec_to_matrix(rng.normal(size=3)) for _ in range(500)]
    for axis in np.eye(3):
        for _ in range(100):
            tilt = axis + rng.normal(scale=0.2, size=3)
            angle = math.pi - rng.uniform(0.0, 0.5)
            out.append(rotvec_to_matrix(angle * tilt / np.linalg.norm(tilt)))
        out.append(rotvec_to_matrix(math.pi * axis))  # exactly π: w = 0
    return out


def test_matrix_to_quat_into_equals_the_numpy_function():
    rng = np.random.default_rng(4)
    buf = np.full(10, np.nan)
    branches = set()
    for R in _rotations(rng):
        q = matrix_to_quat(R)
        matrix_to_quat_into(R, buf, 3)
        np.testing.assert_allclose(buf[3:7], q, rtol=0, atol=ATOL)
        assert np.isnan(buf[:3]).all() and np.isnan(buf[7:]).all()  # only its slot written
        assert buf[3] >= 0.0 and abs(np.linalg.norm(buf[3:7]) - 1.0) < 1e-15
        np.testing.assert_allclose(quat_to_matrix(buf[3:7]), R, rtol=0, atol=ATOL)
        branches.add("trace > 0" if np.trace(R) > 0 else f"R[{np.argmax(np.diag(R))}] largest")
    assert branches == {"trace > 0", "R[0] largest", "R[1] largest", "R[2] largest"}


def test_matrix_to_quat_into_round_trips_quaternions():
    """quat -> matrix -> quat returns the same unit quaternion, sign chosen with w ≥ 0."""
    rng = np.random.default_rng(5)
    out = np.empty(4)
    for v in rng.normal(scale=2.0, size=(500, 3)):
        q = rotvec_to_quat(v)
        q = q if q[0] >= 0 else -q
        matrix_to_quat_into(quat_to_matrix(q), out, 0)
        np.testing.assert_allclose(out, q, rtol=0, atol=ATOL)
        # composing in quaternions and in matrices agrees
        p = rotvec_to_quat(rng.normal(size=3))
        matrix_to_quat_into(quat_to_matrix(p) @ quat_to_matrix(q), out, 0)
        pq = quat_mul(p, q)
        np.testing.assert_allclose(out, pq if pq[0] >= 0 else -pq, rtol=0, atol=ATOL)


def test_pose_distance_and_tracking_error_against_numpy():
    from app.sim.frames import pose_distance, tracking_error

    rng = np.random.default_rng(11)
    for _ in range(50):
        Ta = make_transform(rotvec_to_matrix(rng.normal(size=3)), rng.normal(size=3))
        Tb = make_transform(rotvec_to_matrix(rng.normal(size=3)), rng.normal(size=3))
        d, a = pose_distance(Ta, Tb)
        assert d == pytest.approx(np.linalg.norm(Ta[:3, 3] - Tb[:3, 3]), abs=1e-12)
        assert a == pytest.approx(np.linalg.norm(matrix_to_rotvec(Ta[:3, :3].T @ Tb[:3, :3])),
                                  abs=1e-6)
    y = np.zeros((2, 13))
    y[:, 6] = 1.0
    y[1, :3] = [0.1, 0.2, 0.3]
    T_W_R = make_transform(np.eye(3), np.array([1.0, 0.0, 0.0]))
    T = make_transform(np.eye(3), np.array([1.1, 0.2, 0.3 + 0.04]))
    d, a = tracking_error(T_W_R, y, 1, T)
    assert d == pytest.approx(0.04, abs=1e-12) and a == 0.0


def test_satellite_pose_refuses_a_satellite_outside_the_state():
    """An index that is no row of the ODS state: an IndexError, not a pose read from
    outside the array (the compiled code checks no bounds itself)."""
    y = np.zeros((2, 13))
    y[:, 6] = 1.0
    out = np.zeros((4, 4))
    satellite_pose(np.eye(4), y, 1, out)
    np.testing.assert_array_equal(out, np.eye(4))
    for i in (2, 7, -1):
        with pytest.raises(IndexError, match="no such satellite"):
            satellite_pose(np.eye(4), y, i, out)
