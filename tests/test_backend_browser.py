"""The web app in a real browser (headless Debian Chromium, software WebGL).

One server and one page for the module: the viewer renders both arms, the page's start
button starts a scenario, a mouse drag of a gizmo arrow moves the satellite, and the loop
keeps 500 Hz with the browser connected.
"""

from __future__ import annotations

import contextlib
import io
import threading
import time
from pathlib import Path

import httpx
import numpy as np
import pytest

from app.backend.scene import CAMERA_FOV_RAD, GIZMO_OFFSET_W
from tests.browser import (
    CLIENT_FOV_RAD,
    HAVE_CHROMIUM,
    NEEDS_CHROMIUM,
    chromium,
    project,
    project_initial,
    screenshot,
)
from tests.live_server import LiveServer

pytest.importorskip("playwright.sync_api")
PIL = pytest.importorskip("PIL.Image")

VIEWPORT = {"width": 1000, "height": 700}
ARROW_HEAD = 0.9
"""Where a gizmo arrow is taken, in units of the gizmo's scale: on its head (0.77-1.05),
clear of the rotation rings, which end on each axis at 0.65."""

pytestmark = pytest.mark.skipif(not HAVE_CHROMIUM, reason=NEEDS_CHROMIUM)


@pytest.fixture(scope="module")
def live():
    with LiveServer(default_scenario="collision") as server:
        yield server


@pytest.fixture(scope="module")
def page(live):
    with chromium() as browser:
        page = browser.new_page(viewport=VIEWPORT)
        page.goto(live.url + "/")
        yield page


def _viewer_box(page) -> dict:
    return page.locator("#viewer").bounding_box()


def _wait_rendered(page, live, timeout_s: float = 60.0) -> np.ndarray:
    """Until the viewer shows the scene: the iframe area is not blank."""
    live.wait_for_scene()
    box = _viewer_box(page)
    deadline = time.monotonic() + timeout_s
    while True:
        img = screenshot(page)
        y0, x0 = int(box["y"]), int(box["x"])
        area = img[y0:y0 + int(box["height"]), x0:x0 + int(box["width"] * 0.65)]
        non_bg = np.abs(area - area.reshape(-1, 3)[0]).sum(axis=2) > 60
        if area.std() > 8 and non_bg.mean() > 0.01:
            return img
        if time.monotonic() > deadline:
            raise AssertionError(f"viewer still blank: std {area.std():.1f}, "
                                 f"non-background {non_bg.mean():.4f}")
        page.wait_for_timeout(500)


def test_viewer_renders_both_arms(live, page):
    # the page sets the frame's address from /api/health once that answers
    page.wait_for_function("document.getElementById('viewer').getAttribute('src') !== null",
                           timeout=30_000)
    assert page.locator("#viewer").get_attribute("src") == "/viewer/"  # through the app
    base = _wait_rendered(page, live)
    # the whole rig in view (the default camera frames the mockups, not the arms' homes)
    _set_cameras(live, (1.9, -2.3, 1.7), (0.0, 0.0, 0.95))
    page.wait_for_timeout(1500)  # let the meshes settle
    base = screenshot(page)
    scene = live.app.state.scene
    assert len(scene._active_arms) == 2
    box = _viewer_box(page)
    x_max = int(box["x"] + box["width"] * 0.65)  # the GUI panel is on the right
    for view in scene._active_arms:  # hide one arm: its pixels must change
        view.root.visible = False
        try:
            changed = 0
            for _ in range(20):
                page.wait_for_timeout(500)
                img = screenshot(page)
                diff = np.abs(img - base).sum(axis=2)[int(box["y"]):, :x_max] > 60
                changed = int(diff.sum())
                if changed > 1500:
                    break
        finally:
            view.root.visible = True
        assert changed > 1500, f"hiding an arm changed only {changed} pixels"
    cam = live.app.state.viser.initial_camera
    _set_cameras(live, cam.position, cam.look_at)  # back to the default, which project_initial uses
    page.wait_for_timeout(1000)


