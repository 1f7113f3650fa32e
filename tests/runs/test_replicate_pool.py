"""The replicates side by side (app/runs/replicate_pool.py): the same results bit for bit as
one after the other, the heartbeat kept, and a worker that dies costs nothing but time."""

from __future__ import annotations

import os

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
