"""A UR10e as URDF text and as its chain of link frames, both from the project's DH
kinematics (app/sim/ur10e.py), with every link and joint name prefixed (``robot1/``...):
what the ROS 2 bag (app/runs/bag.py) publishes as ``/robot<k>/robot_description`` and in TF.

Links, base to flange: ``base_link`` (the base frame B, DH frame 0), ``shoulder_link``,
``upper_arm_link``, ``forearm_link``, ``wrist_1_link``, ``wrist_2_link``, ``wrist_3_link``
(each the frame of the joint that turns it: DH frames 1-6 before the joint's placement
to the next) and ``tool0`` (the flange F, DH frame 6, fixed on wrist_3_link). Joint i
turns link i about its z axis; its origin in link i-1 is the DH placement
``Tz(d) Tx(a) Rx(alpha)`` of link i-1 (identity for joint 1). The visuals are plain
cylinders from each link's origin to the next joint (no meshes: nothing to download).

A robot on a rail gains a root link ``rail`` (the base frame with the carriage at 0) and
the prismatic joint ``rail_joint`` from it to ``base_link``: its axis is the rail's in the
base frame, its limits the travel and the carriage's speed limit (the carriage's force is
not modelled: effort 0); its visual, a thin cylinder along the travel.
"""

from __future__ import annotations

import math

import numpy as np

from app.sim.ur10e import JOINT_NAMES, MAX_EFFORT_NM, SPEED_LIMITS_RADPS, T_J6_F, joint_placements

__all__ = ["LINK_NAMES", "RAIL_JOINT", "RAIL_LINK", "joint_names", "link_transforms",
           "link_names", "urdf_text"]

LINK_NAMES = ("base_link", "shoulder_link", "upper_arm_link", "forearm_link", "wrist_1_link",
              "wrist_2_link", "wrist_3_link", "tool0")
LINK_RADIUS_M = 0.045
RAIL_LINK = "rail"
"""A robot on a rail: the frame of its base with the carriage at 0 (its URDF's root)."""
RAIL_JOINT = "rail_joint"
"""A robot on a rail: the carriage's prismatic joint, rail to base_link."""
RAIL_RADIUS_M = 0.03


def link_names(prefix: str) -> list[str]:
    return [f"{prefix}{name}" for name in LINK_NAMES]


def joint_names(prefix: str) -> list[str]:
    return [f"{prefix}{name}" for name in JOINT_NAMES]


def _rz(q: float) -> np.ndarray:
    c, s = math.cos(q), math.sin(q)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def link_transforms(q_rad) -> list[np.ndarray]:
    """The six joints' transforms T_{i-1,i} (4x4, link i in link i-1: its placement, then
    the joint's rotation Rz(q_i)), base_link to wrist_3_link; their product, times T_J6_F
    (tool0 in wrist_3_link), is the flange pose T_B_F."""
    pR, pp = joint_placements()
    out = []
    for i in range(6):
        T = np.eye(4)
        T[:3, :3] = pR[i] @ _rz(float(q_rad[i]))
        T[:3, 3] = pp[i]
        out.append(T)
    return out


def _rpy(R: np.ndarray) -> tuple[float, float, float]:
    """URDF roll-pitch-yaw of R = Rz(yaw) Ry(pitch) Rx(roll)."""
    pitch = math.asin(max(-1.0, min(1.0, -R[2, 0])))
    return math.atan2(R[2, 1], R[2, 2]), pitch, math.atan2(R[1, 0], R[0, 0])


def _origin(p, rpy) -> str:
    return (f'<origin xyz="{p[0]:.6g} {p[1]:.6g} {p[2]:.6g}" '
            f'rpy="{rpy[0]:.9g} {rpy[1]:.9g} {rpy[2]:.9g}"/>')


def _segment_visual(v: np.ndarray, a=(0.0, 0.0, 0.0), radius_m: float = LINK_RADIUS_M) -> str:
    """A cylinder from the point a of a link to the point a + v (z turned onto v)."""
    length = float(np.linalg.norm(v))
    rpy = (0.0, math.atan2(math.hypot(v[0], v[1]), v[2]), math.atan2(v[1], v[0]))
    return (f"<visual>{_origin(np.asarray(a, dtype=float) + 0.5 * v, rpy)}<geometry>"
            f"<cylinder radius=\"{radius_m}\" length=\"{length:.6g}\"/></geometry>"
            f"<material name=\"ur_grey\"/></visual>")


def _rail_text(prefix: str, base_link: str, axis_B, travel_m, speed_limit_mps: float) -> list:
    """The rail's root link and its prismatic joint to base_link (axis_B: the rail's unit
    axis in the base frame)."""
    axis = np.asarray(axis_B, dtype=float)
    lo, hi = float(travel_m[0]), float(travel_m[1])
    return [f'<link name="{prefix}{RAIL_LINK}">'
            f'{_segment_visual((hi - lo) * axis, lo * axis, RAIL_RADIUS_M)}</link>',
            f'<joint name="{prefix}{RAIL_JOINT}" type="prismatic">'
            f'<parent link="{prefix}{RAIL_LINK}"/><child link="{base_link}"/>'
            f'{_origin((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))}'
            f'<axis xyz="{axis[0]:.12g} {axis[1]:.12g} {axis[2]:.12g}"/>'
            f'<limit lower="{lo:.9g}" upper="{hi:.9g}" effort="0" '
            f'velocity="{speed_limit_mps:.6g}"/></joint>']


def urdf_text(prefix: str, robot_name: str, rail=None) -> str:
    """The URDF of a UR10e whose link and joint names all begin with ``prefix``; on a rail
    (``rail``: its axis in the base frame, travel [min, max] and speed limit), the rail's
    link and prismatic joint before base_link."""
    pR, pp = joint_placements()
    links = link_names(prefix)
    ends = [pp[i + 1] for i in range(5)] + [T_J6_F[:3, 3]]  # the next joint, or the flange
    out = ['<?xml version="1.0"?>', f'<robot name="{robot_name}">',
           '<material name="ur_grey"><color rgba="0.7 0.7 0.7 1"/></material>',
           f'<link name="{links[0]}">{_segment_visual(np.array(pp[0]) + [0.0, 0.0, 0.05])}'
           '</link>']
    for i, name in enumerate(links[1:7]):
        out.append(f'<link name="{name}">{_segment_visual(np.asarray(ends[i]))}</link>')
    out.append(f'<link name="{links[7]}"/>')
    if rail is not None:
        out += _rail_text(prefix, links[0], *rail)
    for i, joint in enumerate(joint_names(prefix)):
        out.append(
            f'<joint name="{joint}" type="revolute"><parent link="{links[i]}"/>'
            f'<child link="{links[i + 1]}"/>{_origin(pp[i], _rpy(pR[i]))}'
            f'<axis xyz="0 0 1"/><limit lower="{-2 * math.pi:.9g}" upper="{2 * math.pi:.9g}" '
            f'effort="{MAX_EFFORT_NM[i]:g}" velocity="{SPEED_LIMITS_RADPS[i]:.6g}"/></joint>')
    out.append(f'<joint name="{prefix}wrist_3_link-tool0_fixed_joint" type="fixed">'
               f'<parent link="{links[6]}"/><child link="{links[7]}"/>'
               f'{_origin(T_J6_F[:3, 3], _rpy(T_J6_F[:3, :3]))}</joint>')
    out.append("</robot>")
    return "\n".join(out) + "\n"