def _set_cameras(live, position, look_at) -> None:
    """Every connected viewer's camera to this pose."""
    for client in live.app.state.viser.get_clients().values():
        client.camera.position = tuple(position)
        client.camera.look_at = tuple(look_at)


def test_the_page_shows_the_fidelity_forecast_before_start(live, page):
    """Before Start, the page shows the pre-flight's forecast of the chosen scenario (the
    shipped collision), the same figure the REST answer gives."""
    assert live.state()["loop"]["cycles"] == 0
    page.wait_for_function("document.querySelector('#fidelity').textContent"
                           ".includes('fidelity forecast: restitution sd 0.')", timeout=300_000)
    f = live.client.get("/api/scenarios/collision/forecast").json()["collision_forecast"]
    assert page.text_content("#fidelity") == (
        f"fidelity forecast: restitution sd {f['restitution_sd']:.3f} (contact peak "
        f"{f['peak_force_N']:.1f} N, sensor noise {f['noise_force_N']:.2f} N)")
    assert live.state()["loop"]["cycles"] == 0  # nothing moved


def test_start_button_starts_the_scenario(live, page):
    assert live.state()["status"] == "idle" and live.state()["loop"]["cycles"] == 0
    page.wait_for_function("document.querySelector('#status').textContent"
                           ".includes('not started')", timeout=10_000)
    # a choice made on the page survives the page's polling until it is started
    page.select_option("#scenario", "free-floating")
    page.select_option("#mode", "ideal")
    page.wait_for_timeout(1500)  # three polls
    assert page.input_value("#scenario") == "free-floating"
    assert page.input_value("#mode") == "ideal"
    page.click("#start-button")
    s = live.wait_for(lambda s: s["status"] == "running", timeout_s=30)
    assert (s["scenario"], s["mode"]) == ("free-floating", "ideal")
    page.wait_for_function("document.body.dataset.status === 'running'", timeout=10_000)
    live.client.post("/api/stop")


def test_gizmo_mouse_drag_moves_the_satellite(live, page):
    live.client.post("/api/stop")
    # (120 s: the scenario's 24 s could run out before a second drag on a loaded machine)
    s = live.client.post("/api/scenarios/free-floating/start",
                         json={"loop": {"duration_s": 120.0}}).json()
    assert s["status"] == "running"
    live.wait_for_scene()
    _wait_rendered(page, live)
    s0 = live.wait_for(lambda s: s["t_s"] > 2.0)  # arm settled, the browser caught up
    m = np.array(s0["robots"][0]["mockup_position_W_m"]) + GIZMO_OFFSET_W  # the gizmo
    scale = 0.35  # the gizmo's scale (scene.py): its arrows are that long in metres
    # From the initial camera the +y arrow points nearly into the view, 23 px long, over
    # the rotation rings: the camera goes close, looking at the mockup from +x.
    eye = m + [0.75, -0.25, 0.45]
    with _camera_at(live, page, eye, m):
        center, tip = project(_viewer_box(page), eye, m,
                              [m, m + [0.0, ARROW_HEAD * scale, 0.0]], CLIENT_FOV_RAD)
        img = screenshot(page)
        r, g, b = img[int(round(tip[1])), int(round(tip[0]))]
        assert g > 150 and g > r + 40, f"no green gizmo arrow at {tip}: {(r, g, b)}"
        direction = (tip - center) / np.linalg.norm(tip - center)
        px_per_m = np.linalg.norm(tip - center) / (ARROW_HEAD * scale)
        y0 = s0["satellites"][0]["position_m"][1]
        # In about one full-suite run in three on this shared VM the first press does not
        # grab the arrow (the drag never reaches the server; alone the test always
        # passes): a second drag, from the top, is what an operator would do too.
        for attempt in range(2):
            page.mouse.move(*tip)
            page.mouse.down()
            for k in range(1, 4):  # 15 cm along +y in the lab
                page.mouse.move(*(tip + direction * px_per_m * 0.05 * k))
            try:
                s1 = live.wait_for(lambda s: s["satellites"][0]["velocity_mps"][1] > 0.005,
                                   timeout_s=8)
                break
            except TimeoutError:
                page.mouse.up()
                if attempt == 1:
                    raise
        page.mouse.up()
    assert s1["satellites"][0]["position_m"][1] > y0
    v = s1["satellites"][0]["velocity_mps"]
    assert abs(v[0]) < abs(v[1]) and abs(v[2]) < abs(v[1])
    live.client.post("/api/stop")


