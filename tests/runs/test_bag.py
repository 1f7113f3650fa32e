"""The ROS 2 bag of a run (app/runs/bag.py), read back with rosbags and, independently, with
the mcap and mcap-ros2-support readers, and checked against the run's telemetry.csv: topics,
message types, counts, values, the latched topics' QoS, the URDF, and a tf tree that puts
each mockup where the telemetry has it."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from app.scenarios import load_scenario
from app.sim.rotations import make_transform, quat_to_matrix
from app.sim.ur10e import JOINT_NAMES, T_F_C_from_config, T_W_B_from_config, tcp_jacobian_B

EXE = str(Path(sys.executable).with_name("orbit-emulator"))
rosbags = pytest.importorskip("rosbags")


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("bag_run")
    result = subprocess.run([EXE, "run", "collision", "--duration", "0.6", "--out", str(out),
                             "--bag", "--quiet"], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    return out


def _read(bag: Path) -> tuple[dict, dict]:
    """(topic -> msgtype, topic -> [(t_ns, message)])."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    assert "storage_identifier: mcap" in (bag / "metadata.yaml").read_text()
    assert (bag / "bag.mcap").read_bytes()[:8] == b"\x89MCAP0\r\n"  # the MCAP magic
    with Reader(bag) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        messages: dict[str, list] = {t: [] for t in types}
        for conn, t_ns, raw in reader.messages():
            messages[conn.topic].append((t_ns, store.deserialize_cdr(raw, conn.msgtype)))
    return types, messages


def _telemetry(run_dir: Path) -> tuple[np.ndarray, dict]:
    lines = (run_dir / "telemetry.csv").read_text().splitlines()
    index = {name: k for k, name in enumerate(lines[0].split(","))}
    return np.loadtxt(lines[1:], delimiter=","), index


def test_the_bag_has_every_topic_with_its_standard_type_and_a_message_per_row(run_dir):
    types, messages = _read(run_dir / "bag")
    rows, _ = _telemetry(run_dir)
    expected = {"/tf_static": "tf2_msgs/msg/TFMessage", "/tf": "tf2_msgs/msg/TFMessage",
                "/clock": "rosgraph_msgs/msg/Clock",
                "/markers": "visualization_msgs/msg/MarkerArray"}
    for i in (1, 2):
        expected[f"/robot{i}/robot_description"] = "std_msgs/msg/String"
        expected[f"/sat{i}/ods_input"] = "geometry_msgs/msg/WrenchStamped"
        expected[f"/sat{i}/true_wrench"] = "geometry_msgs/msg/WrenchStamped"
        expected[f"/sat{i}/twist"] = "geometry_msgs/msg/TwistStamped"
        expected[f"/robot{i}/joint_states"] = "sensor_msgs/msg/JointState"
        expected[f"/robot{i}/ft_raw"] = "geometry_msgs/msg/WrenchStamped"
        expected[f"/robot{i}/ft_processed"] = "geometry_msgs/msg/WrenchStamped"
    assert types == expected
    latched = {"/tf_static", "/markers", "/robot1/robot_description",
               "/robot2/robot_description"}
    for topic in expected:
        assert len(messages[topic]) == (1 if topic in latched else len(rows)), topic
    stamps = [t for t, _ in messages["/robot1/joint_states"]]
    np.testing.assert_array_equal(stamps, np.round(rows[:, 0] * 1e9).astype(np.int64))


