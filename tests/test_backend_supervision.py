"""Supervision of the loop process (app/backend/runner.py): a dead or stalled loop is
noticed within 0.5 s, reported (health 503, state "fault") and replaced on reset or start;
no request answers 500 meanwhile."""

from __future__ import annotations

import os
import signal
import time

import pytest

from tests.live_server import LiveServer


@pytest.fixture(scope="module")
def live():
    with LiveServer() as server:
        yield server


def _loop_pid(live) -> int:
    return live.app.state.service.runner._proc.pid


def _wait_fault(live, timeout_s: float = 1.0) -> tuple[float, dict]:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout_s:
        r = live.client.get("/api/health")
        if r.status_code == 503:
            return time.monotonic() - t0, r.json()
        time.sleep(0.02)
    raise AssertionError(f"no fault reported within {timeout_s} s: {r.json()}")


def test_a_killed_loop_is_reported_then_replaced_by_a_reset(live):
    s = live.client.post("/api/scenarios/free-floating/start",
                         json={"pulses": []}).json()
    assert s["status"] == "running"
    os.kill(_loop_pid(live), signal.SIGKILL)
    _, health = _wait_fault(live)
    assert health["status"] == "fault" and "exited (code -9)" in health["reason"]
    state = live.state()
    assert state["status"] == "fault" and "exited" in state["reason"]
    for method, path, body in [("post", "/api/stop", None), ("get", "/api/metrics", None),
                               ("get", "/api/telemetry", None),
                               ("post", "/api/push", {"satellite": 1, "force_N": [0, 5, 0],
                                                      "duration_s": 0.1})]:
        r = getattr(live.client, method)(path, **({"json": body} if body else {}))
        assert r.status_code == 503, (path, r.status_code, r.text)
        assert "restarts the loop" in r.json()["detail"]
    old = _loop_pid(live)
    s = live.client.post("/api/reset").json()
    assert s["status"] == "idle" and _loop_pid(live) != old
    assert live.client.get("/api/health").json()["status"] == "ok"
    s = live.client.post("/api/scenarios/free-floating/start", json={"pulses": []}).json()
    assert s["status"] == "running"
    assert live.wait_for(lambda s: s["t_s"] > 0.3)["status"] == "running"
    live.client.post("/api/stop")


def test_a_stalled_loop_is_noticed_and_a_start_replaces_it(live):
    live.client.post("/api/stop")
    pid = _loop_pid(live)
    os.kill(pid, signal.SIGSTOP)  # alive, but no longer beating
    try:
        elapsed, health = _wait_fault(live, timeout_s=1.0)
        assert "has not answered" in health["reason"]
        assert elapsed < 1.0
        s = live.client.post("/api/scenarios/free-floating/start",
                             json={"pulses": []}).json()
        assert s["status"] == "running" and _loop_pid(live) != pid
    finally:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    assert live.client.get("/api/health").json()["status"] == "ok"
    live.client.post("/api/stop")


def test_health_turns_degraded_when_the_loop_misses_its_deadlines(live):
    live.client.post("/api/stop")
    s = live.client.post("/api/scenarios/free-floating/start", json={"pulses": []}).json()
    assert s["status"] == "running"
    time.sleep(1.0)
    health = live.client.get("/api/health").json()
    ratio = health["deadline_miss_ratio_10s"]
    assert ratio is not None and 0.0 <= ratio <= 1.0
    assert health["status"] == ("ok" if ratio <= 0.01 else "degraded")
    live.client.post("/api/stop")
    # 5 kHz: a dual-stage cycle costs more than its 200 us, most deadlines are missed
    s = live.client.post("/api/scenarios/collision/start",
                         json={"loop": {"rate_hz": 5000}}).json()
    assert s["status"] == "running"
    time.sleep(1.5)
    health = live.client.get("/api/health").json()
    assert health["deadline_miss_ratio_10s"] > 0.01
    assert health["status"] == "degraded"
    live.client.post("/api/stop")


def test_stop_interrupts_a_start_that_would_take_long(live):
    """The wedge of old: a start pose out of reach with the longest approach allowed
    (120 s of virtual time, over a second of search here). A stop sent meanwhile ends the
    start-up within 0.5 s; the loop then takes the next start as usual."""
    import threading

    live.client.post("/api/stop")
    body = {"satellites": {"0": {"position_m": [3.0, 0.0, 0.0]}},
            "loop": {"approach_timeout_s": 120.0}}
    answer = {}
    starter = threading.Thread(target=lambda: answer.update(
        r=live.client.post("/api/scenarios/free-floating/start", json=body)))
    starter.start()
    live.wait_for(lambda s: s["status"] == "starting", timeout_s=5.0)
    t0 = time.monotonic()
    assert live.client.post("/api/stop").status_code == 200
    s = live.wait_for(lambda s: s["status"] == "stopped", timeout_s=0.5)
    assert time.monotonic() - t0 < 0.5
    assert s["reason"] == "stopped by the operator during start-up"
    starter.join(timeout=5.0)
    assert not starter.is_alive() and answer["r"].status_code == 200
    assert answer["r"].json()["status"] == "stopped"
    r = live.client.post("/api/scenarios/free-floating/start")
    assert r.status_code == 200 and r.json()["status"] == "running", r.text
    live.client.post("/api/stop")
