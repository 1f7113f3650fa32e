"""A run as a ROS 2 bag (MCAP storage, standard messages), for Foxglove, PlotJuggler and
``ros2 bag play``: written from the telemetry rows with rosbags, nothing converted later.

Topics (frames: ``world`` = the lab W, ``R`` = the orbit frame, ``robot<k>_base``,
``robot<k>_flange``, ``sat<i>`` = the satellite where the ODS has it (desired),
``sat<i>_mockup`` = the mockup where its arm holds it (actual)):

* ``/tf_static`` (tf2_msgs/TFMessage): world → R, world → each base;
* ``/tf`` (tf2_msgs/TFMessage), every recorded cycle: R → sat<i>, R → sat<i>_mockup,
  base → flange (forward kinematics of the recorded joints);
* ``/robot<k>/joint_states`` (sensor_msgs/JointState): the six joint positions;
* ``/robot<k>/ft_raw`` (geometry_msgs/WrenchStamped): the F/T sensor's raw reading, in its
  flange frame;
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
from app.sim.rotations import make_transform, matrix_to_quat, quat_to_matrix
from app.sim.ur10e import T_W_B_from_config, flange_pose_B

__all__ = ["JOINT_NAMES", "replace_bag_dir", "write_bag"]

JOINT_NAMES = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint",
               "wrist_2_joint", "wrist_3_joint")


class _Messages:
    """Builds the standard messages of one typestore (ROS 2 Humble's definitions)."""

    def __init__(self) -> None:
        from rosbags.typesys import Stores, get_typestore

        self.store = get_typestore(Stores.ROS2_HUMBLE)
        t = self.store.types
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

    def header(self, t_ns: int, frame: str):
        return self.Header(stamp=self.Time(sec=t_ns // 1_000_000_000,
                                           nanosec=t_ns % 1_000_000_000), frame_id=frame)

    def vec(self, v) -> object:
        return self.Vector3(x=float(v[0]), y=float(v[1]), z=float(v[2]))

    def transform(self, t_ns: int, parent: str, child: str, p, q_wxyz):
        q = self.Quaternion(x=float(q_wxyz[1]), y=float(q_wxyz[2]), z=float(q_wxyz[3]),
                            w=float(q_wxyz[0]))
        return self.TransformStamped(header=self.header(t_ns, parent), child_frame_id=child,
                                     transform=self.Transform(translation=self.vec(p),
                                                              rotation=q))

    def wrench(self, t_ns: int, frame: str, force, torque):
        return self.WrenchStamped(header=self.header(t_ns, frame),
                                  wrench=self.Wrench(force=self.vec(force),
                                                     torque=self.vec(torque)))

    def twist(self, t_ns: int, frame: str, linear, angular):
        return self.TwistStamped(header=self.header(t_ns, frame),
                                 twist=self.Twist(linear=self.vec(linear),
                                                  angular=self.vec(angular)))


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


def write_bag(path: str | Path, config: EmulatorConfig, rows: np.ndarray, index: dict,
              rate_hz: float | None = None) -> Path:
    """Write the telemetry ``rows`` (columns ``index``) of a run of ``config`` as a ROS 2
    bag directory at ``path`` (MCAP storage; it must not exist yet). ``rate_hz`` keeps at
    most that many rows per simulated second (all of them if None)."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    path = Path(path)
    msgs = _Messages()
    if rate_hz is not None and len(rows) > 1:
        rows = rows[::thinning_step(rate_hz, float(rows[1, 0] - rows[0, 0]))]
    n_sat = len(config.satellites)
    n_rob = sum(1 for k in range(len(config.robots)) if f"rob{k + 1}_x_m" in index)
    t_ns = np.round(rows[:, 0] * 1e9).astype(np.int64)
    T_W_R = make_transform(quat_to_matrix(config.lab.r_attitude_wxyz), config.lab.r_origin_m)

    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        def topic(name: str, msgtype: str):
            return writer.add_connection(name, msgtype, typestore=msgs.store)

        def write(conn, stamp_ns: int, message) -> None:
            writer.write(conn, int(stamp_ns), msgs.store.serialize_cdr(message,
                                                                      message.__msgtype__))

        start = int(t_ns[0]) if len(t_ns) else 0
        static = [msgs.transform(start, "world", "R", T_W_R[:3, 3],
                                 matrix_to_quat(T_W_R[:3, :3]))]
        for k in range(n_rob):
            T_W_B = T_W_B_from_config(config.robots[k])
            static.append(msgs.transform(start, "world", f"robot{k + 1}_base", T_W_B[:3, 3],
                                         matrix_to_quat(T_W_B[:3, :3])))
        write(topic("/tf_static", "tf2_msgs/msg/TFMessage"), start,
              msgs.TFMessage(transforms=static))

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
                _cols(rows, index, p, tuple(f"q{j}_rad" for j in range(1, 7))),
                _cols(rows, index, p, ("ft_fx_N", "ft_fy_N", "ft_fz_N", "ft_tx_Nm", "ft_ty_Nm",
                                       "ft_tz_Nm")),
                _cols(rows, index, p, ("pft_fx_N", "pft_fy_N", "pft_fz_N", "pft_tx_Nm",
                                       "pft_ty_Nm", "pft_tz_Nm")),
                topic(f"/robot{k}/joint_states", "sensor_msgs/msg/JointState"),
                topic(f"/robot{k}/ft_raw", "geometry_msgs/msg/WrenchStamped"),
                topic(f"/robot{k}/ft_processed", "geometry_msgs/msg/WrenchStamped"),
            ))

        for r, stamp in enumerate(t_ns):
            stamp = int(stamp)
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
            for k, sat, pos, quat, q, ft, pft, c_js, c_ft, c_pft in robots:
                transforms.append(msgs.transform(stamp, "R", f"sat{sat}_mockup", pos[r],
                                                 quat[r]))
                T_B_F = flange_pose_B(q[r])
                transforms.append(msgs.transform(stamp, f"robot{k}_base", f"robot{k}_flange",
                                                 T_B_F[:3, 3], matrix_to_quat(T_B_F[:3, :3])))
                write(c_js, stamp, msgs.JointState(
                    header=msgs.header(stamp, f"robot{k}_base"), name=list(JOINT_NAMES),
                    position=np.array(q[r], dtype=np.float64),
                    velocity=np.zeros(0), effort=np.zeros(0)))
                write(c_ft, stamp, msgs.wrench(stamp, f"robot{k}_flange", ft[r, :3], ft[r, 3:]))
                R_R_M = quat_to_matrix(quat[r])  # the processed force is in R: mockup axes
                write(c_pft, stamp, msgs.wrench(stamp, f"sat{sat}_mockup",
                                                R_R_M.T @ pft[r, :3], pft[r, 3:]))
            write(tf, stamp, msgs.TFMessage(transforms=transforms))
    return path
