"""The replicates side by side (app/runs/replicate_pool.py): the same results bit for bit as
one after the other, the heartbeat kept, and a worker that dies costs nothing but time."""

from __future__ import annotations

import os
import signal

import pytest

from app.runs.replicate_pool import run_replicates
from app.runs.uncertainty import _rng, measured_noise, restitution_spread, snapshot_time_s
from app.sim.loop import Emulator
from tests.runs.test_uncertainty import short_collision


@pytest.fixture(scope="module")
def run():
    """A hil run of the short collision, with its snapshot 0.1 s before the contact."""
    config = short_collision()
    em = Emulator(config)
    em.snapshot_at_s = snapshot_time_s(config, {"contact_start_s": 0.74})
    em.run(config.loop.duration_s)
    return em


def test_replicates_in_two_processes_are_those_run_here_bit_for_bit(run):
    """Six replicates with fresh noise: their restitutions and the spread of the velocities
    after the contact, here and in two forked processes, equal to the last bit; the
    heartbeat is called once per replicate either way."""
    noise = measured_noise(run)
    ticks = {1: 0, 2: 0}
    spreads = {}
    for processes in (1, 2):
        def tick(processes=processes):
            ticks[processes] += 1
        spreads[processes] = restitution_spread(
            run.snapshot, (1, 2), run.t_s, noise, 6, _rng(run.config, 1), tick,
            processes=processes)
    here, apart = spreads[1], spreads[2]
    assert here["replicates_with_restitution"] == 6
    assert len(set(here["restitutions"])) == 6  # the draws differ from replicate to replicate
    assert apart["restitutions"] == here["restitutions"]
    assert apart["velocity_sd_mps"] == here["velocity_sd_mps"]
    assert apart["restitution_sd"] == here["restitution_sd"]
    assert ticks == {1: 6, 2: 6}


def _square_or_die(parent_pid: int, draw: int, noise) -> int:
    """draw², but a forked worker asked for 3 dies as an out-of-memory kill would end it."""
    if draw == 3 and os.getpid() != parent_pid:
        os._exit(9)
    return draw * draw


def test_a_worker_that_dies_leaves_the_same_results_computed_here():
    """The pool breaks (a worker exits mid-task); every replicate is run here instead, in
    order: nothing is lost and nothing hangs."""
    draws = list(range(8))
    got = run_replicates(_square_or_die, (os.getpid(),), None, draws, processes=2)
    assert got == [d * d for d in draws]


def test_one_process_or_one_replicate_runs_here():
    """With one process (a sweep's worker, the web app's loop) nothing is forked: a
    function that would die in a worker runs to its end."""
    pid = os.getpid()
    assert run_replicates(_square_or_die, (pid,), None, [3, 4], processes=1) == [9, 16]
    assert run_replicates(_square_or_die, (pid,), None, [3], processes=4) == [9]
    assert run_replicates(_square_or_die, (pid,), None, [], processes=2) == []


def _children(pid: int) -> set[int]:
    """The processes whose parent is ``pid`` (from /proc)."""
    kids = set()
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as f:
                    fields = f.read().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid:
                kids.add(int(entry))
    return kids


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.parametrize("how", ["SIGTERM", "SIGHUP", "SIGINT twice", "SIGKILL"])
def test_a_run_stopped_during_its_replicates_keeps_its_record_and_leaves_no_process(
        how, tmp_path):
    """SIGTERM (a scheduler's stop), SIGHUP (its terminal closed), or Ctrl+C twice in
    quick succession (the second while
    the files are written), while the interval's replicates run in their processes: the
    command exits 130 with the telemetry and metrics written whole (the interval said to
    be interrupted). Any of these or SIGKILL: neither the replicates' processes nor the
    plot process outlive it."""
    import json
    import subprocess
    import sys
    import time

    out = tmp_path / "out"
    args = [sys.executable, "-m", "app.cli", "run", "collision", "--quiet", "--out", str(out),
            "--set", "uncertainty.replicates=1000"]
    for a in ["satellites.0.position_m=[-0.16,0,0]", "satellites.1.position_m=[0.16,0,0]",
              "loop.duration_s=1.2"]:
        args += ["--set", a]
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 240.0
        seen: set[int] = set()
        while time.monotonic() < deadline and proc.poll() is None:
            kids = _children(proc.pid)
            if len(kids) >= 3:  # the plot process and two replicates' processes
                seen = kids | {k for kid in kids for k in _children(kid)}
                break
            time.sleep(0.05)
        assert seen, "the replicates never ran in processes of their own"
        time.sleep(0.5)
        if how == "SIGINT twice":
            proc.send_signal(signal.SIGINT)
            time.sleep(0.1)
            proc.send_signal(signal.SIGINT)
        else:
            proc.send_signal(getattr(signal, how))
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    time.sleep(1.0)
    assert not [pid for pid in seen if _alive(pid)]
    if how == "SIGKILL":
        return
    assert proc.returncode == 130, err
    assert f"interrupted: metrics.json, telemetry.csv written in {out}" in err
    metrics = json.loads((out / "metrics.json").read_text())
    lines = (out / "telemetry.csv").read_text().splitlines()
    assert float(lines[-1].split(",")[0]) == pytest.approx(1.2)  # to the run's end, whole
    coll = metrics["collision"]
    assert coll["restitution"] is not None and coll["restitution_interval_95"] is None
    assert "the restitution's interval was interrupted: none" in coll["warnings"]


