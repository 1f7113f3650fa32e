"""The page and the 3D view's panel as a user meets them, in a real browser (headless
Debian Chromium at 1280 x 720): /docs with no internet, one set of controls, a choice that
reads "selected, not started", a header that never moves the view, a camera that frames
the mockups, a grab that starts at the centre in each run, signed and uncut plot labels,
a plot window in scenario time, and downloads named by run and shown while they build.

One server and one browser for the module.
"""

from __future__ import annotations

import re
import time
from collections import deque
from urllib.parse import urlsplit

import numpy as np
import pytest

from app.backend.scene import GIZMO_OFFSET_W, PLOT_WINDOW_S, trim_window
from tests.browser import HAVE_CHROMIUM, NEEDS_CHROMIUM, chromium, project_initial
from tests.live_server import LiveServer

pytest.importorskip("playwright.sync_api")

VIEWPORT = {"width": 1280, "height": 720}
GIZMO_ARROW_M = 0.7 * 0.35  # the gizmo's arrows: 0.7 of its scale (scene.py)
R_AXIS_M = 0.25  # frame R's axes (scene.py)

pytestmark = pytest.mark.skipif(not HAVE_CHROMIUM, reason=NEEDS_CHROMIUM)

# Every text a 2D canvas draws (the plots' axis labels), where, and how wide, in each frame.
RECORD_TEXT = """(() => {
  const texts = window.__texts = [];
  const fill = CanvasRenderingContext2D.prototype.fillText;
  CanvasRenderingContext2D.prototype.fillText = function (text, x, y, ...rest) {
    const t = this.getTransform();
    texts.push({text: String(text), x: t.a * x + t.e, y: t.d * y + t.f, scale: t.a,
                width: this.measureText(String(text)).width * t.a, align: this.textAlign,
                baseline: this.textBaseline, font: this.font,
                canvasWidth: this.canvas.width, canvasHeight: this.canvas.height});
    if (texts.length > 20000) texts.splice(0, 10000);
    return fill.call(this, text, x, y, ...rest);
  };
})();"""


def _outside(url: str) -> bool:
    parts = urlsplit(url)
    return parts.scheme in ("http", "https", "ws", "wss") and parts.hostname != "127.0.0.1"


@pytest.fixture(scope="module")
def live():
    with LiveServer(default_scenario="collision") as server:
        yield server


@pytest.fixture(scope="module")
def browser():
    with chromium() as browser:
        yield browser


@pytest.fixture(scope="module")
def offline(browser):
    """A browser context in which every request to a host other than 127.0.0.1 fails:
    (the context, the list of the URLs it blocked, a set of paths of the app's to fail
    too: the server as if unreachable)."""
    context = browser.new_context(viewport=VIEWPORT, accept_downloads=True)
    blocked: list[str] = []
    refused: set[str] = set()

    def route(r):
        if _outside(r.request.url):
            blocked.append(r.request.url)
            r.abort()
        elif urlsplit(r.request.url).path in refused:
            r.abort()
        else:
            r.continue_()

    context.route("**/*", route)
    context.add_init_script(RECORD_TEXT)
    yield context, blocked, refused
    context.close()


@pytest.fixture(scope="module")
def page(live, offline):
    context = offline[0]
    page = context.new_page()
    pending = page.pending = {}  # the requests under way (for a failure's message)
    page.on("request", lambda r: pending.__setitem__(id(r), (time.monotonic(), r.method, r.url)))
    page.on("requestfinished", lambda r: pending.pop(id(r), None))
    page.on("requestfailed", lambda r: pending.pop(id(r), None))
    page.goto(live.url + "/")
    page.wait_for_function("document.getElementById('scenario').options.length > 0",
                           timeout=30_000)
    yield page


def _box_corners(centre_W, size_m) -> np.ndarray:
    half = np.asarray(size_m, float) / 2
    return np.array([np.asarray(centre_W) + half * [sx, sy, sz]
                     for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])


def _segment_distance_px(a0, a1, b0, b1, samples: int = 50) -> float:
    """Least distance between two screen segments (sampled finely)."""
    s = np.linspace(0.0, 1.0, samples)[:, None]
    pa, pb = a0 + s * (a1 - a0), b0 + s * (b1 - b0)
    return float(np.min(np.linalg.norm(pa[:, None, :] - pb[None, :, :], axis=2)))


def _set(page, field: str, value: str) -> None:
    """Type a value into the page's settings form (it opens over the view)."""
    if not page.eval_on_selector("#settings-pop", "e => e.open"):
        page.click("#settings-pop summary")
    page.fill(field, value)
    page.click("#settings-pop summary")  # closed again


