"""`orbit-emulator sweep` end to end on Ray, through the installed console script: rows equal
to single `run`s, failures and a killed worker as rows, --resume, a Ray head started here
(--address), Ctrl+C, sweep-plot. Every Ray is this test's own and is stopped by it (the
local one by the sweep itself); all traffic stays on this machine."""

from __future__ import annotations

import csv
import json
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from app.campaign.sweep import METRIC_FIELDS, TIMING_METRICS

EXE = shutil.which("orbit-emulator") or f"{sys.prefix}/bin/orbit-emulator"
RAY = shutil.which("ray") or f"{sys.prefix}/bin/ray"
ENV = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "RAY_AUTH_MODE": "token",
       "RAY_AUTH_TOKEN": secrets.token_hex(32)}
"""A token of this test's own: the head and the sweeps use it, whatever ~/.ray holds."""

METRICS = ["collision.restitution", "collision.restitution_error", "collision.peak_force_N",
           "satellites.0.position_error_max_m", "satellites.1.velocity_error_rms_mps",
           "safety_stop.t_s", "realtime_factor"]
SPEC4 = f"""
scenario = "collision"
mode = "hil"
duration_s = 3.5
seeds = [0, 1]
metrics = {json.dumps(METRICS)}

[grid]   # 0.05: the collision; 1e-5: a safety stop at the first cycle
"loop.max_tracking_error_m" = [0.05, 1e-5]
"""


def sweep(cwd: Path, *args, timeout=180, check=True) -> subprocess.CompletedProcess:
    proc = subprocess.run([EXE, "sweep", *args, "--quiet"], capture_output=True, text=True,
                          timeout=timeout, cwd=cwd, env=ENV, start_new_session=True)
    if check:
        assert proc.returncode == 0, proc.stderr
        assert "Traceback" not in proc.stderr
    return proc


def read_rows(out: Path) -> list[dict]:
    with open(out / "results.csv", newline="") as f:
        return list(csv.DictReader(f))


def deterministic(metrics: dict) -> dict:
    return {k: v for k, v in metrics.items() if k not in TIMING_METRICS}


@pytest.fixture(scope="module")
def swept(tmp_path_factory) -> Path:
    """The 4-run sweep on local Ray: 2 settings x 2 seeds."""
    here = tmp_path_factory.mktemp("sweep4")
    (here / "spec.toml").write_text(SPEC4)
    proc = sweep(here, "spec.toml", "--out", "out")
    assert "4 of 4 runs in out/results.csv: 2 finished, 2 safety_stop" in proc.stdout
    return here / "out"


def test_the_rows_are_those_of_single_runs(swept, tmp_path):
    """Each row (and its kept metrics.json) is what `orbit-emulator run` gives for that
    setting and seed; the ideal reference ran once per setting, not once per seed."""
    rows = read_rows(swept)
    assert sorted((r["loop.max_tracking_error_m"], r["seed"]) for r in rows) == [
        ("0.05", "0"), ("0.05", "1"), ("1e-05", "0"), ("1e-05", "1")]

    def single(row):
        out = tmp_path / row["run_id"]
        proc = subprocess.run(
            [EXE, "run", "collision", "--mode", "hil", "--duration", "3.5", "--seed",
             row["seed"], "--set", f"loop.max_tracking_error_m={row['loop.max_tracking_error_m']}",
             "--out", str(out), "--quiet"], capture_output=True, text=True, timeout=180)
        assert proc.returncode == (0 if row["status"] == "finished" else 3), proc.stderr
        return json.loads((out / "metrics.json").read_text())

    with ThreadPoolExecutor(2) as pool:
        singles = list(pool.map(single, rows))
    for row, metrics in zip(rows, singles, strict=True):
        kept = json.loads((swept / "runs" / row["run_id"] / "metrics.json").read_text())
        assert deterministic(kept) == deterministic(metrics)
        assert row["status"] == metrics["status"]
        for path in METRICS[:-1]:
            node = metrics
            for part in path.split("."):
                node = node[int(part)] if isinstance(node, list) else (node or {}).get(part)
            assert row[path] == ("" if node is None else repr(node)), path
        assert float(row["realtime_factor"]) > 0 or row["status"] == "safety_stop"
    finished = [r for r in rows if r["status"] == "finished"]
    assert len(finished) == 2 and all(float(r["collision.restitution"]) > 0 for r in finished)
    stops = [r for r in rows if r["status"] == "safety_stop"]
    # (the arm ran up to its satellite's 8 cm/s before t = 0: its 0.2 mm of lag trips the
    # 0.01 mm limit at the first cycle, before the ODS steps)
    assert all(r["reason"].startswith("robot 1 at t = 0.000 s: tracking error: position")
               for r in stops)
    summary = json.loads((swept / "summary.json").read_text())
    assert summary["counts"] == {"finished": 2, "safety_stop": 2, "error": 0, "lost": 0}
    assert (summary["ran"], summary["ideal_runs"], summary["workers"]) == (4, 2, 2)
    # both ideal runs were started before any run waited for one: the first in a process
    # of its own while Ray started, the second ahead of its runs on a worker
    assert (summary["ideal_runs_apart"], summary["ideal_runs_ahead"]) == (1, 1)
    assert 50 < summary["worker_rss_peak_MiB"] < 2048