def _terminate_worker(parent_pid: int, draw: int, noise) -> int:
    """draw², but a forked worker asked for 3 is sent SIGTERM (by someone else, as it were)."""
    if draw == 3 and os.getpid() != parent_pid:
        os.kill(os.getpid(), signal.SIGTERM)
    return draw * draw


def test_a_worker_terminated_alone_does_not_interrupt_the_run():
    """With the run's SIGTERM-as-Ctrl+C in force (app/runs/signals.py), a SIGTERM that one
    replicate's process gets ends that process alone: the run computes the replicates
    itself, the same results, and is not interrupted."""
    from app.runs.signals import interrupt_on_termination

    before = signal.getsignal(signal.SIGTERM)
    interrupt_on_termination()
    try:
        got = run_replicates(_terminate_worker, (os.getpid(),), None, list(range(8)),
                             processes=2)
    finally:
        signal.signal(signal.SIGTERM, before)
    assert got == [d * d for d in range(8)]


def test_an_interrupt_while_the_record_is_written_acts_once_it_is_whole():
    """Ctrl+C (or SIGTERM as the run takes it) during metrics.json and telemetry.csv is held
    until both are written (app/runs/headless.py): inside the block nothing is raised,
    as it ends the KeyboardInterrupt is."""
    import time

    from app.runs.signals import interrupts_held

    reached_end = False
    with pytest.raises(KeyboardInterrupt):
        with interrupts_held():
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.05)  # (an unheld SIGINT would have raised by now)
            reached_end = True
    assert reached_end


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGHUP], ids=["ctrl-c", "sighup"])
def test_a_stop_after_the_loop_s_last_cycle_keeps_the_whole_record(stop, tmp_path,
                                                                    monkeypatch):
    """A stop that comes once the loop has ended, while the metrics are worked out (the
    ideal run's comparison may take seconds), waits for the record: metrics.json and
    telemetry.csv are written whole, the interval said to be interrupted, and then the
    run raises KeyboardInterrupt (it lost the whole record before)."""
    import json

    import app.runs.headless as headless
    from app.runs.signals import interrupt_on_termination
    from app.scenarios import load_scenario

    real = headless.compute_metrics

    def stopped_first(*args, **kwargs):
        os.kill(os.getpid(), stop)
        return real(*args, **kwargs)

    monkeypatch.setattr(headless, "compute_metrics", stopped_first)
    before = signal.getsignal(signal.SIGHUP)
    interrupt_on_termination()
    try:
        with pytest.raises(KeyboardInterrupt):
            headless.run_scenario(load_scenario("collision"), duration_s=3.5,
                                  out_dir=tmp_path, plots_apart=False)
    finally:
        signal.signal(signal.SIGHUP, before)
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["status"] == "finished"
    rows = (tmp_path / "telemetry.csv").read_text().splitlines()
    assert float(rows[-1].split(",")[0]) == pytest.approx(3.5)
    coll = metrics["collision"]
    assert coll["restitution"] is not None and coll["restitution_interval_95"] is None
    assert "the restitution's interval was interrupted: none" in coll["warnings"]


def test_a_call_apart_answers_ignores_ctrl_c_and_stops_at_once():
    """``apart``: the call's result comes back through the pipe; the process ignores a
    Ctrl+C (SIGINT) meant for its parent; ``stop`` ends one still under way at once (a
    sweep interrupted while Ray starts does not wait for its first ideal run)."""
    import time

    from app.runs.replicate_pool import apart

    assert apart(divmod, 17, 5).result() == (3, 2)
    with pytest.raises(ChildProcessError, match="the process apart ended with status 1"):
        apart(divmod, 17, 0).result()  # (ZeroDivisionError there)
    slow = apart(time.sleep, 60.0)
    time.sleep(0.5)  # (its handlers are set)
    os.kill(slow.pid, signal.SIGINT)
    with pytest.raises(TimeoutError, match="no answer within 0.3 s"):
        slow.result(timeout_s=0.3)  # (killed then)
    assert slow.stop() == -signal.SIGKILL
    t0 = time.perf_counter()
    slower = apart(time.sleep, 60.0)
    assert slower.stop() == -signal.SIGKILL and time.perf_counter() - t0 < 2.0