@contextlib.contextmanager
def _camera_at(live, page, eye_W, look_at_W):
    """Every connected viewer's camera at eye_W looking at look_at_W (z up), then back
    to the initial camera."""
    camera = live.app.state.viser.initial_camera
    clients = list(live.app.state.viser.get_clients().values())
    try:
        for c in clients:
            c.camera.position, c.camera.look_at = tuple(eye_W), tuple(look_at_W)
        page.wait_for_timeout(1500)
        yield
    finally:
        for c in clients:
            c.camera.position, c.camera.look_at = camera.position, camera.look_at


def _drag_arrow(live, page, origin_W, axis_W, check, attempts: int = 2) -> dict:
    """Drag the gizmo arrow that starts at origin_W along axis_W by ~20 px; the state
    once check(state) holds (a second drag where the first press missed the arrow)."""
    scale = 0.35  # the gizmo's scale (scene.py): its arrows are that long in metres
    center, tip = project_initial(live, page, [origin_W,
                                               origin_W + ARROW_HEAD * scale * np.asarray(axis_W)])
    direction = (tip - center) / np.linalg.norm(tip - center)
    for attempt in range(attempts):
        page.mouse.move(*tip)
        page.mouse.down()
        for k in range(1, 4):
            page.mouse.move(*(tip + direction * 7 * k))
        try:
            state = live.wait_for(check, timeout_s=8)
            break
        except TimeoutError:
            page.mouse.up()
            if attempt == attempts - 1:
                raise
    page.mouse.up()
    return state


def test_hand_driven_free_floating_from_the_page_stays_at_rest(live, page):
    """The web app's free-floating has nothing scripted: started from the page (its
    scenario and mode selectors), the satellite stays where it is until someone pushes."""
    live.client.post("/api/stop")
    page.select_option("#scenario", "free-floating")
    page.select_option("#mode", "hil")
    page.click("#start-button")
    s = live.wait_for(lambda s: s["status"] == "running" and s["scenario"] == "free-floating",
                      timeout_s=30)
    s = live.wait_for(lambda s: s["t_s"] > 4.0, timeout_s=30)
    assert np.linalg.norm(s["satellites"][0]["velocity_mps"]) < 1e-6
    assert np.linalg.norm(s["satellites"][0]["omega_radps"]) < 1e-6
    assert np.linalg.norm(s["satellites"][0]["position_m"]) < 1e-6
    page.wait_for_function("document.getElementById('settings').textContent"
                           ".includes('duration 120 s')", timeout=10_000)


def test_a_click_grabs_the_mockup_off_centre_and_a_drag_spins_it(live, page):
    """Click the mockup's front face left of and below its centre: the hand holds it
    there (the gizmo moves to that point). Dragging the gizmo's +x arrow pulls that point
    along +x: the satellite moves along +x and, through the sensed torque r × F with
    r = (-0.02, -0.1, -0.02) m, turns mostly about +z (r_y F_x < 0: τ_z = 0.1 F)."""
    s = live.state()
    if s["status"] != "running" or s["scenario"] != "free-floating":
        s = live.client.post("/api/scenarios/free-floating/start", json={}).json()
    _wait_rendered(page, live)
    s0 = live.wait_for(lambda s: s["t_s"] > 2.0)
    m = np.array(s0["robots"][0]["mockup_position_W_m"])
    r_B = np.array([-0.02, -0.1, -0.02])  # on the -y face (body = lab axes at rest),
    # well inside it (the mockup is ~85 px across in the test's 1000 px wide page)
    (click,) = project_initial(live, page, [m + r_B])
    sat_view = live.app.state.scene._sats[0]
    cam = live.app.state.viser.initial_camera  # the layout's camera, whatever the
    with _camera_at(live, page, cam.position, cam.look_at):  # test before left
        _click_until_grabbed(page, click, sat_view)
    grab = sat_view.grab_B.copy()
    assert grab[1] == pytest.approx(-0.1, abs=1e-3), grab  # on the face that was clicked
    np.testing.assert_allclose(grab[[0, 2]], r_B[[0, 2]], atol=0.02)
    page.wait_for_timeout(500)  # the gizmo has moved to the grab point
    s1 = _drag_arrow(live, page, m + grab + GIZMO_OFFSET_W, [1.0, 0.0, 0.0],
                     lambda s: s["satellites"][0]["omega_radps"][2] > 0.005)
    v, w = s1["satellites"][0]["velocity_mps"], s1["satellites"][0]["omega_radps"]
    assert v[0] > 0.0 and w[2] > abs(w[0]) and w[2] > abs(w[1]), (v, w)
    live.client.post("/api/stop")


