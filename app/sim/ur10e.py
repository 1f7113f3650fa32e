"""UR10e kinematics: a Pinocchio model built from the official DH parameters.

Frames (see DESIGN.md "Frames"):

* ``B`` — robot base, DH frame 0 (= the UR controller's "Base" and the URDF link ``base``);
* ``F`` — flange, DH frame 6 (= URDF ``tool0``), Pinocchio frame ``"flange"``;
* ``C`` — mockup centre of mass = TCP; ``T_F_C`` is the mockup mounting (RobotConfig).

Joint i (1-based) turns about z of DH frame i-1, so the standard DH link transform
``Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i)`` splits into the joint rotation and a constant
placement ``Tz(d_i) Tx(a_i) Rx(alpha_i)`` that becomes the placement of joint i+1 (or of
the flange frame for i = 6).

The view model (:func:`urdf_text`) re-uses example-robot-data's UR10 meshes (the UR10e's
are not shipped there) with UR10e joint origins; its root link ``base`` is the DH base B,
so its ``tool0``/``flange`` frame equals :meth:`UR10e.fk` with no correction. The UR10
meshes live in ``base_link``, which ROS-Industrial rotates by pi about z relative to the
controller base; the URDF keeps that as the fixed joint ``base -> base_link``.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np
import pinocchio as pin

from app.config import UR10E_SPEED_LIMITS_RADPS, RobotConfig
from app.sim.rotations import make_transform, quat_to_matrix, skew

__all__ = [
    "DH_A_M",
    "DH_ALPHA_RAD",
    "DH_D_M",
    "N_JOINTS",
    "POSITION_LIMIT_RAD",
    "SPEED_LIMITS_RADPS",
    "UR10e",
    "LinkInertias",
    "T_F_C_from_config",
    "T_J6_F_dh",
    "T_W_B_from_config",
    "build_model",
    "dh_link_transform",
    "ur10_urdf_path",
    "urdf_text",
]

N_JOINTS = 6
DH_D_M = (0.1807, 0.0, 0.0, 0.17415, 0.11985, 0.11655)
DH_A_M = (0.0, -0.6127, -0.57155, 0.0, 0.0, 0.0)
DH_ALPHA_RAD = (math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0)
POSITION_LIMIT_RAD = 2.0 * math.pi
SPEED_LIMITS_RADPS = np.array(UR10E_SPEED_LIMITS_RADPS)
MAX_EFFORT_NM = (330.0, 330.0, 150.0, 56.0, 56.0, 56.0)
JOINT_NAMES = (
    "shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint",
    "wrist_1_joint", "wrist_2_joint", "wrist_3_joint",
)


def dh_link_transform(theta_rad: float, d_m: float, a_m: float, alpha_rad: float) -> np.ndarray:
    """Standard DH link transform ``Rz(theta) Tz(d) Tx(a) Rx(alpha)`` (4x4)."""
    ct, st = math.cos(theta_rad), math.sin(theta_rad)
    ca, sa = math.cos(alpha_rad), math.sin(alpha_rad)
    return np.array(
        [
            [ct, -st * ca, st * sa, a_m * ct],
            [st, ct * ca, -ct * sa, a_m * st],
            [0.0, sa, ca, d_m],
            [0.0, 0.0, 0.0, 1.0],
        ]
    )


@dataclass(frozen=True)
class LinkInertias:
    """Mass properties for :func:`build_model`.

    ``links[i]`` is the inertia of the body moved by joint i+1, expressed in that joint's
    frame (DH frame i). :func:`build_model` without it gives every link a nominal body
    (kinematics only).
    """

    links: tuple[pin.Inertia, ...]


def _nominal_inertias() -> LinkInertias:
    return LinkInertias(tuple(pin.Inertia.FromSphere(1.0, 0.05) for _ in range(N_JOINTS)))


def build_model(
    inertias: LinkInertias | None = None,
    T_F_C: np.ndarray | None = None,
    gravity: bool = True,
) -> pin.Model:
    """Pinocchio model of the UR10e from its DH parameters.

    Frames: ``"flange"`` (DH frame 6 = tool0) on joint 6 and, when ``T_F_C`` is given,
    ``"tcp"`` (mockup COM) placed at ``T_F_C`` from the flange.
    """
    inertias = inertias or _nominal_inertias()
    model = pin.Model()
    model.name = "ur10e"
    placement = pin.SE3.Identity()  # joint 1 sits at DH frame 0 = B
    parent = 0
    for i in range(N_JOINTS):
        parent = model.addJoint(
            parent,
            pin.JointModelRZ(),
            placement,
            JOINT_NAMES[i],
            np.array([MAX_EFFORT_NM[i]]),
            np.array([SPEED_LIMITS_RADPS[i]]),
            np.array([-POSITION_LIMIT_RAD]),
            np.array([POSITION_LIMIT_RAD]),
        )
        model.appendBodyToJoint(parent, inertias.links[i], pin.SE3.Identity())
        placement = pin.SE3(dh_link_transform(0.0, DH_D_M[i], DH_A_M[i], DH_ALPHA_RAD[i]))
    flange_id = model.addFrame(pin.Frame("flange", parent, placement, pin.FrameType.OP_FRAME))
    if T_F_C is not None:
        T_J6_C = placement.homogeneous @ T_F_C
        model.addFrame(
            pin.Frame("tcp", parent, flange_id, pin.SE3(T_J6_C), pin.FrameType.OP_FRAME)
        )
    if not gravity:
        model.gravity = pin.Motion.Zero()
    return model


def T_J6_F_dh() -> np.ndarray:
    """Flange (DH frame 6) in the frame of joint 6 (DH frame 5): ``Tz(d6) Rx(alpha6)``."""
    return dh_link_transform(0.0, DH_D_M[5], DH_A_M[5], DH_ALPHA_RAD[5])


class UR10e:
    """Kinematics of one UR10e: FK to flange/TCP and the TCP Jacobian (base frame)."""

    def __init__(self) -> None:
        self.model = build_model()
        self.data = self.model.createData()
        self.flange_id = self.model.getFrameId("flange")
        self.q_min_rad = np.full(N_JOINTS, -POSITION_LIMIT_RAD)
        self.q_max_rad = np.full(N_JOINTS, POSITION_LIMIT_RAD)
        self.qd_max_radps = SPEED_LIMITS_RADPS.copy()

    def fk(self, q_rad: np.ndarray) -> np.ndarray:
        """Flange pose ``T_B_F`` (4x4)."""
        pin.forwardKinematics(self.model, self.data, np.asarray(q_rad, dtype=float))
        return pin.updateFramePlacement(self.model, self.data, self.flange_id).homogeneous

    def tcp_pose(self, q_rad: np.ndarray, T_F_C: np.ndarray) -> np.ndarray:
        """TCP (mockup COM) pose ``T_B_C = T_B_F T_F_C``."""
        return self.fk(q_rad) @ T_F_C

    def tcp_jacobian(self, q_rad: np.ndarray, T_F_C: np.ndarray) -> np.ndarray:
        """6x6 Jacobian of the TCP, rows ``[v_C; omega]`` in base axes (LOCAL_WORLD_ALIGNED).

        The flange Jacobian is shifted to the TCP point: ``v_C = v_F + omega x p_FC``.
        """
        q = np.asarray(q_rad, dtype=float)
        J = pin.computeFrameJacobian(
            self.model, self.data, q, self.flange_id, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
        )
        R_B_F = self.data.oMf[self.flange_id].rotation
        p_FC_B = R_B_F @ T_F_C[:3, 3]
        J = J.copy()
        J[:3] -= skew(p_FC_B) @ J[3:]
        return J


# --- mounting ---------------------------------------------------------------------------


def T_W_B_from_config(robot: RobotConfig) -> np.ndarray:
    """Base pose in the lab, ``T_W_B``, from ``base_position_m`` / ``base_attitude_wxyz``."""
    return make_transform(quat_to_matrix(robot.base_attitude_wxyz), robot.base_position_m)


def T_F_C_from_config(robot: RobotConfig) -> np.ndarray:
    """Mockup mounting ``T_F_C``; the attitude quaternion is read as ``q_F_C`` (C -> F)."""
    return make_transform(quat_to_matrix(robot.mockup_attitude_wxyz), robot.mockup_offset_m)


# --- view model (URDF) --------------------------------------------------------------------

_UR10_URDF_REL = "share/example-robot-data/robots/ur_description/urdf/ur10_robot.urdf"

# UR10e joint origins in the ROS-Industrial layout. The UR10 y offsets of the shoulder
# (0.220941) and elbow (-0.1719) are kept so the meshes line up; the wrist-2 offset takes
# the rest, so the three sum to d4.
_SHOULDER_Y_M = 0.220941
_ELBOW_Y_M = -0.1719
_URDF_ORIGINS_M = {
    "shoulder_pan_joint": (0.0, 0.0, DH_D_M[0]),
    "shoulder_lift_joint": (0.0, _SHOULDER_Y_M, 0.0),
    "elbow_joint": (0.0, _ELBOW_Y_M, -DH_A_M[1]),
    "wrist_1_joint": (0.0, 0.0, -DH_A_M[2]),
    "wrist_2_joint": (0.0, DH_D_M[3] - _SHOULDER_Y_M - _ELBOW_Y_M, 0.0),
    "wrist_3_joint": (0.0, 0.0, DH_D_M[4]),
    "ee_fixed_joint": (0.0, DH_D_M[5], 0.0),
    "wrist_3_link-tool0_fixed_joint": (0.0, DH_D_M[5], 0.0),
}


def ur10_urdf_path() -> Path:
    """example-robot-data's UR10 URDF, found next to the installed pinocchio (cmeel prefix)."""
    candidates = [Path(pin.__file__).resolve().parents[4] / _UR10_URDF_REL]
    try:  # a non-cmeel install exposes its own module
        from example_robot_data.path import EXAMPLE_ROBOT_DATA_MODEL_DIR  # type: ignore

        candidates.insert(
            0, Path(EXAMPLE_ROBOT_DATA_MODEL_DIR) / "ur_description/urdf/ur10_robot.urdf"
        )
    except ImportError:
        pass
    for path in candidates:
        if path.is_file():
            return path
    raise FileNotFoundError(f"example-robot-data UR10 URDF not found in {candidates}")


