"""End-to-end REST tests against the real app (uvicorn + viser + the loop process)."""

from __future__ import annotations

import time

import httpx
import numpy as np
import pytest

from app.sim.rotations import quat_to_matrix
from tests.live_server import LiveServer


@pytest.fixture(scope="module")
def live():
    with LiveServer() as server:
        yield server


def _post_raw(live, path: str, raw: str):
    return live.client.post(path, content=raw, headers={"Content-Type": "application/json"})


def test_health_scenarios_and_page(live):
    health = live.client.get("/api/health").json()
    assert health["status"] == "ok" and health["loop_alive"]
    assert health["viewer"] == "/viewer/"
    viewer = live.client.get("/viewer/")
    assert viewer.status_code == 200 and "<html" in viewer.text[:200].lower()
    # viser's own port answers no one but the app (a page on any site could reach it)
    direct = httpx.get(f"http://127.0.0.1:{live.viser_port}/")
    assert direct.status_code == 403 and "/viewer/" in direct.text
    names = [s["name"] for s in live.client.get("/api/scenarios").json()]
    assert {"free-floating", "collision"} <= set(names)
    page = live.client.get("/")
    assert page.status_code == 200 and 'id="start-button"' in page.text
    assert "/docs" in page.text
    assert live.client.get("/openapi.json").json()["paths"]["/api/push"]
    state = live.state()
    assert state["status"] == "idle"
    for key in ("t_s", "status", "reason", "satellites", "robots", "loop"):
        assert key in state
    assert set(state["loop"]) >= {"cycles", "cycle_time_us", "deadline_misses"}
    for path in ("/api/telemetry", "/api/metrics", "/api/run.zip", "/api/replay.html",
                 "/api/bag"):  # no run to take home yet
        r = live.client.get(path)
        assert r.status_code == 404 and r.json()["detail"].startswith("no run to download"), (
            path, r.status_code)


def test_push_changes_velocity_by_impulse(live):
    s = live.client.post("/api/scenarios/free-floating/start", json={}).json()
    assert s["status"] == "running", s
    assert s["scenario"] == "free-floating"
    assert s["satellites"][0]["velocity_mps"] == [0.0, 0.0, 0.0]  # hand-driven: at rest
    s0 = live.wait_for(lambda s: s["t_s"] >= 1.7)
    assert np.linalg.norm(s0["satellites"][0]["velocity_mps"]) < 1e-4  # nothing scripted
    v0 = np.array(s0["satellites"][0]["velocity_mps"])
    r = live.client.post("/api/push", json={"satellite": 1, "force_N": [0.0, 20.0, 0.0],
                                             "duration_s": 0.3})
    assert r.status_code == 200, r.text
    t_push = r.json()["t_s"]
    s1 = live.wait_for(lambda s: s["t_s"] >= t_push + 0.9)
    v1 = np.array(s1["satellites"][0]["velocity_mps"])
    dv = v1 - v0
    expected = 0.005 * 20.0 * 0.3 / 1.0  # force_scale * impulse / mass = 0.03 m/s
    assert dv[1] == pytest.approx(expected, rel=0.27), dv
    assert abs(dv[0]) < 0.27 * expected and abs(dv[2]) < 0.27 * expected, dv
    # the mockup (robot FK) follows the satellite
    rob = s1["robots"][0]
    err = np.linalg.norm(np.array(rob["mockup_position_m"])
                         - np.array(s1["satellites"][0]["position_m"]))
    assert err < 0.01


def test_free_flying_starts_over_rest_and_flies_on_its_own(live):
    """The scenario file is listed and starts like any other; its GNC moves the satellite
    toward its first waypoint (orbit (0.75, -0.5, 0) m: (0.15, -0.1, 0) m in the lab)
    with no push, and its thrust is in the telemetry, not in the F/T columns."""
    listed = {s["name"]: s for s in live.client.get("/api/scenarios").json()}
    assert "waypoints" in listed["free-flying"]["description"]
    live.client.post("/api/stop")  # whatever ran before
    s = live.client.post("/api/scenarios/free-flying/start", json={}).json()
    assert s["status"] == "running" and s["scenario"] == "free-flying", s
    s = live.wait_for(lambda s: s["t_s"] >= 2.0)
    x, y, _ = s["satellites"][0]["position_m"]
    assert x > 0.05 and y < -0.03, s["satellites"][0]
    s = live.client.post("/api/stop").json()
    lines = live.client.get("/api/telemetry", params={"format": "csv"}).text.splitlines()
    header = lines[0].split(",")
    fx = np.array([float(line.split(",")[header.index("sat1_gnc_fx_N")]) for line in lines[1:]])
    assert fx.max() > 0.5 and fx[0] == pytest.approx(0.75)  # the first command, unsaturated