def _click_until_grabbed(page, click, sat_view) -> None:
    for _ in range(3):
        page.mouse.click(*click)
        for _ in range(20):
            if sat_view.grab_B.any():
                break
            page.wait_for_timeout(100)
        if sat_view.grab_B.any():
            break


def test_the_page_and_the_panel_follow_a_rest_start(live, page):
    """A run started over REST shows on the page (scenario and mode selectors, the
    settings form and line) and in the 3D view's panel (its status names the scenario)."""
    live.client.post("/api/stop")
    s = live.client.post("/api/scenarios/collision/start",
                         json={"mode": "ideal", "loop": {"duration_s": 9.0},
                               "satellites": {"0": {"velocity_mps": [0.05, 0.0, 0.0]}}}).json()
    assert s["status"] == "running"
    page.wait_for_function("document.getElementById('mode').value === 'ideal'",
                           timeout=10_000)
    assert page.locator("#scenario").input_value() == "collision"
    assert page.input_value("#set-vx") == "0.05" and page.input_value("#set-duration") == "9"
    assert "duration 9 s" in page.text_content("#settings")
    panel = page.frames[1]  # the viewer's panel
    assert "/viewer/" in panel.url
    deadline = time.monotonic() + 15
    while "collision** (ideal)" not in live.app.state.scene._last_status:
        assert time.monotonic() < deadline, live.app.state.scene._last_status
        page.wait_for_timeout(200)
    panel.wait_for_function("document.body.innerText.includes('collision (ideal)')",
                            timeout=10_000)
    live.client.post("/api/stop")


def test_the_page_s_download_links_return_the_run_s_files(live, page):
    for link, kind in (("#download-csv", "text/csv"), ("#download-metrics", "application/json"),
                       ("#download-run", "application/zip"), ("#download-replay", "text/html"),
                       ("#download-bag", "application/zip")):
        href = page.locator(link).get_attribute("href")
        r = page.request.get(live.url + href)
        assert r.status == 200 and r.headers["content-type"].startswith(kind), (link, r.status)
        assert len(r.body()) > 100


