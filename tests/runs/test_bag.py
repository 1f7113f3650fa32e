"""The ROS 2 bag of a run (app/runs/bag.py), read back with rosbags and checked against the
run's telemetry.csv: topics, message types, counts, values, and a tf tree that puts each
mockup where the telemetry has it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from app.runs.bag import JOINT_NAMES
from app.scenarios import load_scenario
from app.sim.rotations import make_transform, quat_to_matrix
from app.sim.ur10e import T_F_C_from_config, T_W_B_from_config

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
    expected = {"/tf_static": "tf2_msgs/msg/TFMessage", "/tf": "tf2_msgs/msg/TFMessage"}
    for i in (1, 2):
        expected[f"/sat{i}/ods_input"] = "geometry_msgs/msg/WrenchStamped"
        expected[f"/sat{i}/true_wrench"] = "geometry_msgs/msg/WrenchStamped"
        expected[f"/sat{i}/twist"] = "geometry_msgs/msg/TwistStamped"
        expected[f"/robot{i}/joint_states"] = "sensor_msgs/msg/JointState"
        expected[f"/robot{i}/ft_raw"] = "geometry_msgs/msg/WrenchStamped"
        expected[f"/robot{i}/ft_processed"] = "geometry_msgs/msg/WrenchStamped"
    assert types == expected
    assert len(messages["/tf_static"]) == 1
    for topic in expected:
        if topic != "/tf_static":
            assert len(messages[topic]) == len(rows), topic
    stamps = [t for t, _ in messages["/robot1/joint_states"]]
    np.testing.assert_array_equal(stamps, np.round(rows[:, 0] * 1e9).astype(np.int64))


def test_the_bag_s_values_are_the_telemetry_s(run_dir):
    _, messages = _read(run_dir / "bag")
    rows, ix = _telemetry(run_dir)
    for k in (0, len(rows) // 2, len(rows) - 1):
        row = rows[k]
        js = messages["/robot2/joint_states"][k][1]
        assert list(js.name) == list(JOINT_NAMES)
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


def test_the_tf_tree_puts_each_mockup_where_the_telemetry_has_it(run_dir):
    """world → base → flange (the joints' forward kinematics) → mockup mounting gives the
    same mockup pose as world → R → sat<i>_mockup (the telemetry's pose in R): the tree is
    one consistent set of frames."""
    _, messages = _read(run_dir / "bag")
    config = load_scenario("collision")
    static = {tf.child_frame_id: _T(tf.transform)
              for tf in messages["/tf_static"][0][1].transforms}
    k = len(messages["/tf"]) - 1
    frames = {tf.child_frame_id: (tf.header.frame_id, _T(tf.transform))
              for tf in messages["/tf"][k][1].transforms}
    for r, robot in enumerate(config.robots, start=1):
        np.testing.assert_allclose(static[f"robot{r}_base"], T_W_B_from_config(robot),
                                   atol=1e-12)
        parent, T_B_F = frames[f"robot{r}_flange"]
        assert parent == f"robot{r}_base"
        by_arm = static[f"robot{r}_base"] @ T_B_F @ T_F_C_from_config(robot)
        sat = config.satellite_index(robot.satellite) + 1
        parent, T_R_M = frames[f"sat{sat}_mockup"]
        assert parent == "R"
        by_telemetry = static["R"] @ T_R_M
        np.testing.assert_allclose(by_arm[:3, 3], by_telemetry[:3, 3], atol=1e-5)
        np.testing.assert_allclose(by_arm[:3, :3], by_telemetry[:3, :3], atol=1e-5)


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