def test_gravity_stabilised_rendezvous_and_tumbling_target_run_from_the_web_app(live):
    """Each starts over REST on the arms and moves as it should: the gravity-stabilised
    satellite's pitch swings back from its 10 deg release; the rendezvous chaser holds S1
    (100 m behind: 0.5 m in the lab) and then leaves it along V-bar; the tumbling target
    turns at its 2 deg/s on its arm while the chaser follows."""
    live.client.post("/api/stop")
    s = live.client.post("/api/scenarios/gravity-stabilised/start", json={}).json()
    assert s["status"] == "running" and s["mode"] == "hil", s
    s = live.wait_for(lambda s: s["t_s"] >= 1.0)
    q0 = live.client.get("/api/telemetry", params={"format": "csv"}).text.splitlines()
    header = q0[0].split(",")
    qz = [float(line.split(",")[header.index("sat1_qz")]) for line in q0[1:]]
    assert s["status"] == "running" and abs(qz[-1]) < abs(qz[0]) - 0.01  # swinging back
    live.client.post("/api/stop")
    s = live.client.post("/api/scenarios/rendezvous/start", json={}).json()
    assert s["status"] == "running" and s["mode"] == "hil", s
    s = live.wait_for(lambda s: s["t_s"] >= 2.5)
    assert s["status"] == "running" and len(s["satellites"]) == 2
    assert s["satellites"][0]["position_m"][1] > -0.5 + 1e-3  # its first burn was fired
    assert s["warnings"] == []
    live.client.post("/api/stop")
    # at k_M = 500 the F/T noise can spin the satellites: the state says so from the start
    s = live.client.post("/api/scenarios/rendezvous/start",
                         json={"scaling": {"mass": 500.0}, "loop": {"duration_s": 0.5}}).json()
    assert [w.split(":")[0] for w in s["warnings"]] == ["satellite 'chaser'",
                                                         "satellite 'target'"], s
    assert "the sensor's noise can spin it" in s["warnings"][0]
    live.client.post("/api/stop")
    s = live.client.post("/api/scenarios/tumbling-target/start", json={}).json()
    assert s["status"] == "running" and s["scenario"] == "tumbling-target", s
    s0 = live.wait_for(lambda s: s["t_s"] >= 1.0)
    s1 = live.wait_for(lambda s: s["t_s"] >= s0["t_s"] + 1.0)
    assert s1["status"] == "running"
    live.client.post("/api/stop")
    lines = live.client.get("/api/telemetry", params={"format": "csv"}).text.splitlines()
    header = lines[0].split(",")
    wz = np.array([float(line.split(",")[header.index("sat2_wz_radps")]) for line in lines[1:]])
    np.testing.assert_allclose(wz, np.radians(2.0), atol=1e-4)
    rob_q = [float(v) for v in lines[-1].split(",")[header.index("rob2_qw"):][:4]]
    sat_q = [float(v) for v in lines[-1].split(",")[header.index("sat2_qw"):][:4]]
    assert abs(np.dot(rob_q, sat_q)) > np.cos(0.01 / 2)  # the arm turns the mockup with it