def _status(page) -> str:
    return page.text_content("#status")


# --- /docs and the page without internet ----------------------------------------------


def test_docs_render_swagger_ui_with_every_outside_request_blocked(live, offline):
    context, blocked, _ = offline
    docs = context.new_page()
    try:
        docs.goto(live.url + "/docs")
        docs.wait_for_selector(".swagger-ui .opblock-summary-path", timeout=30_000)
        paths = docs.eval_on_selector_all(".opblock-summary-path",
                                          "els => els.map(e => e.textContent)")
        assert "/api/state" in "".join(paths) and len(paths) >= 10, paths
        assert docs.locator(".swagger-ui .info .title").inner_text().startswith(
            "orbit-emulator")
    finally:
        docs.close()
    assert blocked == [], blocked  # it asked for nothing outside (no CDN, no validator)


def test_the_page_and_viewer_load_nothing_from_outside(live, page, offline):
    blocked = offline[1]
    page.wait_for_function("document.getElementById('viewer').getAttribute('src')",
                           timeout=30_000)
    live.wait_for_scene()
    page.frame_locator("#viewer").locator("canvas").first.wait_for(timeout=30_000)
    page.wait_for_timeout(1000)
    assert blocked == [], blocked


# --- one set of controls; a choice reads "selected, not started" -----------------------


def test_the_panel_has_no_run_controls_of_its_own(live, page):
    """The run's controls are the page's alone: the panel has no scenario, start, stop
    or reset of its own (only the 3D view's own: "Grab at the centre")."""
    panel = page.frames[1]
    panel.wait_for_selector("button:has-text('Grab at the centre')", timeout=30_000)
    buttons = [t.strip() for t in panel.eval_on_selector_all(
        "button", "els => els.map(e => e.innerText)") if t.strip()]
    assert not {"Start", "Stop", "Reset"} & set(buttons), buttons
    values = panel.eval_on_selector_all("input", "els => els.map(e => e.value)")
    assert not {"collision", "hil", "ideal"} & set(values), values


def test_a_chosen_scenario_reads_selected_not_started(live, page):
    assert live.state()["scenario"] == "collision"
    page.wait_for_function("document.getElementById('status').textContent"
                           ".startsWith('collision (hil)')", timeout=10_000)
    page.select_option("#scenario", "free-floating")
    page.wait_for_timeout(700)  # a poll at least
    text = _status(page)
    assert text.startswith("free-floating (hil) selected, not started"), text
    assert "shown: collision (hil)" in text  # the old one is named as what is shown
    # the settings form offers the chosen scenario's values
    listed = {s["name"]: s for s in live.client.get("/api/scenarios").json()}
    g = listed["free-floating"]["settings"]
    assert page.get_attribute("#set-duration", "placeholder") == f"{g['duration_s']:g}"
    assert live.state()["scenario"] == "collision"  # nothing started
    page.select_option("#scenario", "collision")
    page.wait_for_function("document.getElementById('status').textContent"
                           ".startsWith('collision (hil) not started')", timeout=10_000)


def test_every_figure_on_the_status_and_settings_lines_has_a_tooltip(page):
    page.wait_for_function("document.querySelectorAll('#settings span[title]').length >= 6",
                           timeout=10_000)
    for line in ("#status", "#settings"):
        figures = page.eval_on_selector_all(
            f"{line} span[title]", "els => els.map(e => [e.textContent, e.title])")
        texts = " ".join(t for t, _ in figures)
        for figure in ({"#status": ("p50", "p99", "misses", "t=", "(hil)"),
                        "#settings": ("VFDM kp", "altitude", "force scale")}[line]):
            assert figure in texts, (figure, figures)
        assert all(len(title) > 10 for _, title in figures), figures


# --- the header never moves the view --------------------------------------------------


def test_a_long_status_message_does_not_move_the_view(live, page):
    before = page.locator("#viewer").bounding_box()
    # a start that fails with a long reason (the arm cannot reach its start pose in time)
    r = live.client.post("/api/scenarios/free-floating/start",
                         json={"loop": {"approach_timeout_s": 0.01}})
    assert r.status_code == 422
    page.wait_for_function("document.getElementById('status').textContent"
                           ".includes('not reached')", timeout=10_000)
    # and a refused start from the page itself: its message on the same line
    _set(page, "#set-duration", "-5")
    page.click("#start-button")
    page.wait_for_function("document.getElementById('message').textContent.length > 0",
                           timeout=30_000)
    _set(page, "#set-duration", "")
    line = page.locator("#status-line")
    assert line.evaluate("e => e.scrollWidth > e.clientWidth")  # long: it overflows...
    assert page.locator("#status").get_attribute("title")  # ... its whole text in a tooltip
    assert page.locator("#viewer").bounding_box() == before


