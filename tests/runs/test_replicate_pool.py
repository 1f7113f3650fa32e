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


@pytest.mark.parametrize("how", [signal.SIGTERM, signal.SIGKILL])
def test_a_run_stopped_during_its_replicates_keeps_its_record_and_leaves_no_process(
        how, tmp_path):
    """SIGTERM (a scheduler's stop) while the interval's replicates run in their processes:
    the command exits 130 with the telemetry and metrics written (the interval said to be
    interrupted). SIGTERM or SIGKILL: neither the replicates' processes nor the plot
    process outlive it."""
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
        proc.send_signal(how)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    time.sleep(1.0)
    assert not [pid for pid in seen if _alive(pid)]
    if how == signal.SIGKILL:
        return
    assert proc.returncode == 130, err
    metrics = json.loads((out / "metrics.json").read_text())
    assert (out / "telemetry.csv").stat().st_size > 0
    coll = metrics["collision"]
    assert coll["restitution"] is not None and coll["restitution_interval_95"] is None
    assert "the restitution's interval was interrupted: none" in coll["warnings"]
