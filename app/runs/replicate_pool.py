"""The contact's replicates side by side, in processes forked from this one.

Once its draws are made (app/runs/uncertainty.py ``_draw``), a replicate depends on
nothing but the snapshot it copies, so the replicates of a run's interval (30) or of a
pre-flight forecast (200) can run on every core the command has. The processes are forked:
they share the snapshot copy-on-write and nothing but the draws and the results crosses
between them; each replicate runs the very same code on the very same state as it would
here, so the results are the same bit for bit (tests/runs/test_replicate_pool.py).

Only the headless ``run`` command asks for more than one process: a sweep's Ray workers
already fill the cores, and the web app's loop process must keep its core to itself.
"""

from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool

_job: tuple | None = None
"""In a forked worker: (replicate function, its leading arguments, the noise)."""


def cores() -> int:
    """The cores this process may run on (all of the machine's where the system cannot
    say: sched_getaffinity is Linux's)."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def run_replicates(fn, args: tuple, noise, draws: list, processes: int = 1,
                   tick=None) -> list:
    """``fn(*args, draw, noise)`` for each of ``draws``, in their order, in up to
    ``processes`` processes (here when 1, or where no process can be had: the same
    results). ``tick``: called once per replicate (before it here; as it ends there)."""
    processes = min(processes, len(draws))
    if processes > 1 and "fork" in multiprocessing.get_all_start_methods():
        try:
            return _in_processes(fn, args, noise, draws, processes, tick)
        except (BrokenProcessPool, OSError):
            pass  # a worker died or none could start: the same replicates, here
    results = []
    for draw in draws:
        if tick is not None:
            tick()
        results.append(fn(*args, draw, noise))
    return results


def _in_processes(fn, args: tuple, noise, draws: list, processes: int, tick) -> list:
    context = multiprocessing.get_context("fork")
    with ProcessPoolExecutor(processes, mp_context=context, initializer=_adopt,
                             initargs=(fn, args, noise)) as pool:
        results = []
        for result in pool.map(_one, draws):
            if tick is not None:
                tick()
            results.append(result)
        return results


def _adopt(fn, args: tuple, noise) -> None:
    """A forked worker's start: the job it runs (inherited, never pickled)."""
    global _job
    _job = (fn, args, noise)


def _one(draw):
    fn, args, noise = _job
    return fn(*args, draw, noise)