BAD_PUSHES = [
    ('{"satellite": 1, "force_N": [NaN, 0, 0], "duration_s": 0.3}', "force_N"),
    ('{"satellite": 1, "force_N": [0, Infinity, 0], "duration_s": 0.3}', "force_N"),
    ('{"satellite": 1, "force_N": [0, 1e999, 0], "duration_s": 0.3}', "force_N"),
    ('{"satellite": 1, "force_N": [0, 20, 0], "duration_s": NaN}', "duration_s"),
    ('{"satellite": 1, "force_N": [0, 120, 0], "duration_s": 0.3}', "force_N"),
    ('{"satellite": 1, "force_N": [80, 80, 0], "duration_s": 0.3}',
     "force_N: magnitude 113.1 N exceeds the sensor range 100 N"),
    ('{"satellite": 1, "force_N": [1e308, 0, 0], "duration_s": 0.3}',
     "force_N: magnitude 1e+308 N exceeds"),
    ('{"satellite": 1, "force_N": [1.7e308, 1.7e308, 1.7e308], "duration_s": 0.3}',
     "force_N: magnitude over 1e308 N exceeds"),
    ('{"satellite": 1, "force_N": [0, 20, 0], "duration_s": 0}', "duration_s"),
    ('{"satellite": 1, "force_N": [0, 20, 0], "duration_s": -1}', "duration_s"),
    ('{"satellite": 1, "force_N": [0, 20, 0], "duration_s": 5.5}', "duration_s"),
    ('{"satellite": 0, "force_N": [0, 20, 0], "duration_s": 0.3}', "satellite"),
    ('{"satellite": 2, "force_N": [0, 20, 0], "duration_s": 0.3}', "satellite"),
    ('{"satellite": "1", "force_N": [0, 20, 0], "duration_s": 0.3}', "satellite"),
    ('{"satellite": 1.5, "force_N": [0, 20, 0], "duration_s": 0.3}', "satellite"),
    ('{"satellite": true, "force_N": [0, 20, 0], "duration_s": 0.3}', "satellite"),
    ('{"satellite": 1, "force_N": [0, 20], "duration_s": 0.3}', "force_N"),
    ('{"satellite": 1, "force_N": ["0", 20, 0], "duration_s": 0.3}', "force_N"),
    ('{"satellite": 1, "force_N": 20, "duration_s": 0.3}', "force_N"),
    ('{"satellite": 1, "force_N": [0, 20, 0]}', "duration_s"),
    ('{"satellite": 1, "force_N": [0, 20, 0], "duration_s": 0.3, "extra": 1}', "extra"),
    ('{"satellite": 1, "force_N": [0, 20, 0], "duration_s": "0.3"}', "duration_s"),
    ("not json", "body"),
    ('{"satellite": 1, "force_N": [0, 20, 0], "duration_s": 0.3, "point_m": [0, 0]}',
     "point_m"),
    ('{"satellite": 1, "force_N": [0, 20, 0], "duration_s": 0.3, "point_m": [0, NaN, 0]}',
     "point_m"),
    ('{"satellite": 1, "force_N": [0, 20, 0], "duration_s": 0.3, "point_m": [0.3, 0, 0]}',
     "point_m: [0.3, 0.0, 0.0] is outside the satellite's box: each coordinate within "
     "+-[0.1, 0.1, 0.05] m of its COM"),
]


def test_bad_input_is_rejected_and_changes_nothing(live):
    live.client.post("/api/stop")
    # no scripted pulses in the next 1000 s: the velocity must stay put
    quiet = {"pulses": []}
    s = live.client.post("/api/scenarios/free-floating/start", json=quiet).json()
    assert s["status"] == "running", s
    s0 = live.wait_for(lambda s: s["t_s"] >= 0.3)
    gen = s0["generation"]
    for raw, field in BAD_PUSHES:
        r = _post_raw(live, "/api/push", raw)
        assert r.status_code == 422, (raw, r.status_code, r.text)
        assert field in r.json()["detail"], (raw, r.json())
    bad_starts = [
        ("free-floating", "{}", 409, "already running"),
        ("nope", "{}", 404, "unknown scenario"),
    ]
    for name, raw, code, text in bad_starts:
        r = _post_raw(live, f"/api/scenarios/{name}/start", raw)
        assert r.status_code == code, (name, raw, r.text)
        assert text in r.json()["detail"]
    s1 = live.state()
    assert s1["status"] == "running" and s1["generation"] == gen
    dv = np.subtract(s1["satellites"][0]["velocity_mps"], s0["satellites"][0]["velocity_mps"])
    assert s1["t_s"] - s0["t_s"] < 1.0
    assert np.linalg.norm(dv) < 0.003, dv  # no push got through (a push gives >= 1e-3)