def _cpu_times() -> tuple[int, int]:
    """(all, stolen) CPU time of this machine in jiffies (/proc/stat): what the VM's host
    took away from it shows as "steal"."""
    fields = [int(x) for x in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    return sum(fields[:8]), fields[7]


def test_loop_keeps_500_hz_with_the_browser_connected(live, page):
    """Two 10 s windows with Chromium rendering the scene: the loop keeps its 500 Hz, and
    in at least one window misses under 1 % of its deadlines, plus twice the share of CPU
    time that this VM's host took away meanwhile (steal in /proc/stat): no process here
    can prevent that, and on this project's shared machines it comes in bursts."""
    live.client.post("/api/stop")
    s = live.client.post("/api/scenarios/free-floating/start",
                         json={"loop": {"duration_s": 40.0}}).json()
    assert s["status"] == "running"
    states, cpu = [live.state()], [_cpu_times()]
    for _ in range(2):
        time.sleep(10.0)
        states.append(live.state())
        cpu.append(_cpu_times())
    live.client.post("/api/stop")
    assert states[-1]["status"] == "running"
    windows = []
    for k in range(2):
        s0, s1 = states[k], states[k + 1]
        cycles = s1["loop"]["cycles"] - s0["loop"]["cycles"]
        misses = s1["loop"]["deadline_misses"] - s0["loop"]["deadline_misses"]
        assert cycles >= 0.97 * 10.0 * 500, cycles
        assert s1["t_s"] - s0["t_s"] == pytest.approx(cycles / 500.0, abs=0.05)
        steal = (cpu[k + 1][1] - cpu[k][1]) / max(1, cpu[k + 1][0] - cpu[k][0])
        windows.append((misses / cycles, 0.01 + 2.0 * steal, misses, cycles, steal))
    assert any(ratio < allowed for ratio, allowed, *_ in windows), (windows, states[-1]["loop"])
    print("\n2 x 10 s with the browser: " + "; ".join(
        f"{m} of {c} deadlines missed, host steal {100 * st:.1f} %" for _, _, m, c, st in windows)
        + f"; cycle p50 {states[-1]['loop']['cycle_time_us']['p50']:.0f} us, "
        f"p99 {states[-1]['loop']['cycle_time_us']['p99']:.0f} us, "
        f"scene update p50 {np.median(live.app.state.scene.update_cost_s) * 1e3:.2f} ms")


def test_the_replay_file_plays_offline_with_the_server_stopped(page, tmp_path):
    """A run's replay.html, saved and opened from disk after its server has stopped: the
    viewer loads the embedded recording and plays it (its frames change over time)."""
    with LiveServer(default_scenario="collision") as other:
        assert other.client.get("/api/replay.html").status_code == 404  # nothing recorded
        other.wait_for_scene()
        s = other.client.post("/api/scenarios/collision/start",
                              json={"mode": "ideal", "loop": {"duration_s": 3.0}}).json()
        assert s["status"] == "running"
        other.wait_for(lambda s: s["status"] == "finished", timeout_s=60)
        recorder = other.app.state.scene.replay
        for _ in range(100):  # the scene thread ends the recording with the run's last frame
            if not recorder.recording:
                break
            time.sleep(0.1)
        assert recorder.last is not None and recorder.last[0] == s["generation"]
        r = other.client.get("/api/replay.html")
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
        assert "<title>orbit-emulator replay: collision (ideal)</title>" in r.text
    path = tmp_path / "replay.html"
    path.write_bytes(r.content)
    context = page.context.browser.new_context(viewport=VIEWPORT)
    viewer = context.new_page()
    logs: list[str] = []
    viewer.on("console", lambda m: logs.append(m.text))
    try:
        viewer.goto(path.as_uri())
        deadline = time.monotonic() + 60
        while not any("File loaded" in t for t in logs) and time.monotonic() < deadline:
            viewer.wait_for_timeout(250)
        assert any("File loaded" in t for t in logs), logs[-10:]
        viewer.wait_for_timeout(1500)
        frames = []
        for _ in range(4):
            frames.append(np.asarray(PIL.open(io.BytesIO(viewer.screenshot())).convert("L"),
                                     dtype=int))
            viewer.wait_for_timeout(700)
        assert frames[0].std() > 8  # a scene, not a blank page
        changes = [int((np.abs(a - b) > 30).sum()) for a, b in zip(frames[:-1], frames[1:],
                                                                  strict=True)]
        assert max(changes) > 200, changes  # it plays: the satellites move, the bar runs
    finally:
        context.close()


ATTACK_PAGE = """<!doctype html><title>another local service</title>
<iframe id="framed" src="http://APP/" style="opacity: 0.05"></iframe><script>
window.results = {};
function socket(url) {
  return new Promise((done) => {
    const ws = new WebSocket(url, ["SUBPROTOCOL"]);
    ws.onopen = () => { done("open"); ws.close(); };
    ws.onerror = () => done("error");
    ws.onclose = (e) => done("closed " + e.code);
    setTimeout(() => done("timeout"), 5000);
  });
}
(async () => {
  try {  // a body-less POST: no CORS preflight; the token cookie goes along (same site)
    await fetch("http://APP/api/scenarios/collision/start",
                {method: "POST", mode: "no-cors", credentials: "include"});
    results.post = "sent";
  } catch (e) { results.post = "error " + e; }
  try {  // reads the page cannot see but the app would build: a CSV, a zip
    for (const path of ["/api/telemetry", "/api/run.zip"]) {
      await fetch("http://APP" + path, {mode: "no-cors", credentials: "include"});
    }
    results.reads = "sent";
  } catch (e) { results.reads = "error " + e; }
  results.viewer = await socket("ws://APP/viewer");
  results.viser = await socket("ws://VISER/");
  results.done = true;
})();
</script>"""


def _serve_attack_page(app: str, viser: str):
    """A page on another port of 127.0.0.1 that tries to start a run and open the viewer's
    websockets on the app: (its URL, the server to shut down)."""
    import http.server
    import threading

    body = (ATTACK_PAGE.replace("APP", app).replace("VISER", viser)
            .replace("SUBPROTOCOL", _subprotocol()).encode())

    class Page(http.server.BaseHTTPRequestHandler):
        def do_GET(self):  # noqa: N802 - http.server's name
            self.send_response(200)
            self.send_header("Content-Type", "text/html")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args):
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Page)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    return f"http://127.0.0.1:{server.server_address[1]}/", server


