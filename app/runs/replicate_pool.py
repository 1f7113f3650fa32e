"""The contact's replicates side by side, in processes forked from this one.

Once its draws are made (app/runs/uncertainty.py ``_draw``), a replicate depends on
nothing but the snapshot it copies, so the replicates of a run's interval (30) or of a
pre-flight forecast (200) can run on every core the command has. The processes are forked:
they share the snapshot copy-on-write and nothing but the draws and the results crosses
between them; each replicate runs the very same code on the very same state as it would
here, so the results are the same bit for bit (tests/runs/test_replicate_pool.py).

Only the headless ``run`` command asks for more than one process: a sweep's Ray workers
already fill the cores, and the web app's loop process must keep its core to itself. (A
local sweep forks one process of the same kind, :func:`apart`, for its first ideal run
while Ray starts: app/campaign/sweep_ray.py.)
"""

from __future__ import annotations

import ctypes
import math
import multiprocessing
import os
import pickle
import select
import signal
import time
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

from app.runs.signals import as_helper_process

PR_SET_PDEATHSIG = 1
"""prctl's option: the signal a process gets when its parent ends (linux/prctl.h)."""
_job: tuple | None = None
"""In a forked worker: (replicate function, its leading arguments, the noise)."""


MAX_PROCESSES = 8
"""The most processes the replicates take: 30 or 200 replicates of some 30 ms gain little
from more, and each process holds some 40 MB of its own."""


def cores() -> int:
    """The cores this process may run on: those it is pinned to (all of the machine's where
    the system cannot say: sched_getaffinity is Linux's), at most its container's CPU
    quota (cgroup v2's cpu.max, or v1's cfs quota)."""
    n = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    quota = _cgroup_cpus()
    return max(1, min(n or 1, quota) if quota else (n or 1))


def _cgroup_cpus() -> int | None:
    """The CPU quota of this process's cgroup in whole CPUs (rounded up); None without one."""
    for quota_file, period_file in (("/sys/fs/cgroup/cpu.max", None),
                                    ("/sys/fs/cgroup/cpu/cpu.cfs_quota_us",
                                     "/sys/fs/cgroup/cpu/cpu.cfs_period_us")):
        try:
            fields = Path(quota_file).read_text().split()
            if period_file is not None:
                fields.append(Path(period_file).read_text().strip())
            quota, period = fields[0], fields[1]
            if quota in ("max", "-1"):
                return None
            return max(1, math.ceil(int(quota) / int(period)))
        except (OSError, ValueError, IndexError):
            continue
    return None


def run_replicates(fn, args: tuple, noise, draws: list, processes: int = 1,
                   tick=None) -> list:
    """``fn(*args, draw, noise)`` for each of ``draws``, in their order, in up to
    ``processes`` processes (here when 1, or where no process can be had: the same
    results). ``tick``: called once per replicate (before it here; as it ends there)."""
    processes = min(processes, len(draws), MAX_PROCESSES)
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
    pool = ProcessPoolExecutor(processes, mp_context=context, initializer=_adopt,
                               initargs=(fn, args, noise, os.getpid()))
    try:
        results = []
        for result in pool.map(_one, draws):
            if tick is not None:
                tick()
            results.append(result)
    except BaseException:  # Ctrl+C: the replicates not started are dropped, not waited for
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown()
    return results


class Apart:
    """A call under way in a process forked from this one (:func:`apart`)."""

    def __init__(self, pid: int, reader: int) -> None:
        self.pid, self._reader = pid, reader
        self._ended = False
        self._status: int | None = None  # its exit status once ended (None: unknown)

    def result(self, timeout_s: float | None = None):
        """The call's result, once it has come (within ``timeout_s``, if given); the
        process is then ended. OSError where it failed or died (ChildProcessError) or did
        not answer in time (TimeoutError; it is then killed); an answer cut short does
        not unpickle (pickle.UnpicklingError, EOFError). What failed there is not said:
        the caller does the call itself, where it fails in the open."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        chunks, answered = [], False
        try:
            while True:
                if deadline is not None:
                    left_s = deadline - time.monotonic()
                    if left_s <= 0.0 or not select.select([self._reader], [], [], left_s)[0]:
                        raise TimeoutError(f"no answer within {timeout_s:g} s")
                chunk = os.read(self._reader, 1 << 20)
                if not chunk:
                    break
                chunks.append(chunk)
            answered = True
        finally:
            status = self.stop(kill=not answered)  # (answered: it is ending by itself)
        if status not in (0, None):  # (None: reaped elsewhere; its answer is whole or not)
            raise ChildProcessError(f"the process apart ended with status {status}")
        return pickle.loads(b"".join(chunks))

    def stop(self, kill: bool = True) -> int | None:
        """End the process now if it is still under way (its result is dropped; with
        ``kill`` False, wait for it to end); its exit status (None if something else
        reaped it)."""
        if not self._ended:
            self._ended = True
            try:
                pid, status = os.waitpid(self.pid, os.WNOHANG) if kill else (0, 0)
                if pid == 0:  # under way
                    if kill:
                        os.kill(self.pid, signal.SIGKILL)
                    status = os.waitpid(self.pid, 0)[1]
                self._status = os.waitstatus_to_exitcode(status)
            except ChildProcessError:  # (reaped by something else)
                self._status = None
            os.close(self._reader)
        return self._status


def apart(fn, *args) -> Apart:
    """``fn(*args)`` in a process forked from this one (with os.fork: a daemonic process
    may call it too), whose result comes back pickled through a pipe. The process ignores
    Ctrl+C (the caller's to handle: :meth:`Apart.stop`), ends on SIGTERM and dies with
    this process. OSError where no process can be had."""
    reader, writer = os.pipe()
    parent = os.getpid()
    try:
        pid = os.fork()
    except OSError:
        os.close(reader)
        os.close(writer)
        raise
    if pid == 0:  # the process apart: the call, its result sent, the end
        status = 1
        try:
            os.close(reader)
            _detach(parent)
            data = pickle.dumps(fn(*args))
            with os.fdopen(writer, "wb") as pipe:
                pipe.write(data)
            status = 0
        finally:
            os._exit(status)
    os.close(writer)
    return Apart(pid, reader)


def _adopt(fn, args: tuple, noise, parent_pid: int) -> None:
    """A forked worker's start: the job it runs (inherited, never pickled). Ctrl+C is the
    run's to handle (it stops the pool); SIGTERM ends the worker alone (the run then
    computes its replicates itself); and the worker dies with the run's process however
    that ends (killed: it would otherwise wait for work for ever)."""
    global _job
    _detach(parent_pid)
    _job = (fn, args, noise)


def _detach(parent_pid: int) -> None:
    """A forked process's signals (:func:`as_helper_process`), and it dies with its
    parent."""
    as_helper_process()
    _die_with(parent_pid)


def _die_with(parent_pid: int) -> None:
    """SIGKILL this process when its parent ends (Linux's PR_SET_PDEATHSIG; elsewhere
    nothing), and exit now if the parent has already gone."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    except (OSError, AttributeError):
        pass
    if os.getppid() != parent_pid:
        os._exit(1)


def _one(draw):
    fn, args, noise = _job
    return fn(*args, draw, noise)