def test_a_push_at_a_point_gives_the_ods_r_cross_f_and_turns_the_satellite(live):
    """POST /api/push with point_m (body axes, from the COM): the ODS's input torque is
    r × F (in body axes; ideal: exactly what the hand applies), and the satellite spins up
    by torque_scale · τ · Δt / I, Eq. 7 with the scaled torque."""
    live.client.post("/api/stop")
    s = live.client.post("/api/scenarios/free-floating/start", json={"mode": "ideal"}).json()
    assert s["status"] == "running" and s["mode"] == "ideal", s
    live.wait_for(lambda s: s["t_s"] >= 0.2)
    r_B, f_R, dt = np.array([0.1, 0.0, 0.0]), np.array([0.0, 20.0, 0.0]), 0.3
    r = live.client.post("/api/push", json={"satellite": 1, "force_N": list(f_R),
                                             "duration_s": dt, "point_m": list(r_B)})
    assert r.status_code == 200, r.text
    assert r.json()["point_m"] == list(r_B)
    t_push = r.json()["t_s"]
    during = live.wait_for(lambda s: s["t_s"] >= t_push + 0.1)
    sat = during["satellites"][0]
    R_R_B = quat_to_matrix(np.array(sat["attitude_wxyz"]))  # body axes in R
    torque_B = np.cross(r_B, R_R_B.T @ f_R)  # ~ (0, 0, 2) N m
    np.testing.assert_allclose(sat["applied_torque_Nm"], torque_B, atol=1e-9)
    np.testing.assert_allclose(sat["applied_force_N"], f_R, atol=1e-9)
    after = live.wait_for(lambda s: s["t_s"] >= t_push + dt + 0.2)
    cfg = live.app.state.service.config_for("free-floating")
    inertia_zz = cfg.satellites[0].principal_inertia()[2]
    expected = cfg.orbit.torque_scale * 2.0 * dt / inertia_zz  # 0.045 rad/s
    omega = np.array(after["satellites"][0]["omega_radps"])
    assert omega[2] == pytest.approx(expected, rel=0.03), omega
    assert np.hypot(omega[0], omega[1]) < 0.01 * expected
    live.client.post("/api/stop")


def test_reset_takes_the_run_back_to_its_start_with_its_settings(live):
    """Reset restarts what ran (its scenario, settings and mode), not the file's defaults
    nor whatever a panel shows."""
    live.client.post("/api/stop")
    s = live.client.post("/api/scenarios/free-floating/start",
                         json={"mode": "ideal", "loop": {"duration_s": 50.0},
                               "orbit": {"altitude_m": 500e3}}).json()
    assert s["status"] == "running"
    live.wait_for(lambda s: s["t_s"] >= 0.2)
    live.client.post("/api/stop")
    r = live.client.post("/api/reset").json()
    assert r["status"] == "idle" and r["t_s"] == 0.0
    assert (r["scenario"], r["mode"]) == ("free-floating", "ideal")
    for path in ("/api/telemetry", "/api/replay.html"):  # a reset begins a new run
        assert live.client.get(path).status_code == 404, path
    assert r["settings"]["duration_s"] == 50.0 and r["settings"]["altitude_m"] == 500e3
    s = live.client.post("/api/scenarios/free-floating/start", json={}).json()
    assert s["status"] == "running"
    assert live.wait_for(lambda s: s["t_s"] >= 0.1)["robots"][0]["tracking_error_m"] < 0.01
    plots = live.app.state.scene.plots
    live.wait_for(lambda s: len(plots["force"].data[0]) > 1)  # the panel plots the run
    live.client.post("/api/stop")
    r = live.client.post("/api/reset").json()
    live.wait_for(lambda s: not any(len(p.data[0]) for p in plots.values()), timeout_s=5)
    assert r["mode"] == "hil" and r["robots"]
    assert all(rob["tracking_error_m"] is None for rob in r["robots"])  # not started
    # the panel's scenario selector resets to the chosen scenario in the panel's mode
    r = live.app.state.service.reset("collision", mode="ideal")
    assert (r["scenario"], r["mode"], r["status"]) == ("collision", "ideal", "idle")
    r = live.client.post("/api/reset").json()  # and a reset keeps that choice
    assert (r["scenario"], r["mode"]) == ("collision", "ideal")


def test_the_favicon_is_served(live):
    r = live.client.get("/favicon.ico")
    assert r.status_code == 200 and r.headers["content-type"].startswith("image/svg+xml")
    assert b"<svg" in r.content[:200]