def _subprotocol() -> str:
    """The websocket subprotocol viser's own page asks for (its version)."""
    import viser

    return f"viser-v{viser.__version__}"


OWN_PAGE_CHECK = """async (subprotocol) => {
  const r = await fetch("/api/stop", {method: "POST"});
  const ws = await new Promise((done) => {
    const s = new WebSocket("ws://" + location.host + "/viewer", [subprotocol]);
    s.onopen = () => { done("open"); s.close(); };
    s.onerror = () => done("error");
    setTimeout(() => done("timeout"), 10000);
  });
  return [r.status, ws];
}"""


def _attack_and_own_page(live, browser, token: str | None) -> None:
    """In one browser context (the operator's): the app's page (opened from the token
    link where there is one), then a page on another port of 127.0.0.1 that posts a start,
    opens the viewer websocket (the app's relay and viser's own port) and frames the app's
    page: nothing starts, no socket opens, the framed page is not shown; the app's own
    page still stops a run and opens its viewer (in its own frame)."""
    context = browser.new_context()
    try:
        own = context.new_page()
        own.goto(live.url + ("/" if token is None else f"/?token={token}"))
        if token is not None:  # the link set the SameSite=Strict cookie, sent to any port
            assert any(c["name"] == "orbit_emulator_token" for c in context.cookies())
        live.client.post("/api/stop")
        gen = live.state()["generation"]
        url, server = _serve_attack_page(f"127.0.0.1:{live.port}",
                                         f"127.0.0.1:{live.viser_port}")
        try:
            evil = context.new_page()
            answers = []  # what the app answered the other page's requests
            evil.on("response", lambda r: answers.append((r.url, r.status)))
            evil.goto(url)
            evil.wait_for_function("window.results.done === true", timeout=30_000)
            results = evil.evaluate("window.results")
            for _ in range(100):  # the response events come in as playwright is called
                if sum(f":{live.port}/api/" in u for u, _ in answers) >= 3:
                    break
                evil.wait_for_timeout(100)
            # the app's page framed (to turn the operator's click into Start): not shown
            framed = evil.frame_locator("#framed").locator("#start-button")
            evil.wait_for_timeout(1500)
            assert framed.count() == 0
        finally:
            server.shutdown()
        time.sleep(1.0)  # a start that got through would have moved on by now
        state = live.state()
        assert state["generation"] == gen and state["status"] != "running", state["status"]
        assert results["post"] == results["reads"] == "sent"  # (sent; refused by the app)
        api = [(u, st) for u, st in answers if f":{live.port}/api/" in u]
        assert len(api) == 3 and all(st == 403 for _, st in api), answers
        assert results["viewer"] != "open" and results["viser"] != "open", results
        status, ws = own.evaluate(OWN_PAGE_CHECK, _subprotocol())
        assert (status, ws) == (200, "open")
    finally:
        context.close()


