"""The 3D scene of a run on rails (app/backend/scene.py), on one live server: the rail is
drawn along the carriage's travel and the arm's base moves with the carriage, where the loop
has it (the viser nodes the browser is sent); and in a real browser (Chromium), the page's
settings set the rail and the rendered carriage moves."""

from __future__ import annotations

import numpy as np
import pytest

from app.scenarios import load_scenario
from tests.browser import HAVE_CHROMIUM, NEEDS_CHROMIUM, chromium, project, screenshot
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


# --- in a real browser ------------------------------------------------------------------------


@pytest.mark.skipif(not HAVE_CHROMIUM, reason=NEEDS_CHROMIUM)
def test_in_the_browser_the_panel_sets_the_rail_and_the_carriage_moves_in_the_scene(live):
    """The page's settings offer the rail's start, travel and speed limit (the scenario's
    as placeholders); a Start from the page runs with the travel and speed typed in; and in
    the 3D view (Chromium, software WebGL) the arm's base moves along the rail: seen from
    beside the rail, the pixels that change at the base's height lie between where the base
    was and where it went, and span most of that way."""
    pytest.importorskip("playwright.sync_api")
    pytest.importorskip("PIL.Image")
    rail = load_scenario("free-flying-rails").robots[0].rail
    live.client.post("/api/stop")
    with chromium() as browser:
        page = browser.new_page(viewport={"width": 1000, "height": 700})
        page.goto(live.url + "/")
        page.wait_for_function("document.getElementById('set-rail-0-max') !== null",
                               timeout=30_000)
        page.select_option("#scenario", "free-flying-rails")
        page.click("#settings-pop summary")
        assert page.get_attribute("#set-rail-0-min", "placeholder") == f"{rail.travel_m[0]:g}"
        assert page.get_attribute("#set-rail-0-max", "placeholder") == f"{rail.travel_m[1]:g}"
        assert page.get_attribute("#set-rail-0-start", "placeholder") == f"{rail.start_m:g}"
        assert page.get_attribute("#set-rail-0-speed",
                                  "placeholder") == f"{rail.speed_limit_mps:g}"
        page.fill("#set-rail-0-max", "1.7")
        page.fill("#set-rail-0-speed", "0.8")
        page.click("#settings-pop summary")  # (closed again: the view unhidden)
        page.click("#start-button")
        st = live.wait_for(lambda s: s["status"] == "running" and s["t_s"] > 0.1,
                           timeout_s=60.0)
        assert st["scenario"] == "free-flying-rails"
        assert st["settings"]["rails"][0]["travel_m"] == [rail.travel_m[0], 1.7]
        assert st["settings"]["rails"][0]["speed_limit_mps"] == 0.8
        page.wait_for_function("document.getElementById('settings').textContent"
                               ".includes('travel [-1.6, 1.7] m, ≤ 0.8 m/s')",
                               timeout=10_000)
        live.wait_for_scene()
        robot = load_scenario("free-flying-rails").robots[0]
        base0 = np.array(robot.base_position_m)
        # beside the rail, its first leg (toward -y) in the left of the view (the
        # viewer's panel covers the right third)
        eye, look = base0 + [-3.2, -1.4, -0.4], base0 + [0.0, -1.4, -0.4]
        for client in live.app.state.viser.get_clients().values():
            client.camera.position, client.camera.look_at = tuple(eye), tuple(look)
        fov = float(next(iter(live.app.state.viser.get_clients().values())).camera.fov)
        shots = []
        axis = np.array(rail.axis_W)
        along = lambda s: np.array(s["robots"][0]["base_position_W_m"]) @ axis  # noqa: E731
        for wanted in (lambda s: s["t_s"] > 3.0,  # then 0.3 m further along the rail
                       lambda s: abs(along(s) - shots[0][1] @ axis) > 0.3):
            live.wait_for(wanted, timeout_s=60.0)
            page.wait_for_timeout(400)  # (the scene's 30 Hz frames, the renderer's)
            img = screenshot(page)
            shots.append((img, np.array(live.state()["robots"][0]["base_position_W_m"])))
        box = page.locator("#viewer").bounding_box()
    live.client.post("/api/stop")
    (img1, b1), (img2, b2) = shots
    moved_m = (b2 - b1) @ np.array(rail.axis_W)
    assert abs(moved_m) > 0.25, moved_m  # the carriage travelled between the shots
    (u1, v1), (u2, _) = project(box, eye, look, [b1, b2], fov)
    x_max = box["x"] + 0.65 * box["width"]
    assert max(u1, u2) < x_max - 40  # (both in view, clear of the panel)
    # what changed, less the thin lines (the rail, the safety box's edges) whose
    # anti-aliasing flickers: a pixel counts when its 5x5 neighbourhood all changed
    changed = np.abs(img2 - img1).sum(axis=2) > 60
    solid = changed.copy()
    for dy in range(-2, 3):
        for dx in range(-2, 3):
            solid &= np.roll(np.roll(changed, dy, axis=0), dx, axis=1)
    band = slice(int(v1 - 12), int(v1 + 12))  # the base's height: base and shoulder
    cols = np.nonzero(solid[band, :int(x_max)].any(axis=0))[0]
    assert len(cols) > 10, "nothing moved at the base's height"
    # the base's and shoulder's own size, and the scene's frames behind the state: 0.45 m
    margin_px = 0.45 * abs(u2 - u1) / abs(moved_m)
    assert cols.min() > min(u1, u2) - margin_px and cols.max() < max(u1, u2) + margin_px, (
        cols.min(), cols.max(), u1, u2, margin_px)
    assert cols.max() - cols.min() > 0.6 * abs(u2 - u1), (cols.min(), cols.max(), u1, u2)