# --- the default camera frames the mockups, the gizmo clear of frame R -----------------


def test_the_default_camera_frames_each_mockup_at_least_100_px(live, page):
    live.wait_for_scene()
    s = live.state()
    for scenario in ("collision", "free-floating", "docking"):
        if s["scenario"] != scenario:
            live.client.post("/api/reset", json=None)
            s = live.client.post(f"/api/scenarios/{scenario}/start",
                                 json={"mode": "ideal"}).json()
            live.client.post("/api/stop")
            live.wait_for_scene()
            time.sleep(0.2)  # the scene thread set the camera as it rebuilt
        layout = s["layout"]
        box = page.locator("#viewer").bounding_box()
        T_W_R = np.asarray(layout["T_W_R"])
        r_axes = [project_initial(live, page,
                                  [T_W_R[:3, 3], T_W_R[:3, 3] + R_AXIS_M * T_W_R[:3, k]])
                  for k in range(3)]
        for sat, (_, size, _) in zip(s["satellites"], layout["satellites"], strict=True):
            px = project_initial(live, page, _box_corners(sat["position_W_m"], size))
            across = px.max(axis=0) - px.min(axis=0)
            assert across[0] >= 100 and across[1] >= 50, (scenario, across)
            assert px[:, 0].min() > box["x"] and px[:, 0].max() < box["x"] + box["width"] - 330
            assert px[:, 1].min() > box["y"] and px[:, 1].max() < box["y"] + box["height"]
            gizmo = np.asarray(sat["position_W_m"]) + GIZMO_OFFSET_W
            for k in range(3):
                arrow = project_initial(live, page, [gizmo, gizmo + GIZMO_ARROW_M * np.eye(3)[k]])
                gap = min(_segment_distance_px(*arrow, *axis) for axis in r_axes)
                assert gap >= 15, (scenario, "xyz"[k], gap)


# --- a run from the page: settings, grab, plots, downloads -----------------------------


@pytest.fixture(scope="module")
def free_floating(live, page):
    """free-floating in hil started from the page with its settings form (duration 120 s)."""
    live.client.post("/api/stop")
    s = live.state()  # the page has followed the last run started (the camera test's, on a
    # loaded server its state can come late): its selectors will not change under the choice
    page.wait_for_function("run => document.body.dataset.run === run",
                           arg=f"{s['generation']} {s['scenario']} {s['mode']}", timeout=30_000)
    page.select_option("#scenario", "free-floating")
    page.select_option("#mode", "hil")
    _set(page, "#set-duration", "120")
    page.click("#start-button")
    svc = live.app.state.service
    try:
        s = live.wait_for(lambda s: s["status"] == "running" and s["scenario"] == "free-floating",
                          timeout_s=60)
    except TimeoutError:
        print("the page's start did not arrive:", page.text_content("#status"),
              svc.pending_start, page.text_content("#message"))
        now = time.monotonic()
        print("PENDING", sorted((round(now - t), m, u) for t, m, u in page.pending.values()))
        raise
    assert s["settings"]["duration_s"] == 120.0  # the page's one set of controls
    live.wait_for_scene()
    return s


def test_the_mockup_is_where_the_camera_projection_says(live, page, free_floating):
    """The projection the framing test uses is the browser's: hiding the mockup changes
    the pixels inside its projected outline (and the outline is over 100 px across)."""
    s = live.wait_for(lambda s: s["t_s"] > 1.0)
    corners = _box_corners(s["robots"][0]["mockup_position_W_m"], s["layout"]["satellites"][0][1])
    px = project_initial(live, page, corners)
    x0, y0 = (int(v) for v in px.min(axis=0))
    x1, y1 = (int(v) for v in px.max(axis=0))
    assert x1 - x0 >= 100
    def shot() -> np.ndarray:
        return _png(page.screenshot(clip={"x": x0, "y": y0, "width": x1 - x0,
                                          "height": y1 - y0}))

    mockup = live.app.state.scene._sats[0].mockup
    with_it = shot()
    mockup.visible = False
    try:
        changed = 0.0
        for _ in range(20):
            page.wait_for_timeout(250)
            changed = float((np.abs(shot() - with_it).sum(axis=2) > 60).mean())
            if changed > 0.25:
                break
    finally:
        mockup.visible = True
    assert changed > 0.25, changed  # a quarter of the outline's box at least


def _png(data: bytes) -> np.ndarray:
    import io

    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB")).astype(int)