BAD_OVERRIDES = [
    ('{"vfdm": {"kp_lin": -1}}', "vfdm.kp_lin"),
    ('{"vfdm": {"kp_lin": NaN}}', "vfdm.kp_lin"),
    ('{"satellites": {"0": {"velocity_mps": [0.01, Infinity, 0]}}}', "satellites.0.velocity_mps"),
    ('{"satellites": {"0": {"mass_kg": "heavy"}}}', "satellites.0.mass_kg"),
    ('{"satellites": [{"mass_kg": 2}]}', "satellites.0.name"),  # a list replaces the list
    ('{"satellites": {"first": {"mass_kg": 2}}}', "got the key 'first'"),
    ('{"orbit": {"altitude_m": 0}}', "orbit.altitude_m"),
    ('{"bogus": 1}', "bogus"),
    ('{"mode": "sideways"}', "mode"),
    ('{"loop": {"rate_hz": 1e9}}', "loop.rate_hz"),
    ('[1, 2]', "body"),
    # what would exhaust memory or time is bounded before anything starts
    ('{"loop": {"telemetry_capacity": 10000000}}', "loop.telemetry_capacity"),
    ('{"loop": {"approach_timeout_s": 1e9}}', "loop.approach_timeout_s"),
    ('{"loop": {"duration_s": 1e9}}', "loop.duration_s"),
    ('{"vfdm": {"iterations": 1000}}', "vfdm.iterations"),
    ('{"pulses": [' + ", ".join(['{"satellite": "cubesat", "start_s": 1, "end_s": 2}']
                                * 1001) + "]}", "pulses"),
    ('{"satellites": {"2": {"mass_kg": 2}}}', "satellites.2: index out of range"),
]


def test_collision_stop_reset_and_bad_starts(live):
    live.client.post("/api/stop")
    s = live.state()
    assert s["status"] in ("idle", "stopped", "finished", "safety_stop")
    # pushing while not running: 409, nothing queued
    r = live.client.post("/api/push", json={"satellite": 1, "force_N": [0, 20, 0],
                                             "duration_s": 0.3})
    assert r.status_code == 409 and "no scenario is running" in r.json()["detail"]
    gen = s["generation"]
    for raw, field in BAD_OVERRIDES:
        r = _post_raw(live, "/api/scenarios/collision/start", raw)
        assert r.status_code == 422, (raw, r.status_code, r.text)
        assert field in r.json()["detail"], (raw, r.json())
    s = live.state()
    assert s["generation"] == gen and s["status"] not in ("running", "starting")

    body = {"satellites": {"0": {"velocity_mps": [0.05, 0, 0]}}, "vfdm": {"kp_lin": 20},
            "mode": "hil"}
    s = live.client.post("/api/scenarios/collision/start", json=body).json()
    assert s["status"] == "running" and s["scenario"] == "collision"
    assert len(s["satellites"]) == 2 and len(s["robots"]) == 2
    assert s["satellites"][0]["velocity_mps"][0] == pytest.approx(0.05, abs=1e-3)
    s = live.wait_for(lambda s: s["t_s"] > 0.5)
    x1, x2 = (sat["position_m"][0] for sat in s["satellites"])
    assert x1 > -0.35 + 0.01 and x2 < 0.35 - 0.01  # moving toward each other
    s = live.client.post("/api/stop").json()
    assert s["status"] == "stopped"
    t_stop = s["t_s"]
    time.sleep(0.3)
    assert live.state()["t_s"] == t_stop
    csv = live.client.get("/api/telemetry", params={"format": "csv"})
    assert csv.status_code == 200 and csv.headers["content-type"].startswith("text/csv")
    lines = csv.text.splitlines()
    assert lines[0].startswith("t_s,sat1_x_m") and len(lines) > 200
    # it ends with the state the run stopped in, as a headless run's telemetry.csv does
    assert float(lines[-1].split(",")[0]) == pytest.approx(t_stop, abs=1e-6)
    assert live.client.get("/api/telemetry", params={"format": "xml"}).status_code == 422
    metrics = live.client.get("/api/metrics")
    assert metrics.status_code == 200, metrics.text
    s = live.client.post("/api/reset").json()
    assert s["status"] == "idle" and s["t_s"] == 0.0 and s["scenario"] == "collision"


def test_a_body_over_64_kib_is_refused_with_413_and_changes_nothing(live):
    live.client.post("/api/stop")
    gen = live.state()["generation"]
    big = '{"description": "%s"}' % ("x" * 100_000)
    r = _post_raw(live, "/api/scenarios/collision/start", big)
    assert r.status_code == 413 and "64 KiB" in r.json()["detail"]

    def chunks():  # no Content-Length: the limit counts what streams in
        for _ in range(100):
            yield b" " * 1024

    r = live.client.post("/api/scenarios/collision/start", content=chunks(),
                         headers={"Content-Type": "application/json"})
    assert r.status_code == 413
    s = live.state()
    assert s["generation"] == gen and s["status"] not in ("running", "starting")
    health = live.client.get("/api/health")
    assert health.status_code == 200 and health.json()["loop_alive"]


