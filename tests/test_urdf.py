"""The view model of the UR10e (app.backend.urdf): UR10 meshes on the UR10e's kinematics."""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from app.backend.urdf import ur10_urdf_path, urdf_text
from app.sim.ur10e import JOINT_NAMES, MAX_EFFORT_NM, SPEED_LIMITS_RADPS, flange_pose_B

# The UR10 URDF's joint origins carry rpy angles written as 1.570796325 (π/2 to 9 digits,
# off by 1.8e-9 rad); through the chain that leaves ~1.5e-11 (measured) against the exact DH
# kinematics. 1e-9 is the bound.
URDF_ATOL = 1e-9


@pytest.fixture(scope="module")
def urdf_model():
    return pin.buildModelFromXML(urdf_text())


def test_source_urdf_is_example_robot_data_ur10():
    path = ur10_urdf_path()
    assert path.is_file() and path.name == "ur10_robot.urdf"


def test_urdf_fk_agrees_with_dh_kinematics(urdf_model):
    model, data = urdf_model, urdf_model.createData()
    assert model.nq == 6
    assert model.frames[1].name == "base"  # the root link is the DH base B
    assert [model.names[i] for i in range(1, 7)] == list(JOINT_NAMES)
    rng = np.random.default_rng(0)
    qs = [np.zeros(6), *rng.uniform(-2 * math.pi, 2 * math.pi, (300, 6))]
    for q in qs:
        pin.framesForwardKinematics(model, data, q)
        T_B_F = flange_pose_B(q)
        for name in ("tool0", "flange"):
            T = data.oMf[model.getFrameId(name)].homogeneous
            np.testing.assert_allclose(T, T_B_F, rtol=0, atol=URDF_ATOL)


def test_urdf_limits_are_the_ur10e_ones(urdf_model):
    np.testing.assert_array_equal(urdf_model.upperPositionLimit, np.full(6, 2 * math.pi))
    np.testing.assert_array_equal(urdf_model.lowerPositionLimit, np.full(6, -2 * math.pi))
    np.testing.assert_array_equal(urdf_model.velocityLimit, SPEED_LIMITS_RADPS)
    np.testing.assert_array_equal(urdf_model.effortLimit, MAX_EFFORT_NM)


def test_urdf_is_rooted_at_base_without_simulator_extras():
    root = ET.fromstring(urdf_text())
    assert root.get("name") == "ur10e"
    assert root.find("link").get("name") == "base"  # first link = root for simple parsers
    links = {el.get("name") for el in root.findall("link")}
    assert {"base", "base_link", "tool0", "flange"} <= links and "world" not in links
    assert not root.findall("gazebo") and not root.findall("transmission")


def test_urdf_meshes_are_absolute_existing_files():
    names = re.findall(r'filename="([^"]+)"', urdf_text())
    assert len(names) >= 14
    for n in names:
        assert Path(n).is_absolute() and Path(n).is_file(), n