def test_plot_labels_are_signed_and_not_cut(live, page, free_floating):
    """A push along -x (the force, then the velocity and position negative): the plots'
    y labels then include negative values drawn with their minus sign, and every label
    lies inside its canvas."""
    r = live.client.post("/api/push", json={"satellite": 1, "force_N": [-6.0, 0.0, 0.0],
                                            "duration_s": 0.1})
    assert r.status_code == 200, r.text
    panel = page.frames[1]
    panel.evaluate("window.__texts.length = 0")
    deadline = time.monotonic() + 15
    while True:
        page.wait_for_timeout(500)
        texts = panel.evaluate("window.__texts")
        numbers = [t for t in texts if re.fullmatch(r"[-−]?\d+(\.\d+)?(e[-+]?\d+)?",
                                                    t["text"].strip())]
        negative = [t for t in numbers if t["text"].strip()[0] in "-−"]
        if negative or time.monotonic() > deadline:
            break
    assert negative, sorted({t["text"] for t in numbers})
    for t in numbers:
        left = {"right": t["x"] - t["width"], "center": t["x"] - t["width"] / 2,
                "end": t["x"] - t["width"]}.get(t["align"], t["x"])
        size = float(re.search(r"(\d+(\.\d+)?)px", t["font"]).group(1)) * t["scale"]
        top = {"middle": t["y"] - size / 2, "bottom": t["y"] - size,
               "alphabetic": t["y"] - 0.8 * size}.get(t["baseline"], t["y"])
        assert left >= 0 and t["x"] <= t["canvasWidth"] + 0.5, t  # no sign cut on the left
        assert top >= 0, t  # the top label whole


def test_the_plot_window_spans_its_time_in_scenario_seconds(live, free_floating):
    """The plots keep what lies within the window's seconds of scenario time, whatever
    the rate of their samples (3 s here, for speed; the panel's is 60 s)."""
    scene = live.app.state.scene
    scene.plot_window_s = 3.0
    try:
        live.wait_for(lambda s: s["t_s"] > free_floating["t_s"] + 5.0, timeout_s=30)
        time.sleep(0.6)  # the plots' next update (4 Hz)
        t = np.asarray(scene.plots["velocity"].data[0])
        x_range = scene.plots["velocity"].scales["x"]["range"]
    finally:
        scene.plot_window_s = PLOT_WINDOW_S
    dt = np.diff(t)
    assert t[-1] - t[0] >= 3.0 and t[-1] - t[0] - dt[0] < 3.0, (t[0], t[-1])
    assert x_range == [pytest.approx(t[0]), pytest.approx(t[-1])]


@pytest.mark.parametrize("rate_hz", [10.0, 30.0, 7.3])
def test_the_window_is_60_s_of_scenario_time_at_any_sample_rate(rate_hz):
    history: deque = deque()
    for k in range(int(150 * rate_hz)):
        history.append({"t_s": k / rate_hz})
        trim_window(history, PLOT_WINDOW_S)
    span = history[-1]["t_s"] - history[0]["t_s"]
    assert PLOT_WINDOW_S <= span < PLOT_WINDOW_S + 1.0 / rate_hz


def test_a_new_run_grabs_the_mockup_at_its_centre(live, page, free_floating):
    """An off-centre grab (a click on the mockup) does not carry over: after a
    reset (a new run) the hand holds the centre again, and the gizmo sits under it."""
    s0 = live.wait_for(lambda s: s["t_s"] > 1.0)
    m = np.array(s0["robots"][0]["mockup_position_W_m"])
    sat_view = live.app.state.scene._sats[0]
    (click,) = project_initial(live, page, [m + [-0.06, -0.1, -0.02]])
    for _ in range(3):
        page.mouse.click(*click)
        for _ in range(20):
            if sat_view.grab_B.any():
                break
            page.wait_for_timeout(100)
        if sat_view.grab_B.any():
            break
    # off the centre, on the box's surface (after the push above the satellite drifts:
    # the face the click meets may be another one)
    assert np.max(np.abs(sat_view.grab_B) / (np.asarray(
        s0["layout"]["satellites"][0][1]) / 2)) == pytest.approx(1.0, abs=1e-3), sat_view.grab_B
    gen = live.state()["generation"]
    page.click("#reset-button")
    live.wait_for(lambda s: s["generation"] > gen, timeout_s=30)
    live.wait_for_scene()
    sat_view = live.app.state.scene._sats[0]
    assert not sat_view.grab_B.any(), sat_view.grab_B
    assert "the centre of mass" in live.app.state.scene.gui_grab.content
    page.wait_for_timeout(300)  # the scene's next frames
    s = live.state()
    np.testing.assert_allclose(sat_view.gizmo.position,
                               np.array(s["robots"][0]["mockup_position_W_m"]) + GIZMO_OFFSET_W,
                               atol=0.01)