def test_the_bag_s_values_are_the_telemetry_s(run_dir):
    _, messages = _read(run_dir / "bag")
    rows, ix = _telemetry(run_dir)
    for k in (0, len(rows) // 2, len(rows) - 1):
        row = rows[k]
        js = messages["/robot2/joint_states"][k][1]
        assert list(js.name) == [f"robot2/{name}" for name in JOINT_NAMES]
        assert len(js.velocity) == 6 and len(js.effort) == 0
        np.testing.assert_allclose(js.position, [row[ix[f"rob2_q{j}_rad"]] for j in range(1, 7)],
                                   atol=1e-6)  # the CSV keeps 7 significant digits or so
        ft = messages["/robot1/ft_raw"][k][1].wrench
        np.testing.assert_allclose([ft.force.x, ft.force.y, ft.force.z, ft.torque.z],
                                   [row[ix[f"rob1_ft_{c}"]] for c in ("fx_N", "fy_N", "fz_N",
                                                                      "tz_Nm")], atol=1e-5)
        pft = messages["/robot2/ft_processed"][k][1]
        assert pft.header.frame_id == "sat2_mockup"
        R_R_M = quat_to_matrix(np.array([row[ix[f"rob2_{c}"]] for c in ("qw", "qx", "qy", "qz")]))
        np.testing.assert_allclose(
            R_R_M @ [pft.wrench.force.x, pft.wrench.force.y, pft.wrench.force.z],
            [row[ix[f"rob2_pft_f{a}_N"]] for a in "xyz"], atol=1e-5)
        # the ODS input: force given in R in the telemetry, in body axes in the bag
        R_R_B = quat_to_matrix(np.array([row[ix[f"sat1_{c}"]] for c in ("qw", "qx", "qy", "qz")]))
        w = messages["/sat1/ods_input"][k][1]
        assert w.header.frame_id == "sat1"
        force_R = R_R_B @ [w.wrench.force.x, w.wrench.force.y, w.wrench.force.z]
        np.testing.assert_allclose(force_R, [row[ix[f"sat1_f{a}_N"]] for a in "xyz"], atol=1e-5)
        tw = messages["/sat2/twist"][k][1].twist
        np.testing.assert_allclose([tw.angular.x, tw.angular.y, tw.angular.z],
                                   [row[ix[f"sat2_w{a}_radps"]] for a in "xyz"], atol=1e-6)


def _T(transform) -> np.ndarray:
    t, q = transform.translation, transform.rotation
    return make_transform(quat_to_matrix(np.array([q.w, q.x, q.y, q.z])), [t.x, t.y, t.z])


LINKS = ("base_link", "shoulder_link", "upper_arm_link", "forearm_link", "wrist_1_link",
         "wrist_2_link", "wrist_3_link", "tool0")


def test_the_tf_tree_puts_each_mockup_where_the_telemetry_has_it(run_dir):
    """world → base_link → each link of the arm in turn → tool0 (the flange) → mockup
    mounting gives the same mockup pose as world → R → sat<i>_mockup (the telemetry's pose
    in R): the tree is one consistent set of frames, every link of each arm in it under
    its prefix."""
    _, messages = _read(run_dir / "bag")
    config = load_scenario("collision")
    static = {tf.child_frame_id: (tf.header.frame_id, _T(tf.transform))
              for tf in messages["/tf_static"][0][1].transforms}
    k = len(messages["/tf"]) - 1
    frames = {tf.child_frame_id: (tf.header.frame_id, _T(tf.transform))
              for tf in messages["/tf"][k][1].transforms}
    frames.update(static)
    for r, robot in enumerate(config.robots, start=1):
        assert static[f"robot{r}/base_link"][0] == "world"
        np.testing.assert_allclose(static[f"robot{r}/base_link"][1], T_W_B_from_config(robot),
                                   atol=1e-12)
        T = np.eye(4)
        for parent, child in zip(LINKS[:-1], LINKS[1:], strict=True):
            up, T_link = frames[f"robot{r}/{child}"]
            assert up == f"robot{r}/{parent}"
            T = T @ T_link
        by_arm = static[f"robot{r}/base_link"][1] @ T @ T_F_C_from_config(robot)
        sat = config.satellite_index(robot.satellite) + 1
        parent, T_R_M = frames[f"sat{sat}_mockup"]
        assert parent == "R"
        by_telemetry = static["R"][1] @ T_R_M
        np.testing.assert_allclose(by_arm[:3, 3], by_telemetry[:3, 3], atol=1e-5)
        np.testing.assert_allclose(by_arm[:3, :3], by_telemetry[:3, :3], atol=1e-5)


def _mcap(bag: Path) -> tuple[dict, dict]:
    """With the independent readers (mcap, mcap-ros2-support): (topic -> channel metadata,
    topic -> [(log time ns, decoded message)])."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with (bag / "bag.mcap").open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        channels = {c.topic: c.metadata for c in reader.get_summary().channels.values()}
        messages: dict[str, list] = {t: [] for t in channels}
        for _, channel, message, decoded in reader.iter_decoded_messages():
            messages[channel.topic].append((message.log_time, decoded))
    return channels, messages


@pytest.fixture(scope="module")
def mcap_bag(run_dir) -> tuple[dict, dict]:
    pytest.importorskip("mcap_ros2")
    return _mcap(run_dir / "bag")


def test_the_latched_topics_are_offered_transient_local_as_rosbag2_records_them(mcap_bag):
    """``ros2 bag play`` republishes a topic with the QoS its channel says was offered:
    /tf_static, the markers and the robot descriptions must say transient-local (latched),
    or tf2 and RViz2's latched subscriptions never get them; the others say nothing."""
    import yaml

    channels, _ = mcap_bag
    for topic in ("/tf_static", "/markers", "/robot1/robot_description",
                  "/robot2/robot_description"):
        profiles = yaml.safe_load(channels[topic]["offered_qos_profiles"])
        assert len(profiles) == 1, topic
        assert profiles[0]["durability"] == "transient_local", topic
        assert profiles[0]["reliability"] == "reliable" and profiles[0]["history"] == "keep_last"
        assert profiles[0]["depth"] == 1
    assert yaml.safe_load(channels["/tf"]["offered_qos_profiles"]) == []


def test_every_topic_decodes_with_the_independent_reader(mcap_bag, run_dir):
    """Each topic decodes with mcap-ros2-support (from the schemas in the file), with
    the counts rosbags reads; /clock runs with the telemetry's time, strictly increasing."""
    _, messages = mcap_bag
    rows, _ = _telemetry(run_dir)
    types, by_rosbags = _read(run_dir / "bag")
    assert set(messages) == set(types)
    for topic, decoded in messages.items():
        assert len(decoded) == len(by_rosbags[topic]), topic
    clock = np.array([m.clock.sec + 1e-9 * m.clock.nanosec for _, m in messages["/clock"]])
    assert np.all(np.diff(clock) > 0)
    np.testing.assert_allclose(clock, rows[:, 0], atol=1e-9)


def test_the_markers_show_the_mockups_the_ods_poses_and_the_safety_boxes(mcap_bag):
    _, messages = mcap_bag
    config = load_scenario("collision")
    markers = messages["/markers"][0][1].markers
    by_ns: dict[str, list] = {}
    for m in markers:
        by_ns.setdefault(m.ns, []).append(m)
        assert m.type == 1 and m.action == 0 and m.frame_locked  # CUBE, ADD, follows its frame
    assert sorted(m.header.frame_id for m in by_ns["mockups"]) == ["sat1_mockup", "sat2_mockup"]
    assert sorted(m.header.frame_id for m in by_ns["ods_poses"]) == ["sat1", "sat2"]
    for m, robot in zip(sorted(by_ns["safety_boxes"], key=lambda m: m.id), config.robots,
                        strict=True):
        assert m.header.frame_id == "world"
        lo, hi = np.array(robot.safety_box_min_m), np.array(robot.safety_box_max_m)
        np.testing.assert_allclose([m.scale.x, m.scale.y, m.scale.z], hi - lo)
        np.testing.assert_allclose([m.pose.position.x, m.pose.position.y, m.pose.position.z],
                                   0.5 * (lo + hi))
    sat = config.satellites[0]
    m = next(m for m in by_ns["mockups"] if m.header.frame_id == "sat1_mockup")
    np.testing.assert_allclose([m.scale.x, m.scale.y, m.scale.z], sat.size_m)


def test_the_robot_descriptions_are_urdfs_whose_chain_is_the_arm_s(mcap_bag):
    """Each /robot<k>/robot_description is a URDF (parsed by yourdfpy) with every link and
    joint under the arm's prefix, whose forward kinematics to tool0 is the project's
    flange pose at any joint positions."""
    import io

    import yourdfpy

    from app.sim.ur10e import flange_pose_B

    _, messages = mcap_bag
    for k in (1, 2):
        text = messages[f"/robot{k}/robot_description"][0][1].data
        urdf = yourdfpy.URDF.load(io.StringIO(text), load_meshes=False,
                                  build_collision_scene_graph=False)
        assert set(urdf.link_map) == {f"robot{k}/{name}" for name in LINKS}
        movable = [f"robot{k}/{name}" for name in JOINT_NAMES]
        assert urdf.actuated_joint_names == movable
        q = np.array([0.4, -1.9, 1.5, 0.3, -1.2, 0.8])
        urdf.update_cfg(dict(zip(movable, q, strict=True)))
        np.testing.assert_allclose(urdf.get_transform(f"robot{k}/tool0", f"robot{k}/base_link"),
                                   flange_pose_B(q), atol=1e-9)


def test_joint_velocities_agree_with_the_mockup_s_recorded_velocity(mcap_bag, run_dir):
    """The bag's joint velocities (differenced joint positions) through the arm's Jacobian
    give the mockup velocity the telemetry recorded from the servo's own joint
    velocities (the servo integrates q_k = q_{k-1} + dt qd_k: they agree to rounding),
    every row from the second on, through the start's acceleration too."""
    _, messages = mcap_bag
    rows, ix = _telemetry(run_dir)
    config = load_scenario("collision")
    T_W_R = make_transform(quat_to_matrix(config.lab.r_attitude_wxyz), config.lab.r_origin_m)
    for k, robot in enumerate(config.robots, start=1):
        R_R_B = T_W_R[:3, :3].T @ T_W_B_from_config(robot)[:3, :3]
        T_F_C = T_F_C_from_config(robot)
        errors, speeds = [], []
        for r in range(1, len(rows)):
            js = messages[f"/robot{k}/joint_states"][r][1]
            v_R = R_R_B @ (tcp_jacobian_B(np.array(js.position), T_F_C) @ js.velocity)[:3]
            recorded = [rows[r, ix[f"rob{k}_v{a}_mps"]] for a in "xyz"]
            errors.append(np.linalg.norm(v_R - recorded))
            speeds.append(np.linalg.norm(recorded))
        assert max(speeds) > 0.05  # the arms do move
        assert max(errors) < 1e-6 * max(speeds), (k, max(errors), max(speeds))


def test_bag_rate_thins_the_messages_and_needs_bag(tmp_path):
    out = tmp_path / "thin"
    result = subprocess.run([EXE, "run", "collision", "--mode", "ideal", "--duration", "0.5",
                             "--out", str(out), "--bag", "--bag-rate", "50", "--quiet"],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    types, messages = _read(out / "bag")
    assert "/robot1/joint_states" not in types  # ideal: no arms
    assert len(messages["/sat1/twist"]) == 26  # 0.5 s at 50 Hz, both ends
    bad = subprocess.run([EXE, "run", "collision", "--bag-rate", "50", "--out",
                          str(tmp_path / "x")], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "--bag-rate: only with --bag" in bad.stderr
    assert not (tmp_path / "x").exists()
    # a bag folder that is not free is refused before anything runs
    taken = tmp_path / "taken"
    (taken / "bag").mkdir(parents=True)
    (taken / "bag" / "notes.txt").write_text("mine")
    bad = subprocess.run([EXE, "run", "collision", "--out", str(taken), "--bag", "--quiet"],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "holds files that are not a bag's" in bad.stderr
    assert not (taken / "telemetry.csv").exists()
    assert (taken / "bag" / "notes.txt").read_text() == "mine"


def test_the_thinning_step_never_writes_faster_than_asked():
    from app.runs.bag import thinning_step

    for rate_hz, dt_s, step in ((50, 1e-3, 20), (300, 1e-3, 4), (1000, 1e-3, 1),
                                (2000, 1e-3, 1), (0.5, 0.002, 1000), (333.4, 1e-3, 3)):
        assert thinning_step(rate_hz, dt_s) == step, (rate_hz, dt_s)
        assert 1.0 / (step * dt_s) <= max(rate_hz, 1.0 / dt_s) + 1e-9


# --- a robot on a rail ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def rail_run_dir(tmp_path_factory) -> Path:
    """free-flying-rails for 0.4 s with its carriage starting 0.5 m along the rail."""
    out = tmp_path_factory.mktemp("bag_rail_run")
    result = subprocess.run([EXE, "run", "free-flying-rails", "--duration", "0.4", "--out",
                             str(out), "--bag", "--quiet", "--set",
                             "robots.0.rail.start_m=0.5"],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    return out


def test_the_rail_is_a_prismatic_joint_in_joint_states_and_tf(rail_run_dir):
    """joint_states end with robot1/rail_joint at the carriage's recorded position and
    speed; world → robot1/rail (static, the base at s = 0) → robot1/base_link (the
    carriage's travel) → the arm's links → the mockup lands where the telemetry has it."""
    _, messages = _read(rail_run_dir / "bag")
    rows, index = _telemetry(rail_run_dir)
    config = load_scenario("free-flying-rails")
    robot = config.robots[0]
    states = [m for _, m in messages["/robot1/joint_states"]]
    assert len(states) == len(rows)
    for r, msg in enumerate(states):
        assert list(msg.name) == [f"robot1/{n}" for n in JOINT_NAMES] + ["robot1/rail_joint"]
        # (the CSV keeps 12 significant digits)
        assert msg.position[6] == pytest.approx(rows[r, index["rob1_rail_s_m"]], abs=1e-11)
        assert msg.velocity[6] == pytest.approx(rows[r, index["rob1_rail_v_mps"]], abs=1e-11)
    assert rows[:, index["rob1_rail_s_m"]].min() > 0.49  # it started 0.5 m along
    static = {tf.child_frame_id: (tf.header.frame_id, _T(tf.transform))
              for tf in messages["/tf_static"][0][1].transforms}
    assert static["robot1/rail"][0] == "world" and "robot1/base_link" not in static
    np.testing.assert_allclose(static["robot1/rail"][1], T_W_B_from_config(robot), atol=1e-12)
    k = len(messages["/tf"]) - 1
    frames = {tf.child_frame_id: (tf.header.frame_id, _T(tf.transform))
              for tf in messages["/tf"][k][1].transforms}
    up, T_rail_base = frames["robot1/base_link"]
    assert up == "robot1/rail"
    frames.update(static)  # (wrist_3_link → tool0)
    T = static["robot1/rail"][1] @ T_rail_base
    np.testing.assert_allclose(T[:3, 3] - static["robot1/rail"][1][:3, 3],
                               rows[k, index["rob1_rail_s_m"]] * np.array(robot.rail.axis_W),
                               atol=1e-11)
    for parent, child in zip(LINKS[:-1], LINKS[1:], strict=True):
        up, T_link = frames[f"robot1/{child}"]
        assert up == f"robot1/{parent}"
        T = T @ T_link
    by_arm = T @ T_F_C_from_config(robot)
    by_telemetry = static["R"][1] @ frames["sat1_mockup"][1]
    np.testing.assert_allclose(by_arm, by_telemetry, atol=1e-5)


def test_the_rail_s_robot_description_has_the_prismatic_joint_under_base_link(rail_run_dir):
    """The URDF of a robot on a rail (parsed by yourdfpy) is rooted at robot1/rail, whose
    prismatic robot1/rail_joint (along the rail's axis in the base frame, limited to the
    travel and the carriage's speed) carries base_link: with the joint states the bag
    records, the URDF puts tool0 where the tf tree (rail → base_link → … → tool0) has it."""
    import io

    import yourdfpy

    from app.sim.ur10e import flange_pose_B

    _, messages = _read(rail_run_dir / "bag")
    robot = load_scenario("free-flying-rails").robots[0]
    text = messages["/robot1/robot_description"][0][1].data
    urdf = yourdfpy.URDF.load(io.StringIO(text), load_meshes=False,
                              build_collision_scene_graph=False)
    assert urdf.base_link == "robot1/rail"
    joint = urdf.joint_map["robot1/rail_joint"]
    assert joint.type == "prismatic"
    assert (joint.parent, joint.child) == ("robot1/rail", "robot1/base_link")
    axis_B = T_W_B_from_config(robot)[:3, :3].T @ np.array(robot.rail.axis_W)
    np.testing.assert_allclose(joint.axis, axis_B, atol=1e-12)
    assert (joint.limit.lower, joint.limit.upper) == tuple(robot.rail.travel_m)
    assert joint.limit.velocity == robot.rail.speed_limit_mps
    assert set(urdf.actuated_joint_names) == {f"robot1/{n}" for n in JOINT_NAMES} | {
        "robot1/rail_joint"}
    state = messages["/robot1/joint_states"][-1][1]
    urdf.update_cfg(dict(zip(state.name, state.position, strict=True)))
    T_rail_F = np.eye(4)
    T_rail_F[:3, 3] = state.position[6] * axis_B
    T_rail_F = T_rail_F @ flange_pose_B(np.asarray(state.position[:6]))
    # (to the URDF text's 9 significant digits of each joint's rpy)
    np.testing.assert_allclose(urdf.get_transform("robot1/tool0", "robot1/rail"), T_rail_F,
                               atol=2e-8)
    assert state.position[6] > 0.49  # (the carriage is off its zero: the joint counts)
    # a robot without a rail keeps the plain arm (robot 2 of free-flying-rails has none)
    if "/robot2/robot_description" in messages:
        assert "rail_joint" not in messages["/robot2/robot_description"][0][1].data


# --- the tutorial (docs/tutorials/bag.md), as Foxglove and PlotJuggler read a bag ------------

TUTORIAL = Path(__file__).resolve().parents[2] / "docs" / "tutorials" / "bag.md"


def _tutorial_command(out: Path) -> list[str]:
    """The tutorial's `orbit-emulator run` line, run to 3.4 s (past the contact at 3.1 s,
    not the scenario's 8 s) without the restitution's replicates (the bag does not hold
    them), into out."""
    import shlex

    line = next(s for s in TUTORIAL.read_text().splitlines()
                if s.startswith(".venv/bin/orbit-emulator run "))
    args = shlex.split(line)[1:]
    args[args.index("--out") + 1] = str(out)
    return [EXE, *args, "--duration", "3.4", "--set", "uncertainty.enabled=false", "--quiet"]


@pytest.fixture(scope="module")
def tutorial_bag(tmp_path_factory) -> tuple[dict, dict, dict]:
    """The tutorial's bag read as Foxglove and PlotJuggler read an MCAP file: its summary's
    channels and schemas, each message decoded from the ROS 2 message definition the file
    itself carries (mcap-ros2-support; no ROS type store): (topic -> (schema encoding,
    schema name, message encoding)), (topic -> [(log time ns, message)]), the run's
    telemetry rows."""
    pytest.importorskip("mcap_ros2")
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    out = tmp_path_factory.mktemp("tutorial") / "collision-bag"
    result = subprocess.run(_tutorial_command(out), capture_output=True, text=True,
                            timeout=300)
    assert result.returncode == 0, result.stderr
    assert sorted(p.name for p in (out / "bag").iterdir()) == ["bag.mcap", "metadata.yaml"]
    with (out / "bag" / "bag.mcap").open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        channels = {c.topic: (summary.schemas[c.schema_id].encoding,
                              summary.schemas[c.schema_id].name, c.message_encoding)
                    for c in summary.channels.values()}
        messages: dict[str, list] = {t: [] for t in channels}
        for _, channel, message, decoded in reader.iter_decoded_messages():
            messages[channel.topic].append((message.log_time, decoded))
    rows, _ = _telemetry(out)
    return channels, messages, rows


def _tutorial_paths() -> list[str]:
    """Every topic or field path the tutorial names (in backquotes, starting with /)."""
    return sorted(set(re.findall(r"`(/[A-Za-z0-9_./]+)`", TUTORIAL.read_text())))


def _resolve(path: str, topics) -> tuple[str, list[str]]:
    """A path as the tools write it: a topic, Foxglove's ``/topic.field.field`` or
    PlotJuggler's ``/topic/field/field``: (the topic, its fields)."""
    topic = max((t for t in topics if path == t or path.startswith(t + ".")
                 or path.startswith(t + "/")), key=len, default=None)
    assert topic is not None, f"the tutorial names {path}, which is on no topic of the bag"
    return topic, [f for f in re.split(r"[./]", path[len(topic):]) if f]


def test_the_tutorial_s_topics_and_fields_are_in_its_bag_with_their_types(tutorial_bag):
    """Every channel is CDR with a ros2msg schema named by its standard type (what
    Foxglove's and PlotJuggler's MCAP loaders need to decode it without ROS); every topic
    and field path the tutorial names is there and gives a number (or the message) on every
    message; the 3D panel's sources have the types it draws; the display frames the
    tutorial offers are in the tf tree; and --bag-rate 100 gave 100 messages a second."""
    channels, messages, rows = tutorial_bag
    for topic, (schema_encoding, schema, encoding) in channels.items():
        assert (schema_encoding, encoding) == ("ros2msg", "cdr"), topic
        assert re.fullmatch(r"[a-z0-9_]+/msg/[A-Za-z0-9]+", schema), (topic, schema)
    paths = _tutorial_paths()
    assert len(paths) >= 8, paths
    for path in paths:
        topic, fields = _resolve(path, channels)
        assert messages[topic], topic
        for _, message in messages[topic]:
            value = message
            for field in fields:
                value = getattr(value, field)
            assert not fields or np.isfinite(value), (path, value)
    types = {topic: schema for topic, (_, schema, _) in channels.items()}
    for topic in ("/tf", "/tf_static"):
        assert types[topic] == "tf2_msgs/msg/TFMessage"
    assert types["/markers"] == "visualization_msgs/msg/MarkerArray"
    for k in (1, 2):
        assert types[f"/robot{k}/robot_description"] == "std_msgs/msg/String"
        assert messages[f"/robot{k}/robot_description"][0][1].data.startswith("<?xml")
    frames = {name for _, m in messages["/tf_static"] + messages["/tf"]
              for tf in m.transforms for name in (tf.header.frame_id, tf.child_frame_id)}
    offered = re.search(r"display frame to `(\w+)`[^`]*`(\w+)`", TUTORIAL.read_text())
    assert offered and {offered[1], offered[2]} <= frames, (offered, frames)
    # 3.4 s at 100 Hz, both ends: one message a 10 ms, on the telemetry's own times
    assert len(rows) == 1701 and len(messages["/robot1/ft_raw"]) == 341
    stamps = np.array([t for t, _ in messages["/robot1/ft_raw"]])
    np.testing.assert_array_equal(np.diff(stamps), 10_000_000)
    assert stamps[0] == 0 and stamps[-1] == 3_400_000_000  # scenario time, as the plot's


def test_the_tutorial_s_tf_and_joint_states_decode(tutorial_bag):
    """/tf: every message moves each arm's links and both mockups, with unit quaternions,
    every frame chained to world through /tf_static; /robot<k>/joint_states: the six
    joints under the arm's prefix, at the header's time, positions and velocities
    finite."""
    _, messages, _ = tutorial_bag
    static = {tf.child_frame_id: tf.header.frame_id
              for tf in messages["/tf_static"][0][1].transforms}
    for t_ns, message in messages["/tf"]:
        parents = dict(static)
        for tf in message.transforms:
            q = tf.transform.rotation
            assert abs(np.linalg.norm([q.w, q.x, q.y, q.z]) - 1.0) < 1e-9
            assert tf.header.stamp.sec * 10**9 + tf.header.stamp.nanosec == t_ns
            parents[tf.child_frame_id] = tf.header.frame_id
        for frame in ("robot1/tool0", "robot2/tool0", "sat1_mockup", "sat2_mockup"):
            chain = [frame]
            while chain[-1] != "world":
                assert chain[-1] in parents and len(chain) < 20, (frame, chain)
                chain.append(parents[chain[-1]])
    for k in (1, 2):
        for t_ns, js in messages[f"/robot{k}/joint_states"]:
            assert list(js.name) == [f"robot{k}/{name}" for name in JOINT_NAMES]
            assert js.header.stamp.sec * 10**9 + js.header.stamp.nanosec == t_ns
            assert np.all(np.isfinite(js.position)) and np.all(np.isfinite(js.velocity))


def test_the_tutorial_s_plot_shows_the_contact_s_equal_and_opposite_pushes(tutorial_bag):
    """The Plot panel of step 2: /sat1/ods_input.wrench.force.x and /sat2/… are zero
    before the contact, then equal and opposite (sat1, coming from -x, pushed back
    towards -x), a push of several newtons; /sat1/true_wrench.wrench.force.x, what the
    mockups exchanged, pushes the same way at the same time."""
    _, messages, _ = tutorial_bag
    t_s = np.array([t for t, _ in messages["/sat1/ods_input"]]) * 1e-9
    f1, f2, true1 = (np.array([m.wrench.force.x for _, m in messages[topic]])
                     for topic in ("/sat1/ods_input", "/sat2/ods_input", "/sat1/true_wrench"))
    assert np.all(f1[t_s < 2.9] == 0.0) and np.all(f2[t_s < 2.9] == 0.0)
    peak = np.argmax(np.abs(f1))
    assert 3.0 < t_s[peak] < 3.3 and f1[peak] < -1.0, (t_s[peak], f1[peak])
    np.testing.assert_allclose(f2, -f1, atol=1e-9 + 0.02 * abs(f1[peak]))
    assert true1.min() < -1.0 and 3.0 < t_s[np.argmin(true1)] < 3.3
