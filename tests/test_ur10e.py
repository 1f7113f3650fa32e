"""UR10e kinematics (app.sim.ur10e): DH chain, FK, TCP Jacobian, twist, mounting.

The compiled kernels are checked against the Pinocchio oracle (tests/oracle.py) and an
independent product of DH link transforms over many random postures. Tolerances: 1e-12
where both sides compute the same quantity by different operation orders (results are
O(1): metres up to ~1.5, unit rotations, speeds of a few m/s; measured ≤ 2e-15); looser
only for finite differences (stated there).
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

from app.config import RobotConfig
from app.sim.rotations import make_transform, matrix_to_rotvec, quat_to_matrix, rotvec_to_matrix
from app.sim.ur10e import (
    DH_A_M,
    DH_ALPHA_RAD,
    DH_D_M,
    JOINT_NAMES,
    MAX_EFFORT_NM,
    POSITION_LIMIT_RAD,
    SPEED_LIMITS_RADPS,
    T_J6_F,
    T_F_C_from_config,
    T_W_B_from_config,
    compose,
    dh_link_transform,
    end_frame,
    fk_joints,
    flange_pose_B,
    jacobian_at,
    joint_placements,
    mockup_state,
    tcp_chain,
    tcp_jacobian_B,
    tcp_pose_B,
    tcp_position_W,
)
from tests import oracle

ATOL = 1e-12
N_DRAWS = 1000

CONFIGS = [
    np.zeros(6),
    np.array([0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0]),
    np.array([0.3, -1.1, 1.9, -2.4, 0.7, 1.2]),
    np.array([-2.5, 0.4, -1.0, 3.0, -2.2, -4.0]),
    np.array([5.9, -5.5, 2.8, -0.1, 0.0, 6.2]),
    np.array([1.0, -0.5, 0.0, 0.5, math.pi, -1.0]),  # elbow stretched, wrist singular
    np.full(6, 2 * math.pi),
    np.full(6, -2 * math.pi),
]
T_F_C = make_transform(rotvec_to_matrix([0.3, -0.2, 0.5]), [0.02, -0.03, 0.07])
T_W_B = make_transform(quat_to_matrix([0.0, 1.0, 0.0, 0.0]), [0.85, 0.1, 2.0])  # upside down


def postures(n=N_DRAWS, seed=0):
    """The special postures and n uniform draws over the whole ±2π joint range."""
    rng = np.random.default_rng(seed)
    return [*CONFIGS, *rng.uniform(-2 * math.pi, 2 * math.pi, (n, 6))]


def rot_z(t):
    c, s = math.cos(t), math.sin(t)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def rot_x(t):
    c, s = math.cos(t), math.sin(t)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])


def trans(x, y, z):
    T = np.eye(4)
    T[:3, 3] = (x, y, z)
    return T


def dh_fk(q):
    """Standard DH: the product of Rz(theta) Tz(d) Tx(a) Rx(alpha), the oracle's table."""
    T = np.eye(4)
    for i in range(6):
        T = (T @ rot_z(q[i]) @ trans(0, 0, oracle.DH_D[i]) @ trans(oracle.DH_A[i], 0, 0)
             @ rot_x(oracle.DH_ALPHA[i]))
    return T


@pytest.fixture(scope="module")
def pin_arm():
    return oracle.PinArm(T_F_C)


# --- the DH chain -------------------------------------------------------------------------


def test_dh_table_is_the_official_ur10e_one():
    assert DH_D_M == oracle.DH_D
    assert DH_A_M == oracle.DH_A
    assert DH_ALPHA_RAD == oracle.DH_ALPHA
    assert JOINT_NAMES == oracle.JOINT_NAMES


def test_limits_are_the_data_sheet_ones():
    assert POSITION_LIMIT_RAD == 2 * math.pi
    np.testing.assert_allclose(np.degrees(SPEED_LIMITS_RADPS), [120, 120, 180, 180, 180, 180],
                               rtol=1e-15)
    assert MAX_EFFORT_NM == oracle.MAX_EFFORT