def test_a_failing_start_reports_error_and_the_loop_lives_on(live):
    live.client.post("/api/stop")
    # a course the pre-flight passes, and an approach too short for the arm to reach it
    unreachable = {"loop": {"approach_timeout_s": 0.01}}
    r = live.client.post("/api/scenarios/free-floating/start", json=unreachable)
    assert r.status_code == 422 and "could not start" in r.json()["detail"], r.text
    s = live.state()
    assert s["status"] == "error" and "not reached" in s["reason"]
    assert live.client.get("/api/health").json()["loop_alive"]
    r = live.client.post("/api/scenarios/free-floating/start")
    assert r.status_code == 200 and r.json()["status"] == "running", r.text
    live.client.post("/api/stop")


def test_the_viewer_panels_start_settings_are_a_valid_override(live):
    """The 3D viewer's panel (viser GUI) starts a run with its fields as overrides: they
    merge into the scenario and the first satellite takes the panel's velocity."""
    scene = live.app.state.scene
    scene.gui_velocity.value = (0.02, -0.01, 0.0)
    config = live.app.state.service.config_for("collision", scene._gui_overrides())
    assert config.satellites[0].velocity_mps == pytest.approx((0.02, -0.01, 0.0))
    assert len(config.satellites) == 2


@pytest.mark.parametrize(("headers", "status", "detail"), [
    ({"Host": "evil.example"}, 400, "host 'evil.example' is not allowed"),
    ({"Host": "evil.example:8000"}, 400, "host 'evil.example:8000' is not allowed"),
    ({"Origin": "http://evil.example"}, 403, "origin 'http://evil.example' is not allowed"),
    ({"Origin": "null"}, 403, "origin 'null' is not allowed"),
])
def test_foreign_hosts_and_origins_are_refused_and_change_nothing(live, headers, status,
                                                                  detail):
    """DNS rebinding (a foreign Host) and cross-site pages (a foreign Origin) reach
    nothing: not the state, not a start."""
    live.client.post("/api/stop")
    gen = live.state()["generation"]
    for method, path in [("get", "/api/state"), ("post", "/api/scenarios/collision/start"),
                         ("post", "/api/stop")]:
        r = getattr(live.client, method)(path, headers=headers)
        assert r.status_code == status and r.json()["detail"] == detail, (path, r.text)
    assert live.state()["generation"] == gen


def test_a_same_origin_page_and_loopback_names_are_served(live):
    port = live.port
    for headers in [{"Origin": f"http://127.0.0.1:{port}"}, {"Host": f"localhost:{port}"},
                    {"Host": f"[::1]:{port}"}]:
        assert live.client.get("/api/health", headers=headers).status_code == 200, headers


def test_a_body_that_is_not_json_is_refused_before_anything_reads_it(live):
    """A cross-site form or text/plain post needs no preflight in a browser: refused."""
    live.client.post("/api/stop")
    gen = live.state()["generation"]
    for kind in ["text/plain", "application/x-www-form-urlencoded", None]:
        headers = {} if kind is None else {"Content-Type": kind}
        r = live.client.post("/api/scenarios/collision/start", content=b"{}",
                             headers=headers)
        assert r.status_code == 415, (kind, r.text)
        assert r.json()["detail"] == "a request body must be application/json"
    assert live.state()["generation"] == gen
    assert live.client.post("/api/stop").status_code == 200  # no body: no type needed