def test_a_page_on_another_port_can_neither_start_a_run_nor_open_the_viewer(live, page):
    """Origin is scheme, host and port: a page of another local web service (here
    http://127.0.0.1:<another port>) is refused, in Chromium, without a token."""
    _attack_and_own_page(live, page.context.browser, token=None)


def test_with_a_token_the_cookie_from_another_port_does_not_help(page):
    """With a token, the operator opened the printed link: the cookie (SameSite=Strict,
    but cookies know no ports) goes along with the other port's requests; the origin
    check refuses them all the same."""
    token = "token-for-the-origin-test-0123456789"
    with LiveServer(token=token) as server:
        _attack_and_own_page(server, page.context.browser, token=token)


def test_a_press_held_5_s_pushes_one_way_and_a_twist_on_a_ring_spins(live, page):
    """free-floating (hil), the camera close to the mockup, the grab at the centre.
    A twist: the gizmo's blue ring (about z), taken near its y end (its x end meets the
    green ring), dragged 40 degrees round and held 1 s: the
    satellite spins up about z and spins on after the let-go, never back. A press: the
    +x arrow dragged about 6 cm and held 5 s: the satellite's velocity along x grows, then
    stays; it never reverses, never drops back (the hand only presses and lets go when
    the satellite runs ahead), and after the let-go it stays > 0. The help says in
    numbers what a press does."""
    live.client.post("/api/stop")
    s = live.client.post("/api/scenarios/free-floating/start",
                         json={"mode": "hil", "loop": {"duration_s": 120.0}}).json()
    assert s["status"] == "running", s
    live.wait_for_scene()
    _wait_rendered(page, live)
    page.frames[1].locator("button", has_text="Grab at the centre").dispatch_event("click")
    sat_view = live.app.state.scene._sats[0]
    s0 = live.wait_for(lambda s: s["t_s"] > 2.0)
    assert not sat_view.grab_B.any()
    m = np.array(s0["robots"][0]["mockup_position_W_m"]) + GIZMO_OFFSET_W  # the gizmo
    eye = m + [0.5, -0.7, 0.45]
    size = page.viewport_size
    page.set_viewport_size({"width": 1400, "height": 800})  # the +x arrow clear of the panel
    try:
        with _camera_at(live, page, eye, m):
            _twist_about_z(live, page, eye, m)
            _press_along_x_and_hold(live, page, eye, m)
    finally:
        page.set_viewport_size(size)
    cfg = live.app.state.service.config_for("free-floating")
    dv = 100 * cfg.orbit.force_scale * min(0.1 * cfg.hand.stiffness_Npm, cfg.hand.max_force_N)
    assert dv == pytest.approx(5.0)  # 10 N over the 4 N deadband: passed whole, 1 kg
    assert f"a 10 cm press held 1 s gives satellite 1 up to {dv:.1f} cm/s" in (
        page.text_content("#hand-strength"))
    help_text = live.app.state.scene.gui_help.content
    assert "Held 10 cm\nin for 1 s, satellite 1 gains up to **5.0 cm/s**" in help_text
    live.client.post("/api/stop")


def _twist_about_z(live, page, eye, m) -> None:
    scale = 0.35  # the gizmo's scale (scene.py); its rings' radius is 0.65 of it (drei)
    angles = np.radians([70.0, 90.0, 110.0])  # 40 degrees round the ring, in two moves
    # (few moves: each takes ~1-2 s in software WebGL while a gizmo is dragged)
    ring = project(_viewer_box(page), eye, m,
                   [m + 0.65 * scale * np.array([np.cos(a), np.sin(a), 0]) for a in angles],
                   CAMERA_FOV_RAD)
    ring[0] = _nearest_pixel(screenshot(page), ring[0], lambda r, g, b: b > 180 and
                             b > r + 60 and b > g + 40, "the blue ring")
    page.mouse.move(*ring[0])
    page.mouse.down()
    for point in ring[1:]:
        page.mouse.move(*point)
    live.wait_for(lambda s: s["satellites"][0]["omega_radps"][2] > 0.01, timeout_s=8)
    page.wait_for_timeout(1000)
    page.mouse.up()
    w1 = np.array(live.state()["satellites"][0]["omega_radps"])
    page.wait_for_timeout(1000)
    s2 = live.state()
    w2 = np.array(s2["satellites"][0]["omega_radps"])
    assert s2["status"] == "running", s2["reason"]
    assert w2[2] >= 0.9 * w1[2] > 0.009, (w1, w2)  # let go: it spins on, one way
    assert np.hypot(w2[0], w2[1]) < 0.3 * w2[2], w2


