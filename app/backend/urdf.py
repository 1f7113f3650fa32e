"""The view model of the UR10e for the 3D scene: a URDF with UR10 meshes, UR10e kinematics.

example-robot-data ships the UR10's meshes, not the UR10e's; this URDF re-uses them with
the UR10e's joint origins (from the DH parameters of :mod:`app.sim.ur10e`) and limits. Its
root link ``base`` is the DH base B, so its ``tool0``/``flange`` frame equals the flange
pose of :func:`app.sim.ur10e.flange_pose_B` with no correction. The UR10 meshes live in
``base_link``, which ROS-Industrial rotates by pi about z relative to the controller base;
the URDF keeps that as the fixed joint ``base -> base_link``.
"""

from __future__ import annotations

import math
import site
import sys
import xml.etree.ElementTree as ET
from functools import cache
from pathlib import Path

from app.sim.ur10e import (
    DH_A_M,
    DH_D_M,
    JOINT_NAMES,
    MAX_EFFORT_NM,
    POSITION_LIMIT_RAD,
    SPEED_LIMITS_RADPS,
)

__all__ = ["ur10_urdf_path", "urdf_text"]

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
    """example-robot-data's UR10 URDF, in the cmeel prefix of site-packages (where the
    example-robot-data wheel puts its share/ folder) or from its own module."""
    roots = [*site.getsitepackages(), *(p for p in sys.path if p.endswith("site-packages"))]
    candidates = [Path(root) / "cmeel.prefix" / _UR10_URDF_REL for root in dict.fromkeys(roots)]
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