def test_a_run_can_be_taken_home_as_files_a_zip_and_a_ros_bag(live, tmp_path, monkeypatch):
    """The page's download links: the CSV and metrics of the run, a zip with everything
    (plots, config, summary) and the ROS 2 bag, all of the same (finished) run."""
    import io
    import json
    import zipfile

    live.client.post("/api/stop")
    s = live.client.post("/api/scenarios/collision/start",
                         json={"mode": "ideal", "loop": {"duration_s": 4.0}}).json()
    assert s["status"] == "running"
    live.wait_for(lambda s: s["status"] == "finished", timeout_s=60)
    csv = live.client.get("/api/telemetry").text
    metrics = live.client.get("/api/metrics").json()
    r = live.client.get("/api/run.zip")
    assert r.status_code == 200 and r.headers["content-type"] == "application/zip"
    zf = zipfile.ZipFile(io.BytesIO(r.content))
    names = set(zf.namelist())
    assert {"telemetry.csv", "metrics.json", "summary.txt", "config.json",
            "plots/fig8_forces.png", "plots/fig8b_contact_closeup.png"} <= names
    assert zf.read("telemetry.csv").decode() == csv
    in_zip = json.loads(zf.read("metrics.json"))
    assert in_zip["collision"]["restitution"] == metrics["collision"]["restitution"]
    assert in_zip["cycles"] == metrics["cycles"] == 2000
    config = json.loads(zf.read("config.json"))
    assert (config["scenario"], config["mode"]) == ("collision", "ideal")
    assert config["config"]["loop"]["duration_s"] == 4.0
    assert "restitution" in zf.read("summary.txt").decode()
    assert zf.read("plots/fig8_forces.png")[:4] == b"\x89PNG"

    r = live.client.get("/api/bag", params={"rate_hz": 50})
    assert r.status_code == 200 and r.headers["content-type"] == "application/zip"
    zipfile.ZipFile(io.BytesIO(r.content)).extractall(tmp_path)
    from rosbags.rosbag2 import Reader

    with Reader(tmp_path / "bag") as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert counts["/sat1/twist"] == counts["/sat2/ods_input"] == 201  # 4 s at 50 Hz
    assert r.headers["x-bag-rate-hz"] == "50"
    # a rate the 1 kHz loop cannot give exactly: the next lower one, never above the asked
    r = live.client.get("/api/bag", params={"rate_hz": 300})
    assert r.headers["x-bag-rate-hz"] == "250"
    # a long run's bag is thinned to the message budget: 7 messages a row (ideal: no arms)
    import app.backend.service as service_module

    monkeypatch.setattr(service_module, "MAX_BAG_MESSAGES", 7 * 4 * 25)
    r = live.client.get("/api/bag", params={"rate_hz": 1000})
    assert r.headers["x-bag-rate-hz"] == "25"
    monkeypatch.undo()
    replay = live.client.get("/api/replay.html")
    assert replay.status_code == 200 and "playbackPath" in replay.text
    for bad in ("0", "-1", "2000", "abc"):
        r = live.client.get("/api/bag", params={"rate_hz": bad})
        assert r.status_code == 422 and "rate_hz" in r.text, (bad, r.text)


def test_a_replay_taken_during_a_run_leaves_the_recording_going(live):
    """GET /api/replay.html mid-run gives the run so far and the scene keeps recording:
    a second download, later, is longer."""
    live.client.post("/api/stop")
    live.wait_for_scene()
    s = live.client.post("/api/scenarios/free-floating/start",  # drifting: frames differ
                         json={"mode": "ideal", "loop": {"duration_s": 30.0},
                               "satellites": {"0": {"velocity_mps": [0.02, 0.0, 0.0]}}}).json()
    assert s["status"] == "running"
    recorder = live.app.state.scene.replay
    live.wait_for(lambda s: s["t_s"] >= 1.0)
    first = live.client.get("/api/replay.html")
    assert first.status_code == 200 and recorder.recording
    assert recorder.current()[0] == s["generation"]
    live.wait_for(lambda s: s["t_s"] >= 3.0)
    second = live.client.get("/api/replay.html")
    assert second.status_code == 200 and recorder.recording
    assert len(second.content) > len(first.content)
    s = live.client.post("/api/stop").json()
    live.wait_for(lambda s: not recorder.recording, timeout_s=10)
    # the recording's clock is the scenario's: it lasts as long as the run did
    assert _recording_duration_s(recorder.current()[1]) == pytest.approx(s["t_s"], abs=0.1)


def _recording_duration_s(recording: bytes) -> float:
    """durationSeconds of a viser scene recording (zstd; 8-byte length, msgpack)."""
    import msgspec
    import zstandard

    inner = zstandard.ZstdDecompressor().decompress(recording[8:], max_output_size=1 << 30)
    n = int.from_bytes(inner[:8], "little")
    return msgspec.msgpack.decode(inner[8:8 + n])["durationSeconds"]


def test_a_start_whose_course_leaves_the_arm_s_reach_is_refused_before_the_arms_move(live):
    live.client.post("/api/stop")
    before = live.client.post("/api/reset").json()
    r = live.client.post("/api/scenarios/free-floating/start",
                         json={"satellites": {"0": {"velocity_mps": [0.0, 0.05, 0.0]}}})
    assert r.status_code == 422, r.text
    assert r.json()["detail"].startswith(
        "pre-flight: the ideal run predicts that robot 1 (ceiling): satellite 'cubesat' "
        "leaves the arm's reach")
    after = live.state()
    assert after["status"] == "idle" and after["generation"] == before["generation"]
    assert after["loop"]["cycles"] == 0
    # ideal mode has no arms to protect: the same course starts
    s = live.client.post("/api/scenarios/free-floating/start",
                         json={"mode": "ideal",
                               "satellites": {"0": {"velocity_mps": [0.0, 0.05, 0.0]}}}).json()
    assert s["status"] == "running" and s["mode"] == "ideal"
    live.client.post("/api/stop")