def test_downloads_are_named_by_run_and_show_their_progress(live, page):
    if live.state()["loop"]["cycles"] == 0:  # (after the reset above: a short run)
        live.client.post("/api/scenarios/free-floating/start", json={"mode": "ideal"})
        live.wait_for(lambda s: s["t_s"] > 0.5)
    live.client.post("/api/stop")
    s = live.state()
    page.wait_for_function("!document.getElementById('downloads').classList.contains('none')",
                           timeout=10_000)
    stamp = r"\d{8}T\d{4}Z"
    with page.expect_download(timeout=60_000) as info:
        page.click("#download-run")
        page.wait_for_function("document.getElementById('download-progress').textContent"
                               ".startsWith('building run.zip')", timeout=5_000)
    name = info.value.suggested_filename
    assert re.fullmatch(rf"{s['scenario']}-{s['mode']}-{stamp}-run\.zip", name), name
    assert page.text_content("#download-progress") == ""
    for path, what in (("/api/telemetry", "telemetry.csv"), ("/api/metrics", "metrics.json")):
        header = live.client.get(path).headers["content-disposition"]
        assert re.fullmatch(rf'attachment; filename="{s["scenario"]}-{s["mode"]}-{stamp}-'
                            rf'{re.escape(what)}"', header), header


def test_downloads_are_greyed_out_while_the_server_is_unreachable(live, page, offline):
    page.wait_for_function("!document.getElementById('downloads').classList.contains('none')",
                           timeout=10_000)
    refused = offline[2]
    refused.add("/api/state")
    try:
        page.wait_for_function("document.getElementById('status').textContent"
                               " === 'server unreachable'", timeout=10_000)
        assert "none" in page.get_attribute("#downloads", "class")
        events = page.eval_on_selector("#download-bag", "e => getComputedStyle(e).pointerEvents")
        assert events == "none"
    finally:
        refused.clear()
    page.wait_for_function("!document.getElementById('downloads').classList.contains('none')",
                           timeout=10_000)


def test_the_help_says_when_a_press_is_more_than_the_arm_follows(live, page):
    """The collision's mockups are their satellites (force scale 1, 1 kg): a 10 cm press
    held 1 s would give 1000 cm/s, a hundred times what an arm follows; the help says so
    in the page and the panel (free-floating's 5 cm/s is within it: no such note)."""
    live.client.post("/api/reset", json=None)
    s = live.client.post("/api/scenarios/collision/start",
                         json={"mode": "hil", "loop": {"duration_s": 8.0}}).json()
    assert s["status"] == "running", s
    live.wait_for_scene()
    limit_cm_s = 100 * s["push_max_dv_mps"][0]
    page.wait_for_function("document.querySelector('#hand-strength').textContent"
                           ".includes('more than the arm follows')", timeout=10_000)
    assert f"about {limit_cm_s:.0f} cm/s" in page.text_content("#hand-strength")
    deadline = time.monotonic() + 10
    while "more than the arm follows" not in live.app.state.scene.gui_help.content:
        assert time.monotonic() < deadline, live.app.state.scene.gui_help.content
        time.sleep(0.1)
    live.client.post("/api/stop")
    s = live.client.post("/api/scenarios/free-floating/start", json={"mode": "hil"}).json()
    assert s["status"] == "running", s
    live.wait_for_scene()
    page.wait_for_function("document.querySelector('#hand-strength').textContent"
                           ".includes('5.0 cm/s')", timeout=10_000)
    assert "more than the arm follows" not in page.text_content("#hand-strength")
    live.client.post("/api/stop")


def test_a_slow_runs_list_gets_one_request_at_a_time(live, offline):
    """The runs panel looks at /api/runs every second: while the server has not answered
    (held here for 3.5 s), the page sends no other (a queue of them would hold the
    browser's connections to the server while a Start waits for one); once answered, the
    looks go on."""
    page = offline[0].new_page()
    held = []

    def hold(route):  # neither answered nor refused: under way
        held.append(route)

    page.route("**/api/runs", hold)
    try:
        page.goto(live.url + "/")
        page.wait_for_function("document.getElementById('scenario').options.length > 0",
                               timeout=30_000)
        page.wait_for_timeout(3500)
        assert len(held) == 1, len(held)
        held.pop().continue_()
        page.unroute("**/api/runs", hold)
        page.wait_for_timeout(2500)
        with page.expect_request("**/api/runs", timeout=5000):
            pass  # the next look, after the answer
    finally:
        page.close()