def _nearest_pixel(img, at, wanted, what: str, radius_px: int = 10) -> np.ndarray:
    """The pixel nearest ``at`` (x, y) within radius_px whose colour is ``wanted``: a
    thin gizmo line drawn a pixel or two from where its projection puts it."""
    x0, y0 = int(round(at[0])), int(round(at[1]))
    best = None
    for dy in range(-radius_px, radius_px + 1):
        for dx in range(-radius_px, radius_px + 1):
            r, g, b = (int(c) for c in img[y0 + dy, x0 + dx][:3])
            if wanted(r, g, b) and (best is None or dx * dx + dy * dy < best[0]):
                best = (dx * dx + dy * dy, (x0 + dx, y0 + dy))
    assert best is not None, f"no {what} within {radius_px} px of {at}: {img[y0, x0]}"
    return np.array(best[1], float)


def _press_along_x_and_hold(live, page, eye, m) -> None:
    scale = 0.35
    s = live.state()
    m = np.array(s["robots"][0]["mockup_position_W_m"]) + GIZMO_OFFSET_W  # the gizmo
    center, tip = project(_viewer_box(page), eye, m, [m, m + [ARROW_HEAD * scale, 0.0, 0.0]],
                          CAMERA_FOV_RAD)
    direction = (tip - center) / np.linalg.norm(tip - center)
    tip = _nearest_pixel(screenshot(page), tip, lambda r, g, b: r > 180 and r > g + 60
                         and r > b + 60, "the red arrow")
    gizmo = live.app.state.scene._sats[0].gizmo
    x0 = float(gizmo.position[0])
    px_per_m = np.linalg.norm(tip - center) / (ARROW_HEAD * scale)
    samples: list[float] = []
    sampling = threading.Event()

    def sample() -> None:  # the satellite's v_x from before the press to after the let-go
        with httpx.Client(base_url=live.url, timeout=10.0) as client:
            while not sampling.is_set():
                s = client.get("/api/state").json()
                samples.append(s["satellites"][0]["velocity_mps"][0])
                time.sleep(0.05)

    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    try:
        page.mouse.move(*tip)
        page.mouse.down()
        for k in range(1, 4):  # the hand 7 cm in, in three moves (each slow, see above)
            page.mouse.move(*(tip + direction * px_per_m * 0.07 * k / 3))
        for _ in range(50):
            if float(gizmo.position[0]) - x0 > 0.05:
                break
            page.wait_for_timeout(100)
        assert float(gizmo.position[0]) - x0 > 0.05, "the +x arrow did not move"
        page.wait_for_timeout(5000)  # held still for 5 s
        page.mouse.up()
        page.wait_for_timeout(1500)
    finally:
        sampling.set()
        sampler.join(10.0)
    s = live.state()
    assert s["status"] == "running", s["reason"]
    vx = np.array(samples)
    onset = int(np.argmax(vx > 1e-3))
    assert vx[onset] > 1e-3, vx
    print(f"\npress held 5 s: v_x from {vx[onset]:.4f} to {vx.max():.4f} m/s, "
          f"after the let-go {vx[-1]:.4f} m/s")
    assert np.all(vx[onset:] > 0.0), vx  # never reverses
    assert np.all(np.diff(vx[onset:]) > -2e-4), vx  # never pulled back
    assert vx[-1] > 0.9 * vx.max() and vx[-1] > 0.005, vx  # and stays after the let-go