def test_oracle_model_carries_the_same_limits():
    """The Pinocchio model (Pink's, in benchmarks/ik_compare.py) has the app's limits."""
    m = oracle.build_model()
    np.testing.assert_array_equal(m.upperPositionLimit, np.full(6, POSITION_LIMIT_RAD))
    np.testing.assert_array_equal(m.lowerPositionLimit, np.full(6, -POSITION_LIMIT_RAD))
    np.testing.assert_array_equal(m.velocityLimit, SPEED_LIMITS_RADPS)
    np.testing.assert_array_equal(m.effortLimit, MAX_EFFORT_NM)
    assert [m.names[i] for i in range(1, 7)] == list(JOINT_NAMES)


def test_dh_link_transform_is_rz_tz_tx_rx():
    rng = np.random.default_rng(1)
    for theta, d, a, alpha in rng.uniform(-4.0, 4.0, (200, 4)):
        expected = rot_z(theta) @ trans(0, 0, d) @ trans(a, 0, 0) @ rot_x(alpha)
        np.testing.assert_allclose(dh_link_transform(theta, d, a, alpha), expected,
                                   rtol=0, atol=ATOL)


def test_chain_numbers_equal_the_pinocchio_joint_placements_exactly():
    """The kernels' placements are bit for bit those of the Pinocchio model built from the
    oracle's own DH table (same formula, Tz(d) Tx(a) Rx(alpha), no rounding between)."""
    model = oracle.build_model(T_F_C=T_F_C)
    pR, pp = joint_placements()
    for i in range(6):
        M = model.jointPlacements[i + 1]
        np.testing.assert_array_equal(pR[i], M.rotation)
        np.testing.assert_array_equal(pp[i], M.translation)
    flange = model.frames[model.getFrameId("flange")]
    assert flange.parentJoint == 6
    np.testing.assert_array_equal(T_J6_F, flange.placement.homogeneous)
    chain = tcp_chain(T_W_B, T_F_C)
    np.testing.assert_array_equal(chain.pR, pR)
    np.testing.assert_array_equal(chain.pp, pp)
    np.testing.assert_array_equal(chain.fR, T_J6_F[:3, :3])
    np.testing.assert_array_equal(chain.fp, T_J6_F[:3, 3])
    np.testing.assert_array_equal(chain.T_W_B, T_W_B)
    np.testing.assert_array_equal(chain.T_F_C, T_F_C)
    for a in chain:
        assert a.flags.c_contiguous and a.dtype == np.float64
    default = tcp_chain()
    np.testing.assert_array_equal(default.T_W_B, np.eye(4))
    np.testing.assert_array_equal(default.T_F_C, np.eye(4))


# --- forward kinematics -------------------------------------------------------------------


def test_home_posture_flange_position():
    # At all-zero joints the UR arm lies stretched along -x of the base.
    T = flange_pose_B(np.zeros(6))
    expected = [-0.6127 - 0.57155, -(0.17415 + 0.11655), 0.1807 - 0.11985]
    np.testing.assert_allclose(T[:3, 3], expected, rtol=0, atol=1e-15)


def test_flange_pose_equals_pinocchio_and_the_dh_product(pin_arm):
    for q in postures():
        T = flange_pose_B(q)
        np.testing.assert_allclose(T, pin_arm.flange_pose(q), rtol=0, atol=ATOL)
        np.testing.assert_allclose(T, dh_fk(q), rtol=0, atol=ATOL)
        np.testing.assert_array_equal(T[3], [0.0, 0.0, 0.0, 1.0])


def test_tcp_pose_equals_pinocchio_tcp_frame(pin_arm):
    """tcp_pose_B against the oracle model's own "tcp" frame (placed at T_J6_F T_F_C)."""
    model, data = pin_arm.model, pin_arm.data
    tcp_id = model.getFrameId("tcp")
    for q in postures(seed=2):
        pin.framesForwardKinematics(model, data, q)
        T = tcp_pose_B(q, T_F_C)
        np.testing.assert_allclose(T, data.oMf[tcp_id].homogeneous, rtol=0, atol=ATOL)
        np.testing.assert_allclose(T, dh_fk(q) @ T_F_C, rtol=0, atol=ATOL)