def test_a_start_whose_prediction_fails_is_refused_with_the_reason(live):
    """The pre-flight's ideal run raising is a refusal too (422 naming why), not a 500: here
    a run too long for the prediction to hold (1e8 rows at 100 Hz)."""
    live.client.post("/api/stop")
    before = live.client.post("/api/reset").json()
    r = live.client.post("/api/scenarios/gravity-stabilised/start",
                         json={"mode": "hil", "loop": {"duration_s": 1e6}})
    assert r.status_code == 422, r.text
    assert r.json()["detail"] == (
        "pre-flight: the ideal run failed: invalid configuration: loop.telemetry_capacity: "
        "Input should be less than or equal to 10000000")
    after = live.state()
    assert after["status"] == "idle" and after["generation"] == before["generation"]


def test_the_web_app_runs_a_docking_to_capture_and_its_metrics_say_so(live):
    live.client.post("/api/stop")
    s = live.client.post("/api/scenarios/docking/start", json={}).json()
    assert s["status"] == "running" and s["mode"] == "hil", s
    s = live.wait_for(lambda s: s.get("capture") is not None or s["status"] != "running",
                      timeout_s=40)
    from app.scenarios import load_scenario
    from app.sim.loop import Emulator

    ideal = Emulator(load_scenario("docking"), mode="ideal")  # when the ideal run captures
    ideal.run(load_scenario("docking").loop.duration_s)
    assert s["status"] == "running" and s["capture"]["t_s"] == pytest.approx(
        ideal.capture_event["t_s"], abs=0.1)
    live.client.post("/api/stop")
    metrics = live.client.get("/api/metrics").json()
    assert metrics["capture"]["captured"] and metrics["success"]["passed"]
    assert "similarity" in metrics["scaling"]["text"]


SHORT_COLLISION = {"satellites": {"0": {"position_m": [-0.16, 0, 0]},
                                  "1": {"position_m": [0.16, 0, 0]}},
                   "loop": {"duration_s": 1.2},
                   "uncertainty": {"replicates": 4, "forecast_replicates": 4}}
"""The shipped collision started closer: its contact at 0.74 s in a 1.2 s run."""


def test_the_forecast_before_start_and_the_interval_after_the_run(live):
    """GET .../forecast gives the pre-flight's forecast before Start (null in ideal mode,
    404 for an unknown scenario); a hil run's state carries its restitution's interval
    once it has ended, and its metrics.json the same fields."""
    t0 = time.monotonic()
    f = live.client.get("/api/scenarios/collision/forecast")
    assert f.status_code == 200, f.text
    f = f.json()
    c = f["collision_forecast"]
    assert c["restitution_sd"] > 0.0 and c["noise_force_N"] == pytest.approx(5.0 / 3.0)
    assert c["peak_to_noise"] == pytest.approx(c["peak_force_N"] / (5.0 / 3.0))
    assert 0.0 < f["wall_s"] < time.monotonic() - t0
    again = live.client.get("/api/scenarios/collision/forecast").json()
    assert again == f  # cached: the same answer at once
    ideal = live.client.get("/api/scenarios/collision/forecast", params={"mode": "ideal"})
    assert ideal.json()["collision_forecast"] is None
    assert live.client.get("/api/scenarios/nope/forecast").status_code == 404
    live.client.post("/api/stop")
    s = live.client.post("/api/scenarios/collision/start",
                         json={**SHORT_COLLISION, "mode": "hil"}).json()
    assert s["status"] == "running", s
    s = live.wait_for(lambda s: s["status"] != "running" and s["interval"] is not None, 60.0)
    i = s["interval"]
    lo, hi = i["restitution_interval_95"]
    assert lo < i["restitution"] < hi
    assert hi - lo == pytest.approx(2 * 1.959964 * i["restitution_sd"])
    assert i["uncertainty"]["replicates"] == 4
    coll = live.client.get("/api/metrics").json()["collision"]
    assert coll["restitution"] == i["restitution"]
    assert coll["restitution_interval_95"] == [lo, hi]
