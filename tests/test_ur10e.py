"""UR10e kinematics: DH model, TCP Jacobian, mounting transforms and the view URDF."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from app.config import RobotConfig
from app.sim.rotations import matrix_to_rotvec, quat_to_matrix
from app.sim.ur10e import T_F_C_from_config, T_W_B_from_config, UR10e, urdf_text
from app.sim.ur10e_kernel import mockup_state, tcp_chain, tcp_position_W

# Official UR10e DH table, typed in independently of the module under test.
D = [0.1807, 0.0, 0.0, 0.17415, 0.11985, 0.11655]
A = [0.0, -0.6127, -0.57155, 0.0, 0.0, 0.0]
ALPHA = [math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0]

CONFIGS = [
    np.zeros(6),
    np.array([0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0]),
    np.array([0.3, -1.1, 1.9, -2.4, 0.7, 1.2]),
    np.array([-2.5, 0.4, -1.0, 3.0, -2.2, -4.0]),
    np.array([5.9, -5.5, 2.8, -0.1, 0.0, 6.2]),
    np.array([1.0, -0.5, 0.0, 0.5, math.pi, -1.0]),
]


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
    """Standard DH: product of Rz(theta) Tz(d) Tx(a) Rx(alpha)."""
    T = np.eye(4)
    for i in range(6):
        T = T @ rot_z(q[i]) @ trans(0, 0, D[i]) @ trans(A[i], 0, 0) @ rot_x(ALPHA[i])
    return T


@pytest.fixture(scope="module")
def ur():
    return UR10e()


def mockup(offset=(0.02, -0.03, 0.07), rotvec=(0.3, -0.2, 0.5)):
    T = np.eye(4)
    angle = np.linalg.norm(rotvec)
    T[:3, :3] = pin.AngleAxis(angle, np.array(rotvec) / angle).matrix()
    T[:3, 3] = offset
    return T


@pytest.mark.parametrize("q", CONFIGS)
def test_fk_matches_independent_dh_product(ur, q):
    assert np.abs(ur.fk(q) - dh_fk(q)).max() < 1e-9


def test_home_posture_flange_position(ur):
    # At all-zero joints the UR arm lies stretched along -x of the base.
    T = ur.fk(np.zeros(6))
    expected = [-0.6127 - 0.57155, -(0.17415 + 0.11655), 0.1807 - 0.11985]
    assert np.allclose(T[:3, 3], expected, atol=1e-12)


def test_model_limits(ur):
    m = ur.model
    assert np.allclose(m.upperPositionLimit, 2 * math.pi)
    assert np.allclose(m.lowerPositionLimit, -2 * math.pi)
    assert np.allclose(np.degrees(m.velocityLimit), [120, 120, 180, 180, 180, 180])


@pytest.mark.parametrize("q", CONFIGS[1:4])
def test_tcp_jacobian_matches_finite_differences(ur, q):
    T_F_C = mockup()
    J = ur.tcp_jacobian(q, T_F_C)
    T0 = ur.tcp_pose(q, T_F_C)
    h = 1e-6
    for j in range(6):
        dq = np.zeros(6)
        dq[j] = h
        Tp, Tm = ur.tcp_pose(q + dq, T_F_C), ur.tcp_pose(q - dq, T_F_C)
        v = (Tp[:3, 3] - Tm[:3, 3]) / (2 * h)
        w = (matrix_to_rotvec(Tp[:3, :3] @ T0[:3, :3].T)
             - matrix_to_rotvec(Tm[:3, :3] @ T0[:3, :3].T)) / (2 * h)
        assert np.allclose(J[:3, j], v, atol=1e-7)
        assert np.allclose(J[3:, j], w, atol=1e-7)


def test_tcp_pose_is_flange_times_mounting(ur):
    q = CONFIGS[2]
    T_F_C = mockup()
    assert np.allclose(ur.tcp_pose(q, T_F_C), dh_fk(q) @ T_F_C, atol=1e-12)


def test_mounting_transforms_from_config():
    c, s = math.cos(math.pi / 4), math.sin(math.pi / 4)
    robot = RobotConfig(
        name="r", satellite="s", base_position_m=(0.1, 0.2, 2.5),
        base_attitude_wxyz=(0.0, 1.0, 0.0, 0.0),  # upside down: pi about x
        mockup_offset_m=(0.0, 0.0, 0.07), mockup_attitude_wxyz=(c, 0.0, 0.0, s),
    )
    T_W_B = T_W_B_from_config(robot)
    assert np.allclose(T_W_B[:3, 3], (0.1, 0.2, 2.5))
    assert np.allclose(T_W_B[:3, :3] @ [0, 0, 1], [0, 0, -1])  # base z points down
    T_F_C = T_F_C_from_config(robot)
    assert np.allclose(T_F_C[:3, 3], (0, 0, 0.07))
    assert np.allclose(T_F_C[:3, :3], quat_to_matrix(np.array([c, 0, 0, s])))
    assert np.allclose(T_F_C[:3, :3] @ [1, 0, 0], [0, 1, 0])  # mockup x = flange y


def test_urdf_fk_agrees_with_dh_model(ur):
    model = pin.buildModelFromXML(urdf_text())
    data = model.createData()
    assert model.nq == 6
    assert model.frames[1].name == "base"  # the root link is the DH base B
    for q in CONFIGS:
        pin.framesForwardKinematics(model, data, q)
        for name in ("tool0", "flange"):
            T = data.oMf[model.getFrameId(name)].homogeneous
            assert np.abs(T[:3, 3] - ur.fk(q)[:3, 3]).max() < 1e-6
            assert np.abs(T[:3, :3] - ur.fk(q)[:3, :3]).max() < 1e-6
    assert np.allclose(model.upperPositionLimit, 2 * math.pi)


def test_urdf_meshes_are_absolute_existing_files():
    names = re.findall(r'filename="([^"]+)"', urdf_text())
    assert len(names) >= 14
    for n in names:
        assert Path(n).is_absolute() and Path(n).is_file(), n


# --- the compiled kinematics (app.sim.ur10e_kernel) equals the pinocchio path ---------------


def test_compiled_tcp_position_and_mockup_state_equal_pinocchio(ur):
    robot = RobotConfig(
        name="r", satellite="s", base_position_m=(0.85, 0.1, 2.0),
        base_attitude_wxyz=(0.0, 1.0, 0.0, 0.0), mockup_offset_m=(0.01, -0.02, 0.07),
        mockup_attitude_wxyz=(0.9, 0.1, -0.3, 0.2),
    )
    T_W_B, T_F_C = T_W_B_from_config(robot), T_F_C_from_config(robot)
    chain = tcp_chain(ur.model, ur.flange_id, T_W_B, T_F_C)
    rng = np.random.default_rng(0)
    qs = [*CONFIGS, *rng.uniform(-2 * math.pi, 2 * math.pi, (300, 6))]
    for q in qs:
        qd = rng.uniform(-3.0, 3.0, 6)
        p = np.empty(3)
        tcp_position_W(q, *chain, p)
        np.testing.assert_allclose(p, (T_W_B @ ur.tcp_pose(q, T_F_C))[:3, 3], rtol=0, atol=1e-12)
        out = (np.empty((4, 4)), np.empty((4, 4)), np.empty(3), np.empty(3))
        mockup_state(q, qd, *chain, *out)
        T_W_F = T_W_B @ ur.fk(q)
        twist = ur.tcp_jacobian(q, T_F_C) @ qd
        expected = (T_W_F, T_W_F @ T_F_C, T_W_B[:3, :3] @ twist[:3], T_W_B[:3, :3] @ twist[3:])
        for got, want in zip(out, expected, strict=True):
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