def test_joint_frames_and_kernels_equal_pinocchio(pin_arm):
    """fk_joints (every joint frame), end_frame and compose, one posture at a time."""
    pR, pp = joint_placements()
    R, p, T, T2 = np.empty((6, 3, 3)), np.empty((6, 3)), np.empty((4, 4)), np.empty((4, 4))
    for q in postures(seed=3):
        fk_joints(q, pR, pp, R, p)
        R_ref, p_ref = pin_arm.joint_frames(q)
        np.testing.assert_allclose(R, R_ref, rtol=0, atol=ATOL)
        np.testing.assert_allclose(p, p_ref, rtol=0, atol=ATOL)
        end_frame(R, p, T_J6_F[:3, :3].copy(), T_J6_F[:3, 3].copy(), T)
        np.testing.assert_allclose(T[:3], pin_arm.flange_pose(q)[:3], rtol=0, atol=ATOL)
        T[3] = (0.0, 0.0, 0.0, 1.0)
        compose(T_W_B, T, T2)
        np.testing.assert_allclose(T2, T_W_B @ T, rtol=0, atol=ATOL)


# --- Jacobian and twist ---------------------------------------------------------------------


def test_tcp_jacobian_equals_pinocchio(pin_arm):
    """The LOCAL_WORLD_ALIGNED flange Jacobian shifted to the TCP, and the "tcp" frame's
    own LOCAL_WORLD_ALIGNED Jacobian (the same thing computed another way)."""
    for q in postures(seed=4):
        J = tcp_jacobian_B(q, T_F_C)
        np.testing.assert_allclose(J, pin_arm.tcp_jacobian(q), rtol=0, atol=ATOL)
        np.testing.assert_allclose(J, pin_arm.frame_jacobian(q, "tcp"), rtol=0, atol=ATOL)


def test_jacobian_at_any_point_is_the_shifted_jacobian(pin_arm):
    """jacobian_at(c): linear rows ``z_i × (c − p_i)``, i.e. the flange's shifted to c."""
    pR, pp = joint_placements()
    R, p, J = np.empty((6, 3, 3)), np.empty((6, 3)), np.empty((6, 6))
    rng = np.random.default_rng(5)
    for q in postures(300, seed=5):
        c = rng.uniform(-2.0, 2.0, 3)
        fk_joints(q, pR, pp, R, p)
        jacobian_at(R, p, c, J)
        J_F = pin_arm.frame_jacobian(q, "flange")
        r = c - pin_arm.flange_pose(q)[:3, 3]
        np.testing.assert_allclose(J[3:], J_F[3:], rtol=0, atol=ATOL)
        np.testing.assert_allclose(J[:3], J_F[:3] - oracle.skew(r) @ J_F[3:], rtol=0, atol=ATOL)


def test_tcp_jacobian_matches_finite_differences():
    """Central differences of tcp_pose_B (h = 1e-6): truncation ~h² and rounding ~eps/h
    leave ~3e-10 (measured); 1e-8 is the bound."""
    h = 1e-6
    for q in postures(150, seed=6):
        J = tcp_jacobian_B(q, T_F_C)
        R0 = tcp_pose_B(q, T_F_C)[:3, :3]
        for j in range(6):
            dq = np.zeros(6)
            dq[j] = h
            Tp, Tm = tcp_pose_B(q + dq, T_F_C), tcp_pose_B(q - dq, T_F_C)
            v = (Tp[:3, 3] - Tm[:3, 3]) / (2 * h)
            w = (matrix_to_rotvec(Tp[:3, :3] @ R0.T)
                 - matrix_to_rotvec(Tm[:3, :3] @ R0.T)) / (2 * h)
            np.testing.assert_allclose(J[:3, j], v, rtol=0, atol=1e-8)
            np.testing.assert_allclose(J[3:, j], w, rtol=0, atol=1e-8)