def _fmt(v: tuple[float, ...]) -> str:
    return " ".join(repr(float(x)) for x in v)


@cache
def urdf_text() -> str:
    """URDF of the UR10e for the 3D view: UR10 meshes, UR10e joint origins and limits.

    Mesh filenames are absolute file paths. The root link is ``base`` (= DH base B);
    ``tool0`` and ``flange`` (identical) are DH frame 6.
    """
    src = ur10_urdf_path()
    share = src.parents[3]  # .../share/example-robot-data
    root = ET.fromstring(src.read_text())
    for tag in ("gazebo", "transmission"):
        for el in root.findall(tag):
            root.remove(el)
    for el in root.findall("link"):
        if el.get("name") == "world":
            root.remove(el)
    for el in root.findall("joint"):
        name = el.get("name")
        if name == "world_joint":
            root.remove(el)
            continue
        if name == "base_link-base_fixed_joint":  # re-root at the DH base
            el.set("name", "base-base_link_fixed_joint")
            el.find("parent").set("link", "base")
            el.find("child").set("link", "base_link")
            el.find("origin").set("rpy", _fmt((0.0, 0.0, math.pi)))
        if name in _URDF_ORIGINS_M:
            el.find("origin").set("xyz", _fmt(_URDF_ORIGINS_M[name]))
        if name in JOINT_NAMES:
            i = JOINT_NAMES.index(name)
            lim = el.find("limit")
            lim.set("lower", repr(-POSITION_LIMIT_RAD))
            lim.set("upper", repr(POSITION_LIMIT_RAD))
            lim.set("velocity", repr(float(SPEED_LIMITS_RADPS[i])))
            lim.set("effort", repr(MAX_EFFORT_NM[i]))
    for mesh in root.iter("mesh"):
        fn = mesh.get("filename")
        prefix = "package://example-robot-data/"
        if fn.startswith(prefix):
            mesh.set("filename", str(share / fn.removeprefix(prefix)))
    # base first so that parsers taking the first link as root agree with the tree
    base = next(el for el in root.findall("link") if el.get("name") == "base")
    root.remove(base)
    root.insert(0, base)
    ET.SubElement(root, "link", name="flange")
    joint = ET.SubElement(root, "joint", name="tool0-flange_fixed_joint", type="fixed")
    ET.SubElement(joint, "parent", link="tool0")
    ET.SubElement(joint, "child", link="flange")
    ET.SubElement(joint, "origin", xyz="0 0 0", rpy="0 0 0")
    root.set("name", "ur10e")
    return ET.tostring(root, encoding="unicode")
