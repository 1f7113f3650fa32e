"""A run as a ROS 2 bag (MCAP storage, standard messages), for RViz2, Foxglove, PlotJuggler
and ``ros2 bag play``: written from the telemetry rows with rosbags, nothing converted later.

Frames: ``world`` = the lab W, ``R`` = the orbit frame, ``robot<k>/base_link`` …
``robot<k>/tool0`` = arm k's links (app/runs/urdf.py; ``tool0`` is the flange), ``sat<i>``
= the satellite where the ODS has it (desired), ``sat<i>_mockup`` = the mockup where its
arm holds it (actual).

Latched topics (offered with transient-local durability, as rosbag2 records a latched
publisher, so that ``ros2 bag play`` republishes them latched and late subscribers such as
tf2's and RViz2's get them), one message at the start:

* ``/tf_static`` (tf2_msgs/TFMessage): world → R, world → each arm's base_link, each
  arm's wrist_3_link → tool0;
* ``/robot<k>/robot_description`` (std_msgs/String): arm k's URDF, its names prefixed
  (on a rail, rooted at ``robot<k>/rail`` with the prismatic ``robot<k>/rail_joint`` to
  base_link);
* ``/markers`` (visualization_msgs/MarkerArray): each mockup (at sat<i>_mockup), each
  satellite's ODS pose (translucent, at sat<i>), each arm's safety box (in world, the
  box its mockup's centre must stay in); frame-locked: they follow their frames.

Every recorded cycle:

* ``/clock`` (rosgraph_msgs/Clock): the run's time;
* ``/tf`` (tf2_msgs/TFMessage): R → sat<i>, R → sat<i>_mockup, and each arm's joints
  (base_link → shoulder_link → … → wrist_3_link);
* a robot on a rail: world → robot<k>/rail (static, the base with the carriage at 0) →
  robot<k>/base_link (the carriage's travel along the rail, in /tf), and its joint_states
  end with ``robot<k>/rail_joint`` (the carriage's position in m, its speed in m/s);
* ``/robot<k>/joint_states`` (sensor_msgs/JointState): the six joints (names prefixed
  ``robot<k>/``): position, and velocity as the backward difference of the recorded
  positions since the previous row (the telemetry keeps no joint velocity; at the full
  rate this is the servo's own); effort is left empty: the arm model
  is kinematic (a joint servo) and computes no joint torques;
* ``/robot<k>/ft_raw`` (geometry_msgs/WrenchStamped): the F/T sensor's raw reading, in
  its flange frame (``robot<k>/tool0``);
* ``/robot<k>/ft_processed`` (WrenchStamped): the processed reading (bias, payload and
  inertia compensated, filtered, deadband), the wrench on the mockup's COM, in the
  mockup's frame;
* ``/sat<i>/ods_input`` (WrenchStamped): the wrench the ODS received (the processed F/T
  after the coupling), in the satellite's body frame;
* ``/sat<i>/true_wrench`` (WrenchStamped): the true external force on the mockup, in R;
* ``/sat<i>/twist`` (geometry_msgs/TwistStamped): the satellite's velocity and angular
  velocity relative to R, in its body frame;
* ``/sat<i>/gnc_wrench`` (WrenchStamped), for a satellite with a GNC (app/sim/gnc.py):
  its own thrusters' force and wheels' torque, in its body frame, in orbit units.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from app.config import EmulatorConfig
from app.runs.urdf import (
    RAIL_JOINT,
    RAIL_LINK,
    joint_names,
    link_names,
    link_transforms,
    urdf_text,
)
from app.sim.rotations import make_transform, matrix_to_quat, quat_to_matrix
from app.sim.ur10e import T_J6_F, T_W_B_from_config

__all__ = ["LATCHED", "prefix_of", "replace_bag_dir", "write_bag"]


def prefix_of(k: int) -> str:
    """The frame and joint name prefix of arm k (1-based): ``robot<k>/``."""
    return f"robot{k}/"


def _latched_qos():
    """The QoS profile a latched ROS 2 publisher offers (reliable, transient-local, keep
    last 1; durations at their defaults), as rosbag2 records it for a topic: in the
    bag's metadata.yaml and in the MCAP channel's ``offered_qos_profiles`` metadata."""
    from rosbags.interfaces import (
        Qos,
        QosDurability,
        QosHistory,
        QosLiveliness,
        QosReliability,
        QosTime,
    )

    zero = QosTime(sec=0, nsec=0)
    return Qos(history=QosHistory.KEEP_LAST, depth=1, reliability=QosReliability.RELIABLE,
               durability=QosDurability.TRANSIENT_LOCAL, deadline=zero, lifespan=zero,
               liveliness=QosLiveliness.AUTOMATIC, liveliness_lease_duration=zero,
               avoid_ros_namespace_conventions=False)


LATCHED = ("/tf_static", "/markers", "/robot<k>/robot_description")
"""The topics recorded with a transient-local QoS profile (module doc)."""


class _Messages:
    """Builds the standard messages of one typestore (ROS 2 Humble's definitions)."""

    def __init__(self) -> None:
        from rosbags.typesys import Stores, get_typestore

        self.store = get_typestore(Stores.ROS2_HUMBLE)
        t = self.store.types
        self.types = t
        self.Time, self.Header = t["builtin_interfaces/msg/Time"], t["std_msgs/msg/Header"]
        self.Vector3, self.Quaternion = t["geometry_msgs/msg/Vector3"], t[
            "geometry_msgs/msg/Quaternion"]
        self.Transform = t["geometry_msgs/msg/Transform"]
        self.TransformStamped = t["geometry_msgs/msg/TransformStamped"]
        self.TFMessage = t["tf2_msgs/msg/TFMessage"]
        self.JointState = t["sensor_msgs/msg/JointState"]
        self.Wrench, self.WrenchStamped = t["geometry_msgs/msg/Wrench"], t[
            "geometry_msgs/msg/WrenchStamped"]
        self.Twist, self.TwistStamped = t["geometry_msgs/msg/Twist"], t[
            "geometry_msgs/msg/TwistStamped"]
        self.Clock, self.String = t["rosgraph_msgs/msg/Clock"], t["std_msgs/msg/String"]

    def time(self, t_ns: int):
        return self.Time(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000)

    def header(self, t_ns: int, frame: str):
        return self.Header(stamp=self.time(t_ns), frame_id=frame)

    def vec(self, v) -> object:
        return self.Vector3(x=float(v[0]), y=float(v[1]), z=float(v[2]))

    def quat(self, q_wxyz):
        return self.Quaternion(x=float(q_wxyz[1]), y=float(q_wxyz[2]), z=float(q_wxyz[3]),
                               w=float(q_wxyz[0]))

    def transform(self, t_ns: int, parent: str, child: str, p, q_wxyz):
        return self.TransformStamped(header=self.header(t_ns, parent), child_frame_id=child,
                                     transform=self.Transform(translation=self.vec(p),
                                                              rotation=self.quat(q_wxyz)))

    def transform_of(self, t_ns: int, parent: str, child: str, T: np.ndarray):
        return self.transform(t_ns, parent, child, T[:3, 3], matrix_to_quat(T[:3, :3]))

    def wrench(self, t_ns: int, frame: str, force, torque):
        return self.WrenchStamped(header=self.header(t_ns, frame),
                                  wrench=self.Wrench(force=self.vec(force),
                                                     torque=self.vec(torque)))

    def twist(self, t_ns: int, frame: str, linear, angular):
        return self.TwistStamped(header=self.header(t_ns, frame),
                                 twist=self.Twist(linear=self.vec(linear),
                                                  angular=self.vec(angular)))

    def cube(self, t_ns: int, frame: str, ns: str, marker_id: int, centre, size, rgba):
        """A frame-locked CUBE marker (visualization_msgs/Marker) of ``size`` at ``centre``
        of ``frame``, axes the frame's."""
        t = self.types
        return t["visualization_msgs/msg/Marker"](
            header=self.header(t_ns, frame), ns=ns, id=marker_id, type=1, action=0,
            pose=t["geometry_msgs/msg/Pose"](
                position=t["geometry_msgs/msg/Point"](x=float(centre[0]), y=float(centre[1]),
                                                      z=float(centre[2])),
                orientation=self.quat((1.0, 0.0, 0.0, 0.0))),
            scale=self.vec(size), color=t["std_msgs/msg/ColorRGBA"](*map(float, rgba)),
            lifetime=t["builtin_interfaces/msg/Duration"](sec=0, nanosec=0),
            frame_locked=True, points=[], colors=[], texture_resource="",
            texture=t["sensor_msgs/msg/CompressedImage"](
                header=self.header(t_ns, frame), format="", data=np.zeros(0, dtype=np.uint8)),
            uv_coordinates=[], text="", mesh_resource="",
            mesh_file=t["visualization_msgs/msg/MeshFile"](filename="",
                                                            data=np.zeros(0, dtype=np.uint8)),
            mesh_use_embedded_materials=False)


def check_bag_dir(path: Path) -> Path:
    """``path`` can take a new bag: nothing is there, or an earlier bag (a folder of
    metadata.yaml and .mcap files, as written here); anything else is an error, raised
    before a run so that no run is wasted on it."""
    if path.is_symlink() or path.is_file():
        raise ValueError(f"{path}: exists and is not a bag folder; move it away first")
    if path.is_dir():
        names = [p.name for p in path.iterdir()]
        if not all(n == "metadata.yaml" or n.endswith(".mcap") for n in names):
            raise ValueError(f"{path}: holds files that are not a bag's ({names}); move it "
                             f"away first")
    return path


def replace_bag_dir(path: Path) -> Path:
    """``path``, made free for a new bag: an earlier bag there goes (see check_bag_dir)."""
    if check_bag_dir(path).is_dir():
        for p in path.iterdir():
            p.unlink()
        path.rmdir()
    return path


def _cols(rows: np.ndarray, index: dict, prefix: str, fields) -> np.ndarray:
    return rows[:, [index[f"{prefix}_{f}"] for f in fields]]


def thinning_step(rate_hz: float, dt_s: float) -> int:
    """Keep every step-th row: the smallest step whose rate, 1 / (step · dt_s), is at most
    rate_hz (the rate a bag is then written at)."""
    return max(1, math.ceil(1.0 / (rate_hz * dt_s) - 1e-9))


def joint_velocities(t_s: np.ndarray, q_rad: np.ndarray) -> np.ndarray:
    """Joint velocities (rad/s) from recorded joint positions (rows) at times t_s: the
    backward difference (q_k − q_{k−1}) / (t_k − t_{k−1}), the first row the forward one;
    zeros for a single row. At the loop's full rate this is the servo's own joint velocity
    (it integrates q_k = q_{k−1} + dt · qd_k, app/sim/servo.py); over thinned rows, the
    mean velocity since the previous row kept."""
    if len(t_s) < 2:
        return np.zeros_like(q_rad)
    qd = np.diff(q_rad, axis=0) / np.diff(t_s)[:, None]
    return np.concatenate([qd[:1], qd])


def _markers(msgs: _Messages, t_ns: int, config: EmulatorConfig, carried: dict[int, int]):
    """The scene's markers (module doc): mockups, the ODS poses, the safety boxes."""
    out = []
    for i, sat in enumerate(config.satellites, start=1):
        size = sat.size_m
        if i in carried:
            out.append(msgs.cube(t_ns, f"sat{i}_mockup", "mockups", i, (0.0, 0.0, 0.0), size,
                                 (0.85, 0.55, 0.15, 1.0)))
        out.append(msgs.cube(t_ns, f"sat{i}", "ods_poses", i, (0.0, 0.0, 0.0), size,
                             (0.2, 0.5, 0.9, 0.35)))
    for k in sorted(set(carried.values())):
        robot = config.robots[k - 1]
        lo, hi = np.asarray(robot.safety_box_min_m), np.asarray(robot.safety_box_max_m)
        out.append(msgs.cube(t_ns, "world", "safety_boxes", k, 0.5 * (lo + hi), hi - lo,
                             (0.9, 0.2, 0.2, 0.12)))
    return msgs.types["visualization_msgs/msg/MarkerArray"](markers=out)


RAIL_FRAME = RAIL_LINK
"""A robot on a rail: the frame of its base with the carriage at 0 (static in world; the
root of its URDF, whose prismatic RAIL_JOINT, last in its joint_states, moves base_link)."""


def _rail_of(config: EmulatorConfig, rows: np.ndarray, index: dict, k: int):
    """Robot k's (1-based) rail: (its axis in the base frame, the carriage's position and
    speed per row), or None without one."""
    robot = config.robots[k - 1]
    if robot.rail is None or f"rob{k}_rail_s_m" not in index:
        return None
    axis_B = T_W_B_from_config(robot)[:3, :3].T @ np.asarray(robot.rail.axis_W)
    return (axis_B, rows[:, index[f"rob{k}_rail_s_m"]], rows[:, index[f"rob{k}_rail_v_mps"]])


def write_bag(path: str | Path, config: EmulatorConfig, rows: np.ndarray, index: dict,
              rate_hz: float | None = None) -> Path:
    """Write the telemetry ``rows`` (columns ``index``) of a run of ``config`` as a ROS 2
    bag directory at ``path`` (MCAP storage; it must not exist yet). ``rate_hz`` keeps at
    most that many rows per simulated second (all of them if None); the joint velocities
    are differenced on every row given, before that."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    path = Path(path)
    msgs = _Messages()
    n_sat = len(config.satellites)
    n_rob = sum(1 for k in range(len(config.robots)) if f"rob{k + 1}_x_m" in index)
    qd = {k: joint_velocities(rows[:, 0], _cols(rows, index, f"rob{k}",
                                                 tuple(f"q{j}_rad" for j in range(1, 7))))
          for k in range(1, n_rob + 1)}
    if rate_hz is not None and len(rows) > 1:
        step = thinning_step(rate_hz, float(rows[1, 0] - rows[0, 0]))
        rows, qd = rows[::step], {k: v[::step] for k, v in qd.items()}
    t_ns = np.round(rows[:, 0] * 1e9).astype(np.int64)
    T_W_R = make_transform(quat_to_matrix(config.lab.r_attitude_wxyz), config.lab.r_origin_m)
    latched = [_latched_qos()]

    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        def topic(name: str, msgtype: str, qos=()):
            return writer.add_connection(name, msgtype, typestore=msgs.store,
                                         offered_qos_profiles=qos)

        def write(conn, stamp_ns: int, message) -> None:
            writer.write(conn, int(stamp_ns), msgs.store.serialize_cdr(message,
                                                                      message.__msgtype__))

        start = int(t_ns[0]) if len(t_ns) else 0
        carried = {config.satellite_index(config.robots[k - 1].satellite) + 1: k
                   for k in range(1, n_rob + 1)}
        static = [msgs.transform_of(start, "world", "R", T_W_R)]
        for k in range(1, n_rob + 1):
            links = link_names(prefix_of(k))
            robot = config.robots[k - 1]
            on_rail = robot.rail is not None and f"rob{k}_rail_s_m" in index
            static.append(msgs.transform_of(start, "world", f"{prefix_of(k)}{RAIL_FRAME}"
                                            if on_rail else links[0], T_W_B_from_config(robot)))
            static.append(msgs.transform_of(start, links[6], links[7], T_J6_F))
        write(topic("/tf_static", "tf2_msgs/msg/TFMessage", latched), start,
              msgs.TFMessage(transforms=static))
        for k in range(1, n_rob + 1):
            rail = _rail_of(config, rows, index, k)
            robot = config.robots[k - 1]
            urdf = urdf_text(prefix_of(k), f"robot{k}", None if rail is None else (
                rail[0], robot.rail.travel_m, robot.rail.speed_limit_mps))
            write(topic(f"/robot{k}/robot_description", "std_msgs/msg/String", latched), start,
                  msgs.String(data=urdf))
        write(topic("/markers", "visualization_msgs/msg/MarkerArray", latched), start,
              _markers(msgs, start, config, carried))

        clock = topic("/clock", "rosgraph_msgs/msg/Clock")
        tf = topic("/tf", "tf2_msgs/msg/TFMessage")
        sats = []
        for i in range(1, n_sat + 1):
            p = f"sat{i}"
            sats.append((
                i, _cols(rows, index, p, ("x_m", "y_m", "z_m")),
                _cols(rows, index, p, ("qw", "qx", "qy", "qz")),
                _cols(rows, index, p, ("vx_mps", "vy_mps", "vz_mps")),
                _cols(rows, index, p, ("wx_radps", "wy_radps", "wz_radps")),
                _cols(rows, index, p, ("fx_N", "fy_N", "fz_N")),
                _cols(rows, index, p, ("tx_Nm", "ty_Nm", "tz_Nm")),
                _cols(rows, index, p, ("true_fx_N", "true_fy_N", "true_fz_N")),
                topic(f"/{p}/ods_input", "geometry_msgs/msg/WrenchStamped"),
                topic(f"/{p}/true_wrench", "geometry_msgs/msg/WrenchStamped"),
                topic(f"/{p}/twist", "geometry_msgs/msg/TwistStamped"),
            ))
        gnc = [(i, _cols(rows, index, f"sat{i}", ("gnc_fx_N", "gnc_fy_N", "gnc_fz_N")),
                _cols(rows, index, f"sat{i}", ("gnc_tx_Nm", "gnc_ty_Nm", "gnc_tz_Nm")),
                sats[i - 1][2], topic(f"/sat{i}/gnc_wrench", "geometry_msgs/msg/WrenchStamped"))
               for i in range(1, n_sat + 1) if config.satellites[i - 1].gnc is not None]
        robots = []
        for k in range(1, n_rob + 1):
            p = f"rob{k}"
            robots.append((
                k, config.satellite_index(config.robots[k - 1].satellite) + 1,
                _cols(rows, index, p, ("x_m", "y_m", "z_m")),
                _cols(rows, index, p, ("qw", "qx", "qy", "qz")),
                _cols(rows, index, p, tuple(f"q{j}_rad" for j in range(1, 7))), qd[k],
                _cols(rows, index, p, ("ft_fx_N", "ft_fy_N", "ft_fz_N", "ft_tx_Nm", "ft_ty_Nm",
                                       "ft_tz_Nm")),
                _cols(rows, index, p, ("pft_fx_N", "pft_fy_N", "pft_fz_N", "pft_tx_Nm",
                                       "pft_ty_Nm", "pft_tz_Nm")),
                link_names(prefix_of(k)), joint_names(prefix_of(k)),
                topic(f"/robot{k}/joint_states", "sensor_msgs/msg/JointState"),
                topic(f"/robot{k}/ft_raw", "geometry_msgs/msg/WrenchStamped"),
                topic(f"/robot{k}/ft_processed", "geometry_msgs/msg/WrenchStamped"),
                _rail_of(config, rows, index, k),
            ))

        for r, stamp in enumerate(t_ns):
            stamp = int(stamp)
            write(clock, stamp, msgs.Clock(clock=msgs.time(stamp)))
            transforms = []
            for i, pos, quat, vel, omega, force, torque, true_f, c_in, c_true, c_tw in sats:
                transforms.append(msgs.transform(stamp, "R", f"sat{i}", pos[r], quat[r]))
                R_R_B = quat_to_matrix(quat[r])
                frame = f"sat{i}"
                write(c_in, stamp, msgs.wrench(stamp, frame, R_R_B.T @ force[r], torque[r]))
                write(c_true, stamp, msgs.wrench(stamp, "R", true_f[r], (0.0, 0.0, 0.0)))
                write(c_tw, stamp, msgs.twist(stamp, frame, R_R_B.T @ vel[r], omega[r]))
            for i, force, torque, quat, c_gnc in gnc:
                write(c_gnc, stamp, msgs.wrench(stamp, f"sat{i}",
                                                quat_to_matrix(quat[r]).T @ force[r], torque[r]))
            for (k, sat, pos, quat, q, dq, ft, pft, links, joints, c_js, c_ft,
                 c_pft, rail) in robots:
                transforms.append(msgs.transform(stamp, "R", f"sat{sat}_mockup", pos[r],
                                                 quat[r]))
                for j, T in enumerate(link_transforms(q[r])):
                    transforms.append(msgs.transform_of(stamp, links[j], links[j + 1], T))
                names, position, velocity = joints, q[r], dq[r]
                if rail is not None:  # the carriage: a prismatic joint before base_link
                    axis_B, s, v = rail
                    transforms.append(msgs.transform(stamp, f"{prefix_of(k)}{RAIL_FRAME}",
                                                     links[0], s[r] * axis_B,
                                                     (1.0, 0.0, 0.0, 0.0)))
                    names = [*joints, f"{prefix_of(k)}{RAIL_JOINT}"]
                    position, velocity = np.append(position, s[r]), np.append(velocity, v[r])
                write(c_js, stamp, msgs.JointState(
                    header=msgs.header(stamp, links[0]), name=names,
                    position=np.array(position, dtype=np.float64),
                    velocity=np.array(velocity, dtype=np.float64), effort=np.zeros(0)))
                write(c_ft, stamp, msgs.wrench(stamp, links[7], ft[r, :3], ft[r, 3:]))
                R_R_M = quat_to_matrix(quat[r])  # the processed force is in R: mockup axes
                write(c_pft, stamp, msgs.wrench(stamp, f"sat{sat}_mockup",
                                                R_R_M.T @ pft[r, :3], pft[r, 3:]))
            write(tf, stamp, msgs.TFMessage(transforms=transforms))
    return path
