"""Every web run kept on disk (app/backend/recorder.py, app/runs/store.py), end to end.

A first server (`orbit-emulator serve`, a subprocess) records a short ideal run and the
start of a long one, and is killed with SIGKILL mid-run; a second one (the module's live
server, on the same runs directory) finds both: the first whole, the second interrupted
with its rows up to about a second before the kill. On the second server a short hil
collision is recorded with the ideal run's comparison, the same as `orbit-emulator run`
gives; Reset and a new Start lose nothing; the files are served safely; the CLI lists the
runs. A run's 3D replay is kept in its folder (and found there after the restart); a kept
run's ROS 2 bag is built on demand; two runs' figures are overlaid.
"""

from __future__ import annotations

import base64
import errno
import io
import json
import os
import re
import shutil
import signal
import subprocess
import threading
import time
import zipfile

import httpx
import numpy as np
import pytest

from app.cli import main as cli_main
from app.runs.store import read_telemetry
from app.scenarios import load_scenario
from tests.live_server import LiveServer, free_port
from tests.test_backend_rest import _recording_duration_s
from tests.test_cli import EXE

SHORT_COLLISION = {"satellites": {"0": {"position_m": [-0.16, 0, 0]},
                                  "1": {"position_m": [0.16, 0, 0]}},
                   "loop": {"duration_s": 1.2, "seed": 3},
                   "uncertainty": {"replicates": 4, "forecast_replicates": 4}}
"""The shipped collision started closer: its contact at 0.74 s in a 1.2 s run."""
SHORT_COLLISION_SET = ["satellites.0.position_m=[-0.16,0,0]",
                       "satellites.1.position_m=[0.16,0,0]", "loop.seed=3",
                       "uncertainty.replicates=4", "uncertainty.forecast_replicates=4"]


def _wait(predicate, timeout_s: float, what: str):
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise TimeoutError(what)
        time.sleep(0.1)


@pytest.fixture(scope="module")
def runs_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("runs")