def test_the_metric_fields_a_spec_is_checked_against_are_those_of_metrics_json(swept):
    row = next(r for r in read_rows(swept) if r["status"] == "finished")
    metrics = json.loads((swept / "runs" / row["run_id"] / "metrics.json").read_text())
    assert tuple(metrics) == METRIC_FIELDS[""]
    assert tuple(metrics["satellites"][0]) == METRIC_FIELDS["satellites"]
    assert tuple(metrics["robots"][0]) == METRIC_FIELDS["robots"]
    assert tuple(metrics["collision"]) == METRIC_FIELDS["collision"]
    assert tuple(metrics["cycle_time_us"]) == METRIC_FIELDS["cycle_time_us"]
    if metrics["collision_forecast"] is not None:
        assert set(metrics["collision_forecast"]) <= set(METRIC_FIELDS["collision_forecast"])


def test_resume_of_a_whole_table_runs_nothing(swept, tmp_path):
    shutil.copytree(swept, tmp_path / "out")
    before = (tmp_path / "out" / "results.csv").read_text()
    (tmp_path / "spec.toml").write_text(SPEC4)
    t0 = time.perf_counter()
    proc = sweep(tmp_path, "spec.toml", "--out", "out", "--resume")
    assert time.perf_counter() - t0 < 15  # no Ray started
    assert "this time: 0 run(s)" in proc.stdout and "4 already in the table" in proc.stdout
    assert (tmp_path / "out" / "results.csv").read_text() == before
    proc = sweep(tmp_path, "spec.toml", "--out", "out", check=False)
    assert proc.returncode == 2 and "--resume continues that sweep" in proc.stderr


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def ray_head(tmp_path):
    """A Ray head of this test's own (`ray start --head --block`, its own process group),
    stopped by its process group afterwards, whatever happened."""
    port = _free_port()
    log = open(tmp_path / "head.log", "w")  # noqa: SIM115 - closed below
    head = subprocess.Popen(
        [RAY, "start", "--head", f"--port={port}", "--num-cpus=2", "--include-dashboard=false",
         "--disable-usage-stats", "--block"], stdout=log, stderr=subprocess.STDOUT, env=ENV,
        start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        while "Ray runtime started" not in (tmp_path / "head.log").read_text():
            assert head.poll() is None and time.monotonic() < deadline, \
                (tmp_path / "head.log").read_text()
            time.sleep(0.3)
        yield f"127.0.0.1:{port}"
    finally:
        _stop_group(head)
        log.close()


def _stop_group(proc: subprocess.Popen) -> None:
    """SIGTERM to `ray start --block`, which stops what it started; SIGKILL to whatever of
    the process group this test started is left after that."""
    proc.terminate()
    try:
        proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        pass
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline:
        try:
            os.killpg(proc.pid, 0)
        except ProcessLookupError:
            return
        time.sleep(0.2)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(timeout=10)


def test_a_sweep_joins_a_ray_head_and_resumes_the_runs_it_lacks(swept, ray_head, tmp_path):
    """--address: the runs go to the head started here; --resume runs only the two runs
    taken out of the table, and they come back equal."""
    shutil.copytree(swept, tmp_path / "out")
    rows = read_rows(swept)
    with open(tmp_path / "out" / "results.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows[:2])
    (tmp_path / "spec.toml").write_text(SPEC4)
    proc = sweep(tmp_path, "spec.toml", "--out", "out", "--resume", "--address", ray_head)
    assert "this time: 2 run(s)" in proc.stdout and "2 already in the table" in proc.stdout
    again = read_rows(tmp_path / "out")
    assert [r["run_id"] for r in again[:2]] == [r["run_id"] for r in rows[:2]]
    assert sorted(r["run_id"] for r in again) == sorted(r["run_id"] for r in rows)  # no twice
    by_id = {r["run_id"]: r for r in rows}
    for r in again[2:]:
        old = by_id[r["run_id"]]
        for key in ("seed", "loop.max_tracking_error_m", "status", "reason", *METRICS[:-1]):
            assert r[key] == old[key], key
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert (summary["address"], summary["ran"], summary["skipped"]) == (ray_head, 2, 2)


def _descendants(pid: int) -> list[int]:
    """The processes under pid (from /proc)."""
    children: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            children.setdefault(ppid, []).append(int(entry.name))
    out, todo = [], [pid]
    while todo:
        for c in children.get(todo.pop(), []):
            out.append(c)
            todo.append(c)
    return out


def _cmdline(pid: int) -> str:
    try:
        return (Path("/proc") / str(pid) / "cmdline").read_text().replace("\0", " ")
    except OSError:
        return ""


def _wait_for(predicate, timeout_s: float, what: str):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def test_a_failing_run_and_a_killed_worker_are_rows_not_a_crashed_sweep(tmp_path):
    """A run that raises (its start pose is not found within 0.01 s) is a row with its
    reason, as `run` reports it; a worker killed in the middle of a run is retried. The
    runs last 10 s of emulation, about a second of a quiet machine's time (at 3 s, with
    the kernels compiled, a run could end before it had been under way 0.3 s)."""
    (tmp_path / "spec.toml").write_text("""
scenario = "collision"
duration_s = 10.0
seeds = [0, 1]
metrics = ["satellites.0.position_error_max_m"]
[grid]
"loop.approach_timeout_s" = [20.0, 0.01]
""")
    proc = subprocess.Popen([EXE, "sweep", "spec.toml", "--out", "out", "--quiet"],
                            cwd=tmp_path, env=ENV, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        busy_since: dict[int, float] = {}

        def long_running_task():
            """A worker busy with one run for 0.3 s already: a long one (the failing
            runs end in milliseconds), so that the kill lands in its middle, never as
            it completes (Ray 2.60's core can abort on a reply racing the kill)."""
            now = time.monotonic()
            busy = {p for p in _descendants(proc.pid) if "ray::execute_run" in _cmdline(p)}
            for pid in list(busy_since):
                if pid not in busy:
                    del busy_since[pid]
            for pid in busy:
                busy_since.setdefault(pid, now)
            return [pid for pid, t0 in busy_since.items() if now - t0 >= 0.3]

        killed = _wait_for(long_running_task, 90, "a run under way")[0]
        os.kill(killed, signal.SIGKILL)
        out, err = proc.communicate(timeout=180)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 4, err  # runs ended in error: the sweep says so
    assert err.splitlines()[-1] == ("error: 2 run(s) ended in error and 0 were lost (of 4): "
                                    "their reasons are in out/results.csv")
    rows = {(r["loop.approach_timeout_s"], r["seed"]): r for r in read_rows(tmp_path / "out")}
    assert len(rows) == 4
    for seed in ("0", "1"):
        assert rows[("20.0", seed)]["status"] == "finished"
        assert rows[("20.0", seed)]["worker"] != f"{socket.gethostname()}:{killed}"
        bad = rows[("0.01", seed)]
        assert (bad["status"], bad["satellites.0.position_error_max_m"]) == ("error", "")
        assert bad["reason"].startswith("StartPoseError: robot 1: start pose of satellite "
                                        "'cubesat' not reached")
    single = subprocess.run([EXE, "run", "collision", "--duration", "3", "--set",
                             "loop.approach_timeout_s=0.01", "--out", str(tmp_path / "one"),
                             "--quiet"], capture_output=True, text=True, timeout=120)
    assert single.returncode == 2
    assert single.stderr.splitlines()[-1] == "error: " + bad["reason"].split(": ", 1)[1]


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
def test_ctrl_c_stops_the_sweep_and_keeps_the_rows(stop, tmp_path):
    """Ctrl+C, or a scheduler's SIGTERM: the runs under way are cancelled, the rows kept."""
    (tmp_path / "spec.toml").write_text("""
scenario = "collision"
duration_s = 1.0
seeds = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9]
metrics = ["satellites.0.position_error_max_m"]
""")
    proc = subprocess.Popen([EXE, "sweep", "spec.toml", "--out", "out", "--quiet"],
                            cwd=tmp_path, env=ENV, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    table = tmp_path / "out" / "results.csv"
    try:
        _wait_for(lambda: table.exists() and len(table.read_text().splitlines()) >= 2, 120,
                  "the first row")
        under = _descendants(proc.pid)
        assert under  # Ray's processes
        proc.send_signal(stop)
        t0 = time.perf_counter()
        out, err = proc.communicate(timeout=60)
        assert time.perf_counter() - t0 < 30
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, err
    assert "interrupted: the runs that ended are in out/results.csv" in err
    rows = read_rows(tmp_path / "out")
    assert 1 <= len(rows) < 10 and all(r["status"] == "finished" for r in rows)
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["interrupted"] and summary["rows"] == len(rows)
    _wait_for(lambda: not [p for p in under if Path(f"/proc/{p}").exists()
                           and "zombie" not in _state(p)], 30, "Ray's processes to end")


@pytest.mark.parametrize("when", ["raylet", "agent"])
def test_a_sigterm_while_ray_starts_ends_the_sweep_as_interrupted_and_leaves_nothing(
        when, tmp_path):
    """A scheduler's SIGTERM while ray.init is still starting Ray's processes (as soon as
    the raylet, or one of its agents, is up): the sweep ends as interrupted (130, not
    Ray's own exit 15 or an abort), says that no run had ended, and every process Ray
    had started ends with it (none is left to init)."""
    (tmp_path / "spec.toml").write_text("""
scenario = "free-floating-scripted"
duration_s = 0.5
seeds = [0, 1]
metrics = ["realtime_factor"]
""")
    proc = subprocess.Popen([EXE, "sweep", "spec.toml", "--out", "out", "--quiet"],
                            cwd=tmp_path, env=ENV, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    seen: set[int] = set()

    def up(cmdline: str) -> bool:  # an agent names itself ray::DashboardAgent and the like
        return ("/raylet" in cmdline if when == "raylet"
                else cmdline.startswith("ray::") and "Agent" in cmdline)

    def started():
        seen.update(_descendants(proc.pid))
        return any(up(_cmdline(p)) for p in seen)

    try:
        _wait_for(started, 120, f"Ray's {when}")
        proc.send_signal(signal.SIGTERM)
        while proc.poll() is None:
            seen.update(_descendants(proc.pid))
            time.sleep(0.05)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, err
    assert err.splitlines()[-1] == "interrupted: no run had ended"
    assert not (tmp_path / "out" / "results.csv").exists()
    _wait_for(lambda: not [p for p in seen if Path(f"/proc/{p}").exists()
                           and "zombie" not in _state(p)], 30, "Ray's processes to end")


def _state(pid: int) -> str:
    try:
        return (Path("/proc") / str(pid) / "status").read_text().split("State:")[1].split("\n")[0]
    except (OSError, IndexError):
        return "zombie"


def test_sweep_plot_of_a_sweep(swept, tmp_path):
    proc = subprocess.run([EXE, "sweep-plot", str(swept), "--x", "loop.max_tracking_error_m",
                           "--metric", "satellites.0.position_error_max_m", "--out",
                           str(tmp_path / "p.png")], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "p.png").read_bytes()[:4] == b"\x89PNG"


def test_an_infinite_metric_leaves_the_sweep_going(tmp_path):
    """An infinite metric (a satellite's delta-v past float range) is null in the run's
    metrics.json and inf in the table; the sweep ends with both rows and its summary."""
    (tmp_path / "spec.toml").write_text("""
scenario = "collision"
mode = "ideal"
duration_s = 0.5
seeds = [0]
metrics = ["satellites.0.delta_v_mps", "cycles"]
[grid]
"satellites.0.velocity_mps" = [[0.05, 0.0, 0.0], [1e300, 0.0, 0.0]]
""")
    sweep(tmp_path, "spec.toml", "--out", "out")
    out = tmp_path / "out"
    rows = read_rows(out)
    assert [r["status"] for r in rows] == ["finished", "finished"]
    values = sorted(r["satellites.0.delta_v_mps"] for r in rows)
    assert values[1] == "inf" and float(values[0]) < 1.0
    for row in rows:
        metrics = json.loads((out / "runs" / row["run_id"] / "metrics.json").read_text(),
                             parse_constant=lambda name: pytest.fail(f"{name} in JSON"))
        assert metrics["status"] == "finished"
    assert json.loads((out / "summary.json").read_text())["counts"] == {
        "finished": 2, "safety_stop": 0, "error": 0, "lost": 0}


def test_a_sweep_whose_runs_end_in_error_exits_4_and_counts_them(tmp_path):
    """Draws outside a setting's range (a negative noise) are runs that end in error: the
    sweep goes on, then exits 4 and says how many (exit 0 only when none did)."""
    (tmp_path / "spec.toml").write_text("""
scenario = "collision"
mode = "ideal"
duration_s = 0.2
draws = 4
metrics = ["cycles"]
[random]
"sensor.noise_force_N" = { normal = [0, 1] }
""")
    proc = sweep(tmp_path, "spec.toml", "--out", "out", check=False)
    rows = read_rows(tmp_path / "out")
    bad = [r for r in rows if r["status"] == "error"]
    assert len(rows) == 4 and 0 < len(bad) < 4, rows  # seeds 0..3: some draws negative
    assert all("sensor.noise_force_N" in r["reason"] for r in bad)
    assert proc.returncode == 4, proc.stderr
    assert proc.stderr.splitlines()[-1] == (
        f"error: {len(bad)} run(s) ended in error and 0 were lost (of 4): their reasons are "
        f"in out/results.csv")
    assert "Traceback" not in proc.stderr
