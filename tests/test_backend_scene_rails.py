"""The 3D scene of a run on rails (app/backend/scene.py), on a live server: the rail is drawn
along the carriage's travel and the arm's base moves with the carriage, where the loop has
it (the viser nodes the browser is sent)."""

from __future__ import annotations

import numpy as np
import pytest

from app.scenarios import load_scenario
from tests.live_server import LiveServer


@pytest.fixture(scope="module")
def live():
    with LiveServer(default_scenario="free-flying-rails") as server:
        yield server


def test_the_arm_rides_its_carriage_along_the_drawn_rail(live):
    s = live.client.post("/api/scenarios/free-flying-rails/start", json={}).json()
    assert s["status"] in ("running", "preparing", "starting"), s
    live.wait_for_scene()
    live.wait_for(lambda s: s["t_s"] > 3.0, timeout_s=60.0)
    robot = load_scenario("free-flying-rails").robots[0]
    p0, axis = np.array(robot.base_position_m), np.array(robot.rail.axis_W)
    scene = live.app.state.scene
    np.testing.assert_allclose(
        np.asarray(scene._boxes[0].points).reshape(2, 3),
        [p0 + robot.rail.travel_m[0] * axis, p0 + robot.rail.travel_m[1] * axis], atol=1e-12)
    seen = []
    for _ in range(2):
        st = live.wait_for(lambda s, t=(seen[-1][0] + 1.0 if seen else 0.0): s["t_s"] > t)
        base_W = np.array(st["robots"][0]["base_position_W_m"])
        seen.append((st["t_s"], base_W, np.array(scene._active_arms[0].root.position)))
    live.client.post("/api/stop")
    for _, base_W, shown in seen:
        # on the rail's line through the base at s = 0 ...
        off = base_W - p0
        np.testing.assert_allclose(off - (off @ axis) * axis, 0.0, atol=1e-9)
        # ... and the scene's arm where the loop's base is (to its 30 Hz update, at most
        # the carriage's 1 m/s for a few frames)
        assert np.linalg.norm(shown - base_W) < 0.05
    assert abs((seen[1][1] - seen[0][1]) @ axis) > 0.02  # the carriage moved
    assert np.linalg.norm(seen[1][2] - seen[0][2]) > 0.02  # and the arm with it
