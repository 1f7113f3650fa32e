"""Supervision of the loop process (app/backend/runner.py): a dead or stalled loop is
noticed within 0.5 s, reported (health 503, state and metrics "fault") and replaced on
reset or start; a stall that ends gives control back; no request answers 500 meanwhile."""

from __future__ import annotations

import io
import json
import os
import signal
import time
import zipfile
from pathlib import Path

import pytest

from tests.live_server import LiveServer


@pytest.fixture(scope="module")
def live():
    with LiveServer() as server:
        yield server


def _cpu_times() -> tuple[int, int]:
    """(all, stolen) CPU time of this machine in jiffies (/proc/stat)."""
    fields = [int(x) for x in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    return sum(fields[:8]), fields[7]


def _loop_pid(live) -> int:
    return live.app.state.service.runner._proc.pid


def _reap(pid: int) -> None:
    """Kill a loop process the test stalled or killed, if it is still there."""
    try:
        os.kill(pid, signal.SIGKILL)
    except ProcessLookupError:
        pass


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
    live.wait_for(lambda s: s["t_s"] > 0.1)
    os.kill(_loop_pid(live), signal.SIGKILL)
    _, health = _wait_fault(live)
    assert health["status"] == "fault" and "exited (code -9)" in health["reason"]
    state = live.state()
    assert state["status"] == "fault" and "exited" in state["reason"]
    for method, path, body in [("post", "/api/stop", None),
                               ("post", "/api/push", {"satellite": 1, "force_N": [0, 5, 0],
                                                      "duration_s": 0.1})]:
        r = getattr(live.client, method)(path, **({"json": body} if body else {}))
        assert r.status_code == 503, (path, r.status_code, r.text)
        assert "restarts the loop" in r.json()["detail"]
    # what the dead loop recorded is still there (the ring lives in the web process)
    r = live.client.get("/api/telemetry")
    assert r.status_code == 200 and len(r.text.splitlines()) > 50  # 0.1 s at 500 Hz
    m = live.client.get("/api/metrics").json()  # a crashed run is not "running"
    assert m["status"] == "fault" and m["duration_s"] > 0.0 and m["cycles"] > 0
    assert m["error"] == "the loop process exited (code -9), killed by SIGKILL"
    with zipfile.ZipFile(io.BytesIO(live.client.get("/api/run.zip").content)) as zf:
        archived = json.loads(zf.read("metrics.json"))
    assert (archived["status"], archived["error"]) == ("fault", m["error"])
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
        _reap(pid)
    assert live.client.get("/api/health").json()["status"] == "ok"
    live.client.post("/api/stop")


def test_a_stall_that_ends_gives_control_back_within_a_second(live):
    """A VM pause or a swap storm: the loop process stops for 0.7 s, then runs on. While
    stalled it is a fault (health 503, state and metrics "fault"); once it beats again the
    fault is over, with no reset: health is ok again and says how long the stall lasted,
    the run goes on, and a stop sent after it works within 1 s of the SIGCONT."""
    live.client.post("/api/reset")
    s = live.client.post("/api/scenarios/free-floating/start", json={"pulses": []}).json()
    assert s["status"] == "running"
    live.wait_for(lambda s: s["t_s"] > 0.2)
    pid = _loop_pid(live)
    stopped_at = time.monotonic()
    os.kill(pid, signal.SIGSTOP)
    try:
        _wait_fault(live)
        m = live.client.get("/api/metrics").json()
        assert m["status"] == "fault" and "has not answered" in m["error"]
        time.sleep(max(0.0, stopped_at + 0.7 - time.monotonic()))
    finally:
        os.kill(pid, signal.SIGCONT)
    resumed = time.monotonic()
    answers = []
    while time.monotonic() - resumed < 3.0:
        r = live.client.post("/api/stop")
        answers.append(r.status_code)
        if r.status_code == 200:
            break
    took_s = time.monotonic() - resumed
    print(f"\nstop after a 0.7 s stall: 200 after {took_s:.3f} s ({answers})")
    assert answers[-1] == 200 and r.json()["status"] == "stopped", answers
    assert took_s < 1.0
    assert _loop_pid(live) == pid  # the same process: control came back, nothing replaced
    health = live.client.get("/api/health").json()
    assert health["status"] in ("ok", "degraded") and health["last_stall_s"] >= 0.5
    assert live.client.get("/api/metrics").json()["status"] == "stopped"


def test_a_stop_during_a_stall_is_queued_and_ends_the_run_when_the_loop_runs_again(live):
    """The operator presses stop while the loop is stalled: 202, the stop waits in the
    pipe, and the loop takes it first when it runs again: the run never goes on after a
    stop it was sent."""
    live.client.post("/api/reset")
    s = live.client.post("/api/scenarios/free-floating/start", json={"pulses": []}).json()
    assert s["status"] == "running"
    live.wait_for(lambda s: s["t_s"] > 0.2)
    pid = _loop_pid(live)
    os.kill(pid, signal.SIGSTOP)
    try:
        _wait_fault(live)
        r = live.client.post("/api/stop")
        assert r.status_code == 202, r.text
        assert r.json()["status"] == "fault"
        assert "the stop is queued and ends the run as soon as the loop runs again" in (
            r.json()["detail"])
        t_stalled = r.json()["t_s"]
    finally:
        os.kill(pid, signal.SIGCONT)
    s = live.wait_for(lambda s: s["status"] == "stopped", timeout_s=1.0)
    assert s["reason"] == "stopped by the operator"
    assert s["t_s"] - t_stalled < 0.1  # a few cycles at most after the SIGCONT
    assert _loop_pid(live) == pid


@pytest.mark.parametrize("sig", [signal.SIGSTOP, signal.SIGKILL], ids=["stalled", "killed"])
def test_a_hil_start_that_replaces_a_faulted_loop_is_pre_flighted(live, sig):
    """A stalled or dead loop still shows its last status ("running"): a hil start in its
    place is pre-flighted all the same, refused as on an idle server (422, the same
    reason), and the faulted loop is left as it was (nothing replaced, nothing moved)."""
    spin = {"mode": "hil", "satellites": {"0": {"omega_radps": [0, 0, 0.004]}}}
    live.client.post("/api/reset")
    idle = live.client.post("/api/scenarios/gravity-stabilised/start", json=spin)
    assert idle.status_code == 422, idle.text
    assert idle.json()["detail"].startswith("pre-flight: the ideal run predicts that robot 1")
    assert "turns faster than the arm's wrist" in idle.json()["detail"]
    s = live.client.post("/api/scenarios/free-floating/start",
                         json={"mode": "ideal", "loop": {"duration_s": 600}}).json()
    assert s["status"] == "running"
    pid = _loop_pid(live)
    os.kill(pid, sig)
    try:
        _wait_fault(live)
        r = live.client.post("/api/scenarios/gravity-stabilised/start", json=spin)
        assert (r.status_code, r.json()) == (422, idle.json())
        assert _loop_pid(live) == pid
        assert live.client.get("/api/health").status_code == 503
    finally:
        _reap(pid)
    assert live.client.post("/api/reset").json()["status"] == "idle"


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
    """A start-up that takes long (the longest calibration allowed, 60 s of virtual time:
    most of a second here; a start pose the arm could not take once searched for longer,
    but the pre-flight now refuses such a pose). A stop sent meanwhile ends the start-up
    within 0.5 s; the loop then takes the next start as usual."""
    import threading

    live.client.post("/api/stop")
    body = {"mode": "hil", "wrench": {"calibration_s": 60.0}}
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
    assert not starter.is_alive()
    assert (answer["r"].status_code, answer["r"].json()) == (409, {
        "detail": "scenario 'free-floating' did not start: stopped by the operator during "
                  "start-up"})
    r = live.client.post("/api/scenarios/free-floating/start")
    assert r.status_code == 200 and r.json()["status"] == "running", r.text
    live.client.post("/api/stop")


def _window(live, seconds: float, action=None) -> tuple[int, int, float]:
    """(deadlines missed, cycles, host steal share) of the loop over a window, while
    ``action(stop_at)`` runs (None: nothing)."""
    s0, cpu0 = live.state(), _cpu_times()
    stop_at = time.monotonic() + seconds
    if action is None:
        time.sleep(seconds)
    else:
        action(stop_at)
    s1, cpu1 = live.state(), _cpu_times()
    steal = (cpu1[1] - cpu0[1]) / max(1, cpu1[0] - cpu0[0])
    return (s1["loop"]["deadline_misses"] - s0["loop"]["deadline_misses"],
            s1["loop"]["cycles"] - s0["loop"]["cycles"], steal)


def test_clients_reading_metrics_and_telemetry_cost_the_loop_nothing(live):
    """8 clients polling metrics and the telemetry CSV for 3 s of a collision run: the
    reads are computed in the web process from the shared telemetry ring, and the loop
    misses far fewer deadlines than the 31 % it missed when it answered the reads itself.
    The VM's host takes CPU time away in bursts (steal in /proc/stat), which makes the
    loop miss deadlines with no reader at all: the baseline is the worse of the quiet
    window and twice the steal."""
    import threading

    import httpx

    live.client.post("/api/stop")
    s = live.client.post("/api/scenarios/collision/start").json()
    assert s["status"] == "running"
    live.wait_for(lambda s: s["t_s"] > 0.5)
    answers = []

    def poll(path, stop_at):
        with httpx.Client(base_url=live.url, timeout=30.0) as client:
            while time.monotonic() < stop_at:
                answers.append(client.get(path).status_code)

    def readers(stop_at):
        threads = [threading.Thread(target=poll, args=(p, stop_at))
                   for p in ["/api/metrics", "/api/telemetry"] * 4]
        for t in threads:
            t.start()
        for t in threads:
            t.join(timeout=60.0)

    quiet = _window(live, 3.0)
    busy = _window(live, 3.0, readers)
    assert live.state()["status"] == "running"
    assert len(answers) >= 8 and set(answers) == {200}
    print(f"\n3 s quiet: {quiet[0]} of {quiet[1]} deadlines missed (steal "
          f"{100 * quiet[2]:.1f} %); 3 s with 8 readers ({len(answers)} reads): {busy[0]} of "
          f"{busy[1]} (steal {100 * busy[2]:.1f} %)")
    assert quiet[1] > 1000 and busy[1] > 1000
    baseline = max(quiet[0] / quiet[1], 2.0 * busy[2])
    # alone: no more than the quiet window; late in the full suite on this 2-core VM up
    # to 4.7 % (README): far from the 31 % of reads answered by the loop, not yet the 1 %
    assert busy[0] / busy[1] < baseline + 0.06, (quiet, busy)
    live.client.post("/api/stop")


def test_a_start_too_large_for_the_pipe_to_a_stalled_loop_does_not_wedge_the_server(live):
    """1000 pulses pickle to more than the pipe's 64 KiB: to a stopped loop the send would
    block the request, and with it (through the state lock) health and reset."""
    live.client.post("/api/reset")
    pulses = [{"satellite": "cubesat", "start_s": k + 0.5, "end_s": k + 1.0}
              for k in range(1000)]
    pid = _loop_pid(live)
    os.kill(pid, signal.SIGSTOP)
    try:
        t0 = time.monotonic()
        r = live.client.post("/api/scenarios/collision/start",  # (ideal: no pre-flight)
                             json={"pulses": pulses, "mode": "ideal"}, timeout=10)
        assert time.monotonic() - t0 < 3.0, "the start blocked"
        assert r.status_code in (200, 503), r.text  # 200: noticed first and replaced
        t0 = time.monotonic()
        live.client.get("/api/health", timeout=5)
        assert time.monotonic() - t0 < 1.0, "health blocked"
    finally:
        _reap(pid)  # (503: the loop that did not take the start was killed already)
    assert live.client.post("/api/reset").json()["status"] == "idle"
    s = live.client.post("/api/scenarios/free-floating/start", json={"pulses": []}).json()
    assert s.get("status") == "running", s
    live.client.post("/api/stop")


def test_a_long_start_up_keeps_the_heartbeat(live):
    """A 20 s bias calibration (40,000 rest readings) and the lag identification are
    start-up work, not a stall: no fault, and the run starts."""
    live.client.post("/api/reset")
    s = live.client.post("/api/scenarios/collision/start",
                         json={"wrench": {"calibration_s": 20.0}}).json()
    assert s["status"] == "running", s
    assert live.client.get("/api/health").json()["status"] in ("ok", "degraded")
    live.client.post("/api/stop")


def test_resets_at_once_each_get_their_own_telemetry_ring(live):
    """Four resets in flight before the loop reaches the first: each its own generation
    and ring, none released before the loop opened it (it answered FileNotFoundError)."""
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(4) as pool:
        states = list(pool.map(lambda _: live.client.post("/api/reset").json(), range(4)))
    for s in states:
        assert s["status"] == "idle", s
    s = live.client.post("/api/scenarios/free-floating/start", json={"pulses": []}).json()
    assert s["status"] == "running", s
    live.wait_for(lambda s: s["t_s"] > 0.2)
    assert len(live.client.get("/api/telemetry").text.splitlines()) > 50
    live.client.post("/api/stop")


def test_the_miss_ratio_counts_only_the_latest_run_in_its_window():
    from app.backend.runner import miss_ratio_of

    # (time_s, generation, cycles, misses): run 1 missed most deadlines, run 2 none
    samples = [(0.0, 1, 0, 0), (1.0, 1, 5000, 4500), (2.0, 2, 100, 0), (9.0, 2, 7100, 0)]
    assert miss_ratio_of(samples, 10.0) == 0.0  # not (0 - 4500) / (7100 - 0)
    samples.append((10.0, 2, 8100, 81))
    assert miss_ratio_of(samples, 10.0) == 81 / 8000
    assert miss_ratio_of(samples, 0.5) is None  # one sample in the window: no cycles seen
    assert miss_ratio_of([(0.0, 1, 10, 5), (0.1, 1, 20, 10)], 10.0) == 0.5
    assert miss_ratio_of([], 10.0) is None


def test_a_loop_killed_by_sigbus_is_reported_with_the_likely_cause(live):
    """SIGBUS is how a loop dies when /dev/shm cannot give its telemetry ring a page (a
    start is refused when its ring does not fit: tests/test_backend_ring.py); should it
    still happen, health names it and what to do."""
    s = live.client.post("/api/scenarios/free-floating/start", json={"pulses": []}).json()
    assert s["status"] == "running"
    pid = _loop_pid(live)
    os.kill(pid, signal.SIGBUS)
    _, health = _wait_fault(live)
    assert health["reason"] == (
        "the loop process exited (code -7), killed by SIGBUS: a bus error, which here means "
        "the shared memory in /dev/shm (where the telemetry ring lives) ran out; give it "
        "more room (docker run --shm-size=1g) or lower loop.telemetry_capacity")
    assert live.client.post("/api/reset").json()["status"] == "idle"
    assert live.client.get("/api/health").json()["status"] == "ok"


def test_a_command_waits_for_a_slow_sender_while_the_loop_beats_not_for_a_stalled_one():
    """Runner._delivered: a message not yet handed to the pipe after SEND_TIMEOUT_S is a
    stalled loop's only if the loop ran no cycle meanwhile (its heartbeat still); while it
    beats (a loaded machine: the web's sender thread waits for the CPU), it waits on, up
    to SEND_PATIENCE_S. The full suite on a loaded VM once killed a running loop so."""
    import threading
    from types import SimpleNamespace

    from app.backend import runner, snapshots

    shm = SimpleNamespace(buf=bytearray(4096))
    done, stop = threading.Event(), threading.Event()

    def loop_beating():
        count = 0
        while not stop.wait(0.05):
            count += 1
            snapshots.beat(shm.buf, count)

    beating = threading.Thread(target=loop_beating)
    beating.start()
    threading.Timer(2.5, done.set).start()  # handed over after 2.5 s
    try:
        t0 = time.monotonic()
        assert runner.Runner._delivered(done, shm)
        assert 2.4 < time.monotonic() - t0 < 3.5
    finally:
        stop.set()
        beating.join()
    t0 = time.monotonic()
    assert not runner.Runner._delivered(threading.Event(), shm)  # no beat: stalled
    assert runner.SEND_TIMEOUT_S <= time.monotonic() - t0 < runner.SEND_TIMEOUT_S + 0.5
    assert not runner.Runner._delivered(threading.Event(), None)  # no loop at all