def test_tcp_position_and_mockup_state_equal_pinocchio(pin_arm):
    """Flange and TCP poses in W, and the TCP twist ``R_W_B J_C q̇`` in W."""
    robot = RobotConfig(
        name="r", satellite="s", base_position_m=(0.85, 0.1, 2.0),
        base_attitude_wxyz=(0.0, 1.0, 0.0, 0.0), mockup_offset_m=(0.01, -0.02, 0.07),
        mockup_attitude_wxyz=(0.9, 0.1, -0.3, 0.2),
    )
    T_W_B_r, T_F_C_r = T_W_B_from_config(robot), T_F_C_from_config(robot)
    arm = oracle.PinArm(T_F_C_r)
    chain = tcp_chain(T_W_B_r, T_F_C_r)
    rng = np.random.default_rng(7)
    p = np.empty(3)
    out = (np.empty((4, 4)), np.empty((4, 4)), np.empty(3), np.empty(3))
    for q in postures(seed=7):
        qd = rng.uniform(-3.0, 3.0, 6)
        tcp_position_W(q, *chain, p)
        T_W_F = T_W_B_r @ arm.flange_pose(q)
        np.testing.assert_allclose(p, (T_W_F @ T_F_C_r)[:3, 3], rtol=0, atol=ATOL)
        mockup_state(q, qd, *chain, *out)
        twist = arm.tcp_jacobian(q) @ qd
        expected = (T_W_F, T_W_F @ T_F_C_r, T_W_B_r[:3, :3] @ twist[:3],
                    T_W_B_r[:3, :3] @ twist[3:])
        for got, want in zip(out, expected, strict=True):
            np.testing.assert_allclose(got, want, rtol=0, atol=ATOL)


def test_mockup_twist_is_the_time_derivative_of_the_pose():
    """Independent of any Jacobian: the pose moved along q + t q̇, central differences in t
    (h = 1e-6; ~1e-9 of truncation and rounding on speeds of a few m/s, bound 1e-7)."""
    chain = tcp_chain(T_W_B, T_F_C)
    rng = np.random.default_rng(8)
    h = 1e-6
    out, plus, minus = (
        (np.empty((4, 4)), np.empty((4, 4)), np.empty(3), np.empty(3)) for _ in range(3)
    )
    for q in postures(150, seed=8):
        qd = rng.uniform(-2.0, 2.0, 6)
        mockup_state(q, qd, *chain, *out)
        mockup_state(q + h * qd, qd, *chain, *plus)
        mockup_state(q - h * qd, qd, *chain, *minus)
        v = (plus[1][:3, 3] - minus[1][:3, 3]) / (2 * h)
        w = matrix_to_rotvec(plus[1][:3, :3] @ minus[1][:3, :3].T) / (2 * h)
        np.testing.assert_allclose(out[2], v, rtol=0, atol=1e-7)
        np.testing.assert_allclose(out[3], w, rtol=0, atol=1e-7)


# --- mounting -------------------------------------------------------------------------------


def test_mounting_transforms_from_config():
    c, s = math.cos(math.pi / 4), math.sin(math.pi / 4)
    robot = RobotConfig(
        name="r", satellite="s", base_position_m=(0.1, 0.2, 2.5),
        base_attitude_wxyz=(0.0, 1.0, 0.0, 0.0),  # upside down: pi about x
        mockup_offset_m=(0.0, 0.0, 0.07), mockup_attitude_wxyz=(c, 0.0, 0.0, s),
    )
    T_W_B_r = T_W_B_from_config(robot)
    np.testing.assert_allclose(T_W_B_r[:3, 3], (0.1, 0.2, 2.5), rtol=0, atol=1e-15)
    np.testing.assert_allclose(T_W_B_r[:3, :3] @ [0, 0, 1], [0, 0, -1], atol=1e-15)  # z down
    T_F_C_r = T_F_C_from_config(robot)
    np.testing.assert_allclose(T_F_C_r[:3, 3], (0, 0, 0.07), rtol=0, atol=1e-15)
    np.testing.assert_allclose(T_F_C_r[:3, :3], quat_to_matrix(np.array([c, 0, 0, s])),
                               rtol=0, atol=1e-15)
    np.testing.assert_allclose(T_F_C_r[:3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-15)  # x_C = y_F