@pytest.fixture(scope="module")
def killed(runs_dir):
    """The first server: a 0.6 s ideal run recorded whole, then a 60 s one killed (the
    server, SIGKILL) about 3 s in; (the first run's id, the second's, its last t_s seen
    before the kill)."""
    port = free_port()
    proc = subprocess.Popen([EXE, "serve", "--port", str(port), "--runs-dir", str(runs_dir)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    client = httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=60.0)
    try:
        def up():
            try:
                return client.get("/api/health").status_code == 200
            except httpx.HTTPError:
                return False
        _wait(up, 120.0, "the first server did not start")
        _wait(lambda: client.get("/api/health").json()["scene_generation"]  # the 3D scene
              == client.get("/api/state").json()["generation"], 60.0,  # is built: it
              "the first server's scene was not built")  # records the short run's replay
        r = client.post("/api/scenarios/collision/start",
                        json={"mode": "ideal", "loop": {"duration_s": 0.6}})
        assert r.status_code == 200, r.text
        whole = _wait(lambda: [x for x in client.get("/api/runs").json()["runs"]
                               if x["status"] == "finished"], 30.0, "no finished run")[0]
        r = client.post("/api/scenarios/collision/start",
                        json={"mode": "ideal", "loop": {"duration_s": 60.0}})
        assert r.status_code == 200, r.text
        state = _wait(lambda: (s := client.get("/api/state").json())["t_s"] >= 3.0 and s,
                      30.0, "the long run did not reach 3 s")
        cut = client.get("/api/runs").json()["recording"]
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
    finally:
        client.close()
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    return whole["id"], cut, state["t_s"]


@pytest.fixture(scope="module")
def live(killed, runs_dir):
    with LiveServer(runs_dir=runs_dir, keep_runs=6) as server:
        yield server


def _runs(live) -> dict:
    r = live.client.get("/api/runs")
    assert r.status_code == 200, r.text
    return {x["id"]: x for x in r.json()["runs"]}


def _ended(live, run_id: str, timeout_s: float = 60.0) -> dict:
    """The run's record once its plots are drawn."""
    return _wait(lambda: (x := _runs(live).get(run_id)) and isinstance(x.get("plots"), list)
                 and x, timeout_s, f"run {run_id} has no plots")


def test_a_killed_server_leaves_its_rows_up_to_a_second_before_the_kill(live, killed,
                                                                        runs_dir):
    whole, cut, t_seen_s = killed
    runs = _runs(live)
    assert runs[cut]["status"] == "interrupted", runs[cut]
    assert "stopped before the run ended" in runs[cut]["reason"]
    columns, rows = read_telemetry(runs_dir / cut / "telemetry.csv")
    assert columns[0] == "t_s"
    assert rows[-1, 0] >= t_seen_s - 1.0, (rows[-1, 0], t_seen_s)
    assert np.all(np.diff(rows[:, 0]) > 0) and rows[0, 0] <= 0.01  # whole, in order
    # the new server gives it the metrics of what it recorded
    run = _wait(lambda: (x := live.client.get(f"/api/runs/{cut}").json())["metrics"] and x,
                60.0, "no metrics for the interrupted run")
    assert run["metrics"]["status"] == "interrupted"
    assert run["metrics"]["duration_s"] == pytest.approx(rows[-1, 0])
    # the run the first server finished is there whole after the restart
    first = _ended(live, whole)
    assert first["status"] == "finished" and first["mode"] == "ideal"
    files = live.client.get(f"/api/runs/{whole}").json()["files"]
    assert {"telemetry.csv", "metrics.json", "config.json", "summary.txt"} <= set(files)
    assert set(first["plots"]) <= set(files) and first["plots"]
    # with its 3D replay, kept by the first server when the run ended
    assert "replay.html" in files and first["replay"] is True
    _check_replay(live, whole, "collision (ideal)", first["duration_s"])


def _check_replay(live, run_id: str, title: str, duration_s: float) -> None:
    """The run's replay.html is the standalone player with the run's recording inside,
    which lasts as long as the run did (scenario time)."""
    r = live.client.get(f"/api/runs/{run_id}/files/replay.html")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    assert f"<title>orbit-emulator replay: {title}</title>" in r.text
    recording = base64.b64decode(re.search(r'var b64 = "([A-Za-z0-9+/=]+)"', r.text)[1])
    assert _recording_duration_s(recording) == pytest.approx(duration_s, abs=0.1)


def test_a_web_run_is_listed_with_its_figures_and_the_cli_s_numbers(live, tmp_path):
    r = live.client.post("/api/scenarios/collision/start", json={**SHORT_COLLISION,
                                                                 "mode": "hil"})
    assert r.status_code == 200, r.text
    run_id = live.client.get("/api/runs").json()["recording"]
    record = _ended(live, run_id, 90.0)
    assert (record["scenario"], record["mode"], record["seed"], record["status"]) == (
        "collision", "hil", 3, "finished")
    h = record["headline"]
    assert h["restitution"] is not None and h["restitution_ideal"] is not None
    assert h["restitution_error"] == pytest.approx(
        (h["restitution"] - h["restitution_ideal"]) / h["restitution_ideal"])
    lo, hi = h["restitution_interval_95"]
    assert lo < h["restitution"] < hi
    assert any(name.endswith(".png") for name in record["plots"])
    png = live.client.get(f"/api/runs/{run_id}/files/{record['plots'][0]}")
    assert png.status_code == 200 and png.content[:8] == b"\x89PNG\r\n\x1a\n"
    web = live.client.get(f"/api/runs/{run_id}").json()["metrics"]
    rest = live.client.get("/api/metrics").json()  # REST of the run that is there
    # nothing asked /forecast for this configuration: the forecast a start does not wait
    # for is computed after the run, into metrics.json, and /api/metrics then has it too
    assert web["collision_forecast"]["restitution_sd"] > 0
    assert rest == web
    # the same scenario, settings and seed headless: the same numbers
    out = tmp_path / "cli"  # (the CLI's own code in this process: no start-up to wait)
    assert cli_main(["run", "collision", "--quiet", "--out", str(out), "--duration", "1.2",
                     *[a for s in SHORT_COLLISION_SET for a in ("--set", s)]]) == 0
    cli = json.loads((out / "metrics.json").read_text())
    for key in ("restitution", "restitution_ideal", "restitution_error", "true_impulse_ratio",
                "restitution_interval_95", "peak_force_N", "rendering_error_m",
                "contact_depth_m"):
        assert web["collision"][key] == pytest.approx(cli["collision"][key], rel=1e-9), key
    web_fc, cli_fc = dict(web["collision_forecast"]), dict(cli["collision_forecast"])
    web_v, cli_v = web_fc.pop("velocity_sd_mps"), cli_fc.pop("velocity_sd_mps")
    assert web_fc == pytest.approx(cli_fc, rel=1e-9)
    assert web_v.keys() == cli_v.keys()
    for sat, sd in cli_v.items():  # (the drift check's velocity spread, per satellite)
        assert web_v[sat] == pytest.approx(sd, rel=1e-9)


def _hil_run(live) -> str:
    """The hil collision of the test above (the newest finished hil run)."""
    return next(x["id"] for x in live.client.get("/api/runs").json()["runs"]
                if x["mode"] == "hil" and x["status"] == "finished")


def test_a_run_s_replay_is_kept_in_its_folder(live):
    run_id = _hil_run(live)
    record = _wait(lambda: (x := _runs(live)[run_id])["replay"] and x, 20.0, "no replay")
    assert "replay.html" in live.client.get(f"/api/runs/{run_id}").json()["files"]
    _check_replay(live, run_id, "collision (hil)", record["duration_s"])


def test_a_kept_run_s_bag_is_built_from_its_telemetry(live, runs_dir, tmp_path):
    """GET /api/runs/{id}/bag: the run's telemetry.csv as a ROS 2 bag (MCAP), at the rate
    asked, read back with the independent mcap reader."""
    pytest.importorskip("mcap_ros2")
    from app.runs.bag import thinning_step
    from tests.runs.test_bag import _mcap

    run_id = _hil_run(live)
    r = live.client.get(f"/api/runs/{run_id}/bag", params={"rate_hz": 50})
    assert r.status_code == 200 and r.headers["content-type"] == "application/zip", r.text
    assert f'filename="{run_id}-bag.zip"' in r.headers["content-disposition"]
    assert r.headers["x-bag-rate-hz"] == "50"  # (the loop's 500 Hz, every 10th row)
    zipfile.ZipFile(io.BytesIO(r.content)).extractall(tmp_path)
    channels, messages = _mcap(tmp_path / "bag")
    assert {"/clock", "/tf", "/robot1/joint_states", "/sat2/ods_input"} <= set(channels)
    rows = read_telemetry(runs_dir / run_id / "telemetry.csv")[1]
    kept = rows[::thinning_step(50.0, rows[1, 0] - rows[0, 0])]
    clock = np.array([m.clock.sec + 1e-9 * m.clock.nanosec for _, m in messages["/clock"]])
    np.testing.assert_allclose(clock, kept[:, 0], atol=1e-9)
    assert len(messages["/robot2/joint_states"]) == len(kept)
    for path, status, detail in [
            (f"/api/runs/{run_id[:-1]}X/bag", 422, "not a run's id"),
            ("/api/runs/20991126T050005123Z-collision/bag", 404, "no run "),
            (f"/api/runs/{run_id}/bag?rate_hz=0", 422, "rate_hz")]:
        r = live.client.get(path)
        assert r.status_code == status and detail in r.text, (path, r.text)


def test_two_runs_figures_are_overlaid(live):
    """GET /api/runs/compare: the settings that differ; /api/runs/compare/plot: one figure
    of both runs on the same axes, a PNG; bad ids and figure names refused by name."""
    from PIL import Image

    a = _hil_run(live)
    b = next(x["id"] for x in live.client.get("/api/runs").json()["runs"]
             if x["mode"] == "ideal" and x["status"] == "finished")
    r = live.client.get("/api/runs/compare", params={"a": a, "b": b})
    assert r.status_code == 200, r.text
    diff = {d["key"]: (d["a"], d["b"]) for d in r.json()["settings"]}
    assert diff["mode"] == ("hil", "ideal")
    assert diff["loop.duration_s"][0] != diff["loop.duration_s"][1]
    assert "scenario" not in diff  # both collisions
    assert {"forces", "velocity"} <= set(r.json()["figures"])
    r = live.client.get("/api/runs/compare/plot",
                        params={"a": a, "b": b, "figure": "contact_closeup"})
    assert r.status_code == 200 and r.headers["content-type"] == "image/png", r.text
    png = Image.open(io.BytesIO(r.content))
    assert png.size[0] == 1100 and png.size[1] > 400  # 11 in at 100 dpi, two panels
    base = {"a": a, "b": b, "figure": "velocity"}
    for params, status, detail in [
            ({**base, "figure": "nope"}, 422, "figure 'nope': not a run's figure (one of "
                                              "forces, contact_closeup"),
            ({**base, "figure": "capture"}, 404, f"neither run {a!r} nor run {b!r} has a "
                                                 f"'capture' figure"),
            ({**base, "a": "../x"}, 422, "run id '../x': not a run's id"),
            ({**base, "b": "20991126T050005123Z-collision"}, 404,
             "no run '20991126T050005123Z-collision'"),
            ({"a": a, "figure": "velocity"}, 422, "b: Field required")]:
        r = live.client.get("/api/runs/compare/plot", params=params)
        assert r.status_code == status and detail in r.json()["detail"], (params, r.text)


def test_reset_and_a_new_start_keep_the_runs_files(live, runs_dir):
    before = _runs(live)
    r = live.client.post("/api/scenarios/collision/start",
                         json={"mode": "ideal", "loop": {"duration_s": 30.0}})
    assert r.status_code == 200, r.text
    reset_one = live.client.get("/api/runs").json()["recording"]
    live.wait_for(lambda s: s["t_s"] >= 1.0)
    t_reset = live.state()["t_s"]
    live.client.post("/api/reset")
    record = _wait(lambda: (x := _runs(live)[reset_one])["status"] != "running" and x, 10.0,
                   "the reset run was not ended")
    assert record["status"] == "stopped" and "reset" in record["reason"]
    rows = read_telemetry(runs_dir / reset_one / "telemetry.csv")[1]
    assert rows[-1, 0] >= t_reset - 0.1  # its rows up to the reset
    r = live.client.post("/api/scenarios/collision/start",
                         json={"mode": "ideal", "loop": {"duration_s": 0.4}})
    assert r.status_code == 200, r.text
    after = _runs(live)
    assert set(before) | {reset_one} < set(after)  # one more: the new run
    for run_id in before:
        assert (runs_dir / run_id / "telemetry.csv").is_file()
    assert (runs_dir / reset_one / "metrics.json").is_file()


def test_retention_removes_the_oldest(live, runs_dir):
    ids = sorted(_runs(live))
    for _ in range(7 - len(ids)):
        live.wait_for(lambda s: s["status"] not in ("running", "starting"))
        r = live.client.post("/api/scenarios/collision/start",
                             json={"mode": "ideal", "loop": {"duration_s": 0.2}})
        assert r.status_code == 200, r.text
    live.wait_for(lambda s: s["status"] not in ("running", "starting"))
    now = sorted(_runs(live))
    assert len(now) == 6  # keep_runs=6 on this server
    assert ids[0] not in now and not (runs_dir / ids[0]).exists()
    assert "newest 6 runs" in live.client.get("/api/runs").json()["retention"]


def test_bad_ids_and_names_get_exact_errors(live):
    run_id = sorted(_runs(live))[0]  # the oldest: not the one being recorded
    cases = [
        (f"/api/runs/{run_id[:-1]}X", 422, "not a run's id"),
        ("/api/runs/20991126T050005123Z-collision", 404,
         "no run '20991126T050005123Z-collision' in"),
        (f"/api/runs/{run_id}/files/nope.png", 404, f"run '{run_id}' has no file 'nope.png'"),
        (f"/api/runs/{run_id}/files/%2E%2E", 422, "file name '..': not a file of a run"),
        (f"/api/runs/{run_id}/files/.run.json.tmp", 422, "not a file of a run"),
    ]
    for path, status, detail in cases:
        r = live.client.get(path)
        assert r.status_code == status and detail in r.json()["detail"], (path, r.text)
    for path in (f"/api/runs/{run_id}/files/..%2F..%2Fetc%2Fpasswd",
                 f"/api/runs/..%2F{run_id}/files/run.json", "/api/runs/%2E%2E"):
        assert live.client.get(path).status_code in (404, 422), path
    gone = live.client.delete(f"/api/runs/{run_id}")
    assert gone.status_code == 200 and gone.json() == {"deleted": run_id}
    assert live.client.get(f"/api/runs/{run_id}").status_code == 404
    assert live.client.delete(f"/api/runs/{run_id}").status_code == 404


def test_the_cli_lists_the_runs_and_shows_one(live, capsys):
    runs = _runs(live)
    proc = subprocess.run([EXE, "runs", "--dir", str(live.runs_dir)], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    listed = [line.split()[0] for line in proc.stdout.splitlines()[1:]]
    assert listed == sorted(runs, reverse=True)  # newest first
    shown = next(i for i, x in runs.items() if x["status"] == "finished")
    assert cli_main(["runs", "show", shown, "--dir", str(live.runs_dir)]) == 0
    out = capsys.readouterr().out
    assert f"run {shown}" in out and "status finished" in out
    assert "simulated" in out and "telemetry.csv" in out
    assert cli_main(["runs", "show", "../x", "--dir", str(live.runs_dir)]) == 2
    assert "run id '../x': not a run's id" in capsys.readouterr().err
    assert cli_main(["runs", "--dir", str(live.runs_dir) + "-none"]) == 2
    assert "no runs directory" in capsys.readouterr().err


def test_the_page_shows_the_result_and_compares_two_runs(live):
    """In a real browser: after a short hil collision the result panel shows its
    restitution against the ideal run's and its plots, read from the run's folder; two runs
    chosen in the runs list are compared (settings that differ, plots side by side)."""
    sync_api = pytest.importorskip("playwright.sync_api")
    from tests.browser import HAVE_CHROMIUM, NEEDS_CHROMIUM, chromium

    if not HAVE_CHROMIUM:
        pytest.skip(NEEDS_CHROMIUM)
    live.wait_for(lambda s: s["status"] not in ("running", "starting"))
    with chromium() as browser:
        page = browser.new_page(viewport={"width": 1000, "height": 700})
        errors = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(live.url + "/")
        page.wait_for_selector("#run-result", state="attached", timeout=60_000)
        page.locator("#runs-toggle").click()  # the panel opens on a click only
        r = live.client.post("/api/scenarios/collision/start",
                             json={**SHORT_COLLISION, "mode": "hil"})
        assert r.status_code == 200, r.text
        run_id = live.client.get("/api/runs").json()["recording"]
        record = _ended(live, run_id, 90.0)
        h = record["headline"]
        expected = (f"restitution {h['restitution']:.3f} (95 % interval "
                    f"{h['restitution_interval_95'][0]:.3f} – "
                    f"{h['restitution_interval_95'][1]:.3f}) · ideal run "
                    f"{h['restitution_ideal']:.3f}")
        try:
            page.wait_for_function(
                "([id, text]) => { const r = document.getElementById('run-result');"
                " return r && r.dataset.runId === id && r.querySelector('img.run-plot')"
                " && r.textContent.includes(text); }", arg=[run_id, expected],
                timeout=60_000)
            page.wait_for_function(  # a plot drawn, served from the run's folder
                "() => [...document.querySelectorAll('#run-result img.run-plot')]"
                ".some((i) => i.complete && i.naturalWidth > 300)", timeout=60_000)
        except sync_api.TimeoutError:
            pytest.fail(f"the result panel shows {page.locator('#run-result').inner_text()!r}"
                        f"; expected run {run_id} with {expected!r} and a plot; page "
                        f"errors: {errors}")
        assert (f"restitution {h['restitution']:.3f} (ideal {h['restitution_ideal']:.3f}"
                in page.locator("#runs-headline").inner_text())  # the line at a glance
        c = live.client.get(f"/api/runs/{run_id}").json()["metrics"]["collision"]
        err, depth = c["rendering_error_m"], c["contact_depth_m"]
        assert page.locator("#run-result .result-rendering").inner_text() == (
            f"the mockups rendered the contact to {1e6 * err:.1f} µm rms of overlap against "
            f"the satellites' {1e6 * depth:.0f} µm contact depth ({100 * err / depth:.1f} %)")
        src = page.locator("#run-result img.run-plot").first.get_attribute("src")
        assert src.startswith(f"/api/runs/{run_id}/files/") and ".png" in src
        assert page.locator("#runs-retention").inner_text().startswith("the newest 6 runs")
        # compare it with an ideal run
        other = next(x["id"] for x in live.client.get("/api/runs").json()["runs"]
                     if x["mode"] == "ideal" and x["status"] == "finished")
        for rid in (run_id, other):
            page.locator(f"input.run-choose[data-run-id='{rid}']").check()
        page.locator("#compare-button").click()
        page.wait_for_function(  # the figures overlaid, drawn by the server
            "() => { const c = document.getElementById('run-compare');"
            " return c && c.querySelector('.compare-diff') && [...c.querySelectorAll("
            "'img.compare-overlay')].some((i) => i.complete && i.naturalWidth > 300); }",
            timeout=90_000)
        diff = page.locator("#run-compare .compare-diff").inner_text()
        assert "mode" in diff and "hil" in diff and "ideal" in diff
        assert "loop.duration_s" in diff  # 1.2 s against the ideal run's
        assert page.locator("#run-compare .run-summary").count() == 2
        a, b = sorted((run_id, other))
        src = page.locator("#run-compare img.compare-overlay").first.get_attribute("src")
        assert src.startswith(f"/api/runs/compare/plot?a={a}&b={b}&figure=")
        # the runs list offers the run's 3D replay, which opens and loads in a new tab
        link = page.locator(f"#runs-list tr[data-run-id='{run_id}'] a.run-replay")
        link.wait_for(timeout=20_000)
        assert link.get_attribute("href") == f"/api/runs/{run_id}/files/replay.html"
        assert link.get_attribute("target") == "_blank"
        logs: list[str] = []
        page.context.on("console", lambda m: logs.append(m.text))  # (every tab's)
        with page.context.expect_page() as opened:
            link.click()
        viewer = opened.value
        viewer.bring_to_front()  # (a tab in the background is not drawn)
        deadline = time.monotonic() + 60
        while not any("File loaded" in t for t in logs) and time.monotonic() < deadline:
            viewer.wait_for_timeout(250)
        assert any("File loaded" in t for t in logs), logs[-10:]
        assert viewer.title() == "orbit-emulator replay: collision (hil)"


def test_a_dead_loop_s_run_keeps_its_rows(live, runs_dir, caplog):
    """The loop process killed mid-run: the run ends "fault" with the reason, and its
    rows up to the kill are on disk (read from the ring the recorder keeps open); the
    server's log says so."""
    live.wait_for(lambda s: s["status"] not in ("running", "starting"))
    r = live.client.post("/api/scenarios/collision/start",
                         json={"mode": "ideal", "loop": {"duration_s": 30.0}})
    assert r.status_code == 200, r.text
    run_id = live.client.get("/api/runs").json()["recording"]
    s = live.wait_for(lambda s: s["t_s"] >= 1.0)
    os.kill(s["loop"]["pid"], signal.SIGKILL)
    record = _wait(lambda: (x := _runs(live)[run_id])["status"] != "running" and x, 20.0,
                   "the dead loop's run was not ended")
    assert record["status"] == "fault" and "killed by SIGKILL" in record["reason"]
    rows = read_telemetry(runs_dir / run_id / "telemetry.csv")[1]
    # the state's t_s is the ODS's after its last step; that step's row is one cycle
    # earlier, and the kill may come before another cycle ran (the CSV's 12 digits
    # against the state's float)
    dt_s = 1.0 / load_scenario("collision").loop.rate_hz
    assert rows[-1, 0] >= s["t_s"] - dt_s - 1e-9
    assert json.loads((runs_dir / run_id / "metrics.json").read_text())["status"] == "fault"
    assert any(r.getMessage().startswith("the loop process exited (code -9), killed by "
                                         "SIGKILL: the run ends here") for r in caplog.records)


def test_a_start_the_loop_takes_late_is_recorded_whole(live, runs_dir):
    """The loop process paused for 0.8 s as a start is sent (a core taken by other work):
    the recorder waits for the loop to take the new run, instead of ending it at once as
    "stopped" by a reset with none of its rows; the run is kept finished, whole."""
    live.wait_for(lambda s: s["status"] not in ("running", "starting"))
    r = live.client.post("/api/scenarios/collision/start",  # a live loop (after a fault)
                         json={"mode": "ideal", "loop": {"duration_s": 0.1}})
    assert r.status_code == 200, r.text
    pid = live.wait_for(lambda s: s["status"] == "finished")["loop"]["pid"]
    os.kill(pid, signal.SIGSTOP)
    try:
        start = threading.Thread(target=lambda: httpx.post(
            f"{live.url}/api/scenarios/collision/start", timeout=60.0,
            json={"mode": "ideal", "loop": {"duration_s": 1.0}}))
        start.start()
        time.sleep(0.8)
    finally:
        os.kill(pid, signal.SIGCONT)
    start.join(60.0)
    run_id = max(_runs(live))  # the newest (ids begin with their start time)
    record = _ended(live, run_id)
    assert record["status"] == "finished", record
    rows = read_telemetry(runs_dir / run_id / "telemetry.csv")[1]
    assert rows[-1, 0] == pytest.approx(1.0, abs=0.003) and len(rows) >= 500


class _FillingDisk:
    """A run's telemetry.csv on a disk with ``room`` bytes left: a write past it writes what
    fits, the next one fails with ENOSPC, as write(2) on a full disk does (the fault is
    injected at the recorder's file, the OS boundary; the recorder, loop and server are
    real)."""

    def __init__(self, file, room: int) -> None:
        self.file, self.room = file, room

    def write(self, data) -> int:
        if self.room <= 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        n = self.file.write(data[:self.room])
        self.room -= n
        return n

    def fileno(self) -> int:
        return self.file.fileno()

    def close(self) -> None:
        self.file.close()

    @property
    def closed(self) -> bool:
        return self.file.closed


def test_a_full_disk_stops_the_recording_at_a_whole_row_and_the_run_goes_on(live, runs_dir,
                                                                             caplog):
    """telemetry.csv's disk fills mid-run (a row cut in the middle): the file keeps its
    whole rows only, each once; the run goes on, its run.json and the state say the
    recording stopped; one log line, not one a period; no temporary file left."""
    live.wait_for(lambda s: s["status"] not in ("running", "starting"))
    r = live.client.post("/api/scenarios/collision/start",
                         json={"mode": "ideal", "loop": {"duration_s": 30.0}})
    assert r.status_code == 200, r.text
    run_id = live.client.get("/api/runs").json()["recording"]
    recorder = live.app.state.service.recorder
    with recorder._lock:  # the disk fills 3 rows and a part of a row from now
        appender = recorder._run.appender
        appender.file = _FillingDisk(appender.file, room=3 * 2000 + 777)
    record = _wait(lambda: (x := _runs(live)[run_id]).get("recording") == "failed" and x,
                   10.0, "the failed recording was not noted")
    assert "telemetry.csv could not be written: No space left on device" in \
        record["recording_error"]
    t_then = live.state()["t_s"]
    s = live.wait_for(lambda s: s["t_s"] >= t_then + 1.0)  # the run goes on, saying so
    assert s["status"] == "running"
    assert any("the recording stopped" in w for w in s.get("warnings", [])), s.get("warnings")
    lines = (runs_dir / run_id / "telemetry.csv").read_text().splitlines(keepends=True)
    n_columns = lines[0].count(",") + 1
    assert all(line.endswith("\n") and line.count(",") == n_columns - 1 for line in lines)
    rows = read_telemetry(runs_dir / run_id / "telemetry.csv")[1]
    assert np.all(np.diff(rows[:, 0]) > 0)  # each row once, in order
    assert f"({len(rows)} rows written)" in record["recording_error"]
    failed = [r for r in caplog.records if "could not be written" in r.getMessage()]
    assert len(failed) == 1, [r.getMessage() for r in failed]
    assert live.client.post("/api/stop").status_code == 200
    record = _wait(lambda: "telemetry_rows" in (x := _runs(live)[run_id]) and x, 10.0,
                   "the run was not ended")
    assert record["status"] == "stopped" and record["recording"] == "failed"
    assert record["telemetry_rows"] == len(rows)
    metrics = json.loads((runs_dir / run_id / "metrics.json").read_text())
    assert record["recording_error"] in metrics["warnings"]
    assert not [p.name for p in (runs_dir / run_id).iterdir() if p.name.endswith(".tmp")]


@pytest.mark.parametrize("runs_dir_arg, message", [
    ("/dev/null", "error: --runs-dir /dev/null: not a directory"),
    ("/proc/1", "error: --runs-dir /proc/1: the runs cannot be written there: "),
])
def test_serve_names_a_runs_dir_it_cannot_write_before_it_starts(runs_dir_arg, message):
    proc = subprocess.run([EXE, "serve", "--port", "0", "--runs-dir", runs_dir_arg],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and message in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr


def test_a_malformed_run_json_is_left_out_and_named(live, runs_dir, caplog):
    """A run.json spoiled by hand (not an object; a seed that is not a number): the list,
    REST and the CLI's, shows the other runs and names the bad one; its GET is a 422."""
    good = _runs(live)
    spoiled = {"20261126T000000001Z-collision": "[1, 2]",
               "20261126T000000002Z-collision": json.dumps(
                   {"id": "20261126T000000002Z-collision", "scenario": "collision",
                    "seed": "x", "status": "finished"})}
    for run_id, text in spoiled.items():
        (runs_dir / run_id).mkdir()
        (runs_dir / run_id / "run.json").write_text(text)
    try:
        assert set(_runs(live)) == set(good)  # the others, listed
        warned = " ".join(r.getMessage() for r in caplog.records)
        assert ("run '20261126T000000001Z-collision': its run.json is not a run's record "
                "(a JSON object), it is list") in warned
        assert ("run '20261126T000000002Z-collision': its run.json has seed = 'x', not int"
                in warned)
        r = live.client.get("/api/runs/20261126T000000002Z-collision")
        assert r.status_code == 422 and "has seed = 'x', not int" in r.json()["detail"]
        proc = subprocess.run([EXE, "runs", "--dir", str(runs_dir)], capture_output=True,
                              text=True, timeout=60)
        assert proc.returncode == 0, proc.stderr
        listed = [line.split()[0] for line in proc.stdout.splitlines()[1:]]
        assert listed == sorted(good, reverse=True)
        assert "its run.json is not a run's record" in proc.stderr
        assert "has seed = 'x', not int; left out of the runs list" in proc.stderr
        proc = subprocess.run([EXE, "runs", "show", "20261126T000000001Z-collision", "--dir",
                               str(runs_dir)], capture_output=True, text=True, timeout=60)
        assert proc.returncode == 2 and "error: run '20261126T000000001Z-collision': its " \
            "run.json is not a run's record" in proc.stderr, proc.stderr
    finally:
        for run_id in spoiled:
            shutil.rmtree(runs_dir / run_id)


def test_a_runs_dir_gone_or_unwritable_while_serving_never_fails_a_start(live, runs_dir):
    """The runs folder deleted while the server runs: the list is empty (not a 500); a
    file in its place: a start runs unrecorded, saying so; the folder back: the next run
    is recorded in it, made again. (The runs are moved away and back.)"""
    live.wait_for(lambda s: s["status"] not in ("running", "starting"))
    away = runs_dir.with_name(runs_dir.name + "-away")
    runs_dir.rename(away)
    try:
        r = live.client.get("/api/runs")
        assert r.status_code == 200 and r.json()["runs"] == [], r.text
        runs_dir.write_text("not a folder")
        r = live.client.post("/api/scenarios/collision/start",
                             json={"mode": "ideal", "loop": {"duration_s": 0.4}})
        assert r.status_code == 200, r.text
        assert any("this run is not recorded: its folder could not be made in" in w
                   for w in r.json().get("warnings", [])), r.json().get("warnings")
        assert live.client.get("/api/runs").json()["runs"] == []
        live.wait_for(lambda s: s["status"] not in ("running", "starting"))
        runs_dir.unlink()
        r = live.client.post("/api/scenarios/collision/start",
                             json={"mode": "ideal", "loop": {"duration_s": 0.4}})
        assert r.status_code == 200, r.text
        assert not any("not recorded" in w for w in r.json().get("warnings", []))
        run_id = live.client.get("/api/runs").json()["recording"]
        assert (runs_dir / run_id / "run.json").is_file()  # the folder made again
        live.wait_for(lambda s: s["status"] not in ("running", "starting"))
        _wait(lambda: "telemetry_rows" in _runs(live)[run_id], 10.0, "the run did not end")
        # its figures are drawn after it ended, by the recorder's worker: done before the
        # folder is removed (else they land in it while it goes)
        _wait(lambda: _runs(live)[run_id].get("plots") != "pending", 60.0,
              "the run's figures were not drawn")
    finally:
        if runs_dir.is_dir():
            shutil.rmtree(runs_dir)
        else:
            runs_dir.unlink(missing_ok=True)
        away.rename(runs_dir)


def test_a_run_json_the_disk_refuses_is_written_when_it_takes_it(live, runs_dir, caplog):
    """run.json cannot be written when the run ends (a folder stands where its temporary
    file goes, a real write error): the run is ended all the same, logged once, and its
    run.json says so as soon as the disk takes it again."""
    live.wait_for(lambda s: s["status"] not in ("running", "starting"))
    r = live.client.post("/api/scenarios/collision/start",
                         json={"mode": "ideal", "loop": {"duration_s": 30.0}})
    assert r.status_code == 200, r.text
    run_id = live.client.get("/api/runs").json()["recording"]
    live.wait_for(lambda s: s["t_s"] >= 0.5)
    blocker = runs_dir / run_id / ".run.json.tmp"
    blocker.mkdir()
    try:
        assert live.client.post("/api/stop").status_code == 200
        _wait(lambda: (runs_dir / run_id / "metrics.json").is_file(), 10.0, "no metrics")
        time.sleep(1.0)  # four periods of the recorder, each trying again
        assert _runs(live)[run_id]["status"] == "running"  # (the disk refuses run.json)
        refused = [r for r in caplog.records if r.getMessage().startswith(f"run {run_id}: ")]
        assert len(refused) == 1 and "could not be written" in refused[0].getMessage()
    finally:
        blocker.rmdir()
    record = _wait(lambda: "telemetry_rows" in (x := _runs(live)[run_id]) and x, 10.0,
                   "run.json was not written once the disk took it")
    assert record["status"] == "stopped" and record["telemetry_rows"] > 0
    assert not [p.name for p in (runs_dir / run_id).iterdir() if p.name.endswith(".tmp")]
