"""The real-time runner, web-process side: :class:`Runner` supervises the loop process.

The Emulator runs paced at its loop rate in a process of its own
(:mod:`app.backend.loop_process`). Why a process and not a thread: the loop needs the GIL
for every cycle, and any thread holding it (the web server, viser's event loop, the scene)
that gets preempted by another busy process (a browser rendering WebGL in software runs at
nice -8) keeps the loop waiting for milliseconds: a priority inversion no thread priority
can fix. Measured on a 2-core machine with a browser connected: 10-60 % deadline misses
with a thread, well under 1 % with the process.

The loop process (:class:`~app.backend.loop_process.LoopCore`) owns the Emulator.
Everything else talks to it through :class:`Runner`, its thread-safe proxy in the web
process, which starts and stops the process and

* sends commands (:class:`~app.sim.hand.Push`, :class:`~app.sim.hand.HandAnchor`) and
  control requests (start / stop / reset) down a pipe; the loop polls it between cycles
  and hands commands to ``Emulator.post``;
* reads the snapshot (a plain dict) the loop publishes every ``snapshot_every`` cycles into
  shared memory (:mod:`app.backend.snapshots`: two slots and a sequence number; the writer
  never waits for a reader, a reader retries when the writer lapped it);
* gives each run a telemetry ring in shared memory (:class:`RunTelemetry`): the loop
  writes a row per cycle into it, and telemetry and metrics are read and computed here, in
  the web process, from a copy of it; nothing a client reads costs the loop a cycle.
"""

from __future__ import annotations

import collections
import logging
import multiprocessing as mp
import queue
import signal
import threading
import time
from collections.abc import Callable
from multiprocessing import shared_memory
from typing import Any

from app.backend import snapshots
from app.backend.loop_process import _loop_main
from app.backend.memory import TRIM_EVERY_S, give_back_memory
from app.backend.ring import RunTelemetry
from app.config import EmulatorConfig
from app.sim.hand import Command

log = logging.getLogger("orbit_emulator.runner")

#: Statuses reported by the runner: the emulator's own plus "starting" (moving the
#: arms to their start poses) and "error" (an exception in the loop; see ``reason``).
RUNNER_STATUSES = ("idle", "starting", "running", "finished", "safety_stop", "stopped", "error")


class RunnerBusy(RuntimeError):
    """A request that needs the runner idle (start) or running (push) came at a bad time."""


class RunnerError(RuntimeError):
    """The loop process failed to answer a request."""


class LoopDown(RunnerError):
    """The loop process is dead or stalled (see Runner.fault); reset or start restarts it."""


MISS_WINDOW_S = 10.0
"""Health reports the deadline-miss ratio over this window."""
STALL_S = 0.5
"""A loop process whose heartbeat has not moved for this long is stalled (a fault that
ends when it beats again)."""
SEND_TIMEOUT_S = 1.0
"""A loop process that takes no command for this long, and has not run a cycle meanwhile,
is killed (see Runner._send)."""
SEND_PATIENCE_S = 10.0
"""A command not delivered for this long kills the loop process even if it still runs
cycles (it is not reading its commands)."""


def exit_reason(exitcode: int | None) -> str:
    """Why the loop process is gone, from its exit code (negative: the signal that killed
    it; SIGBUS explained: the telemetry ring in /dev/shm could not get a page)."""
    text = f"the loop process exited (code {exitcode})"
    if exitcode is None or exitcode >= 0:
        return text
    try:
        name = signal.Signals(-exitcode).name
    except ValueError:
        name = f"signal {-exitcode}"
    text += f", killed by {name}"
    if -exitcode == signal.SIGBUS:
        text += (": a bus error, which here means the shared memory in /dev/shm (where the "
                 "telemetry ring lives) ran out; give it more room (docker run "
                 "--shm-size=1g) or lower loop.telemetry_capacity")
    return text


def miss_ratio_of(samples: list[tuple[float, int, int, int]], window_s: float) -> float | None:
    """Share of missed deadlines over the last ``window_s`` of samples (time_s,
    generation, cycles, deadline misses), counting only the latest run (generation): a
    new run starts its counters from zero. None when no cycle of it ran in the window."""
    if not samples:
        return None
    now, gen, c1, m1 = samples[-1]
    _, _, c0, m0 = next(x for x in samples if now - x[0] <= window_s and x[1] == gen)
    return min(1.0, max(0.0, (m1 - m0) / (c1 - c0))) if c1 > c0 else None


class Runner:
    """Proxy of the loop process; thread-safe."""

    def __init__(
        self,
        config: EmulatorConfig,
        scenario: str = "custom",
        mode: str | None = None,
        snapshot_every: int = 10,
        spin_s: float = 0.0003,
        max_lag_s: float = 0.1,
        rt_priority: int | None = 10,
        nice: int | None = -10,
        warm_up: bool = True,
    ) -> None:
        self._initial = (config, scenario, mode)
        self._settings = {
            "snapshot_every": snapshot_every, "spin_s": spin_s, "max_lag_s": max_lag_s,
            "rt_priority": rt_priority, "nice": nice, "warm_up": warm_up,
        }
        self._outbox: queue.SimpleQueue = queue.SimpleQueue()  # for the sender thread
        self._sender: threading.Thread | None = None
        self._state_lock = threading.RLock()
        self._proc: mp.process.BaseProcess | None = None
        self._shm: shared_memory.SharedMemory | None = None
        self._cache: tuple[int, dict] = (-1, {})
        self._pending: str | None = None  # status asked for and not yet published
        self._pending_gen = -1
        self._beat = (0, time.monotonic())  # last heartbeat seen, and when it moved
        self._fault: str | None = None  # the process is gone: until restart()
        self._stalled = False  # no heartbeat for STALL_S: until the next beat
        self.last_stall: dict | None = None
        """The last stall that ended: {"duration_s", "ended_at"} (monotonic clock)."""
        self._watch: threading.Thread | None = None
        self._timing: collections.deque = collections.deque(maxlen=int(MISS_WINDOW_S / 0.1) + 2)
        self._rings: dict[int, RunTelemetry] = {}  # by generation; the last two are kept
        self._ring_lock = threading.Lock()

    # --- lifecycle --------------------------------------------------------------------

    def start_thread(self, timeout_s: float = 60.0) -> None:
        """Start the loop process and wait for its first snapshot."""
        if self._proc is not None:
            return
        ctx = mp.get_context("spawn")  # never fork a process that runs threads
        self._shm = shared_memory.SharedMemory(create=True, size=snapshots.SHM_BYTES)
        snapshots.clear(self._shm.buf)
        cmd_parent, cmd_child = ctx.Pipe(duplex=False)  # (receive end, send end)
        config, scenario, mode = self._initial
        self._proc = ctx.Process(
            target=_loop_main, name="emulator-loop", daemon=True,
            args=(cmd_parent, self._shm.name, config, scenario, mode, self._settings),
        )
        self._proc.start()
        cmd_parent.close()
        self._cmd = cmd_child
        deadline = time.monotonic() + timeout_s
        while self._read_snapshot()[1] is None:
            if not self._proc.is_alive():
                raise RunnerError(exit_reason(self._proc.exitcode))
            if time.monotonic() > deadline:
                raise RunnerError("the loop process did not start in time")
            time.sleep(0.02)
        self._fault, self._stalled = None, False
        self._beat = (snapshots.heartbeat(self._shm.buf), time.monotonic())
        if self._watch is None:
            self._watch = threading.Thread(target=self._watchdog, name="runner-watchdog",
                                           daemon=True)
            self._watch.start()

    # --- supervision ------------------------------------------------------------------

    def _watchdog(self) -> None:
        """Every 0.1 s: is the loop process alive, has its heartbeat moved; and a sample
        of its (cycles, deadline misses) for :meth:`miss_ratio`; every TRIM_EVERY_S, the
        web process's freed memory handed back (:func:`give_back_memory`)."""
        trimmed = time.monotonic()
        while True:
            time.sleep(0.1)
            if time.monotonic() - trimmed > TRIM_EVERY_S:
                give_back_memory()
                trimmed = time.monotonic()
            if self.fault() is None:
                try:
                    snap = self.snapshot()
                    sample = (time.monotonic(), snap["generation"], snap["loop"]["cycles"],
                              snap["loop"]["deadline_misses"])
                except (RunnerError, KeyError):
                    continue
                with self._state_lock:
                    self._timing.append(sample)

    def miss_ratio(self, window_s: float = MISS_WINDOW_S) -> float | None:
        """Share of the cycles in the last ``window_s`` that missed their deadline (None
        when no cycle ran in that window)."""
        with self._state_lock:
            samples = list(self._timing)
        return miss_ratio_of(samples, window_s)

    def fault(self) -> str | None:
        """Why the loop process cannot serve now; None when it is fine. A process that
        exited (or was killed for not taking a command) stays at fault until
        :meth:`restart`; a stall (no heartbeat for STALL_S: a VM pause, a swap storm, a
        SIGSTOP) lasts until the next heartbeat, and control returns with it."""
        with self._state_lock:
            proc, shm = self._proc, self._shm  # (a restart may let them go meanwhile)
            if self._fault is not None or proc is None or shm is None:
                return self._fault
            if not proc.is_alive():
                self._fault = exit_reason(proc.exitcode)
                log.error("%s: the run ends here, its rows kept; the next start brings up a "
                          "new loop process", self._fault)
                return self._fault
            count, since = self._beat
            now = time.monotonic()
            current = snapshots.heartbeat(shm.buf)
            if current != count:
                if self._stalled:
                    self._stalled = False
                    self.last_stall = {"duration_s": now - since, "ended_at": now}
                    log.warning("the loop process answered again after %.2f s without a "
                                "heartbeat", now - since)
                self._beat = (current, now)
                return None
            if now - since > STALL_S:
                self._stalled = True
                return f"the loop process has not answered for {now - since:.1f} s"
            return None

    def dead(self) -> str | None:
        """Why the loop process is gone for good (until :meth:`restart`), else None."""
        self.fault()
        with self._state_lock:
            return self._fault

    def restart(self, config: EmulatorConfig, scenario: str, mode: str | None) -> None:
        """A new loop process in place of a dead or stalled one (what was recorded by the
        old one is gone with it)."""
        with self._state_lock:
            proc = self._proc
        if proc is not None and proc.is_alive():
            proc.kill()
            proc.join(2.0)
        self.shutdown(timeout_s=0.5)
        with self._state_lock:
            self._initial = (config, scenario, mode)
            self._pending, self._pending_gen = None, -1  # the new process counts from 0
            self._cache = (-1, {})
            self._timing.clear()
        self.start_thread()

    def shutdown(self, timeout_s: float = 5.0) -> None:
        if self._proc is None:
            return
        try:
            self._send(("shutdown",))
        except (OSError, RunnerError):
            pass
        self._proc.join(timeout_s)
        if self._proc.is_alive():  # pragma: no cover
            self._proc.terminate()
            self._proc.join(2.0)
        self._proc = None
        self._cmd.close()
        self._release_rings()
        with self._state_lock:  # fault() reads the heartbeat under this lock
            shm, self._shm = self._shm, None
        if shm is not None:
            try:
                shm.close()
            except BufferError:  # a reader still holds a view: the mapping goes with it
                pass
            shm.unlink()

    @property
    def alive(self) -> bool:
        return self._proc is not None and self._proc.is_alive()

    def _send(self, msg: tuple, through_stall: bool = False) -> None:
        """Hand the loop a command, or raise LoopDown. The pipe takes 64 KiB before the
        loop reads; a larger message to a stalled loop would block the caller (who may
        hold the state lock that health needs), so one sender thread writes to the pipe.
        A loop that does not take a message within SEND_TIMEOUT_S is killed: the message
        is half-written, and the run must not go on where no command reaches it.
        ``through_stall``: send to a stalled loop too (a stop: it takes it as soon as it
        runs again)."""
        if self._proc is None:
            raise RunnerError("the loop process is not running")
        reason = self.fault()
        if reason is not None and not (through_stall and self._fault is None):
            raise LoopDown(reason)
        with self._state_lock:  # one sender thread, whoever sends first
            if self._sender is None:
                self._sender = threading.Thread(target=self._sender_main,
                                                name="loop-commands", daemon=True)
                self._sender.start()
        done, failed, queued = threading.Event(), [], time.monotonic()
        with self._state_lock:
            proc, shm = self._proc, self._shm
            self._outbox.put((self._cmd, msg, done, failed))
        if not self._delivered(done, shm):
            waited = time.monotonic() - queued
            reason = (f"the loop process did not take a command for {waited:.1f} s "
                      f"and was stopped (killed)")
            with self._state_lock:
                if self._proc is proc and self._fault is None:  # not replaced meanwhile
                    self._fault = reason
                    log.error("%s", reason)
            if proc is not None and proc.is_alive():
                proc.kill()
            raise LoopDown(reason)
        if failed:
            raise LoopDown(f"the loop process is gone ({type(failed[0]).__name__})")

    @staticmethod
    def _delivered(done: threading.Event, shm) -> bool:
        """Wait for the sender to hand a message to the pipe: SEND_TIMEOUT_S, and longer
        (up to SEND_PATIENCE_S) while the loop keeps running cycles, which it does only
        between reads of its commands: on a loaded machine the delay is then the web
        process's own (its sender thread waiting for the CPU), not a stalled loop's."""
        def heartbeat():
            try:
                return snapshots.heartbeat(shm.buf)
            except (AttributeError, TypeError, ValueError):  # none, or let go by a restart
                return None

        beat, waited = heartbeat(), 0.0
        while not done.wait(SEND_TIMEOUT_S):
            waited += SEND_TIMEOUT_S
            now = heartbeat()
            if now is None or now == beat or waited >= SEND_PATIENCE_S:
                return False
            beat = now
        return True

    def _sender_main(self) -> None:
        """The sender thread: writes each message to its pipe in order. A send blocked on
        a stalled loop ends when restart() kills that process (BrokenPipeError)."""
        while True:
            conn, msg, done, failed = self._outbox.get()
            try:
                conn.send(msg)
            except Exception as err:  # noqa: BLE001 - the process died, or its pipe was
                failed.append(err)   # closed under a blocked send (TypeError): go on
            finally:
                done.set()

    # --- state --------------------------------------------------------------------------

    def snapshot(self) -> dict[str, Any]:
        """The latest published state (treat as read-only)."""
        shm = self._shm
        if shm is None:
            raise RunnerError("the loop process is not running")
        try:
            seq = snapshots.sequence(shm.buf)
        except (TypeError, ValueError):  # shut down meanwhile: the mapping is gone
            raise RunnerError("the loop process is not running") from None
        if seq != self._cache[0]:
            seq, snap = self._read_snapshot(shm)
            self._cache = (seq, snap)
        return self._cache[1]

    def _read_snapshot(self, shm: shared_memory.SharedMemory | None = None,
                       ) -> tuple[int, dict | None]:
        try:
            return snapshots.read_snapshot((shm or self._shm).buf)
        except snapshots.SnapshotError as err:
            raise RunnerError(str(err)) from err
        except (AttributeError, TypeError, ValueError):  # shut down meanwhile
            raise RunnerError("the loop process is not running") from None

    @property
    def status(self) -> str:
        """The published status, or the one asked for and not yet published."""
        with self._state_lock:
            return self._status(self.snapshot())

    def _status(self, snap: dict) -> str:  # call with _state_lock held
        if self._pending is not None:
            if snap["generation"] >= self._pending_gen:
                self._pending = None
            else:
                return self._pending
        return snap["status"]

    @property
    def scenario(self) -> str:
        return self.snapshot()["scenario"]

    @property
    def wall_s(self) -> float:
        return self.snapshot()["loop"]["wall_s"]

    def wait_until(self, predicate: Callable[[dict], bool], timeout_s: float,
                   through_stalls: bool = False) -> bool:
        """Wait for the published state to satisfy predicate; raises LoopDown as soon as
        the loop process dies or (unless ``through_stalls``) stalls meanwhile."""
        return self.wait_for(predicate, timeout_s, through_stalls) is not None

    def wait_for(self, predicate: Callable[[dict], bool], timeout_s: float,
                 through_stalls: bool = False) -> dict | None:
        """The first published state that satisfies predicate (None after timeout_s); a
        LoopDown as :meth:`wait_until`."""
        deadline = time.monotonic() + timeout_s
        while True:
            snap = self.snapshot()
            if predicate(snap):
                return snap
            reason = self.fault()
            if reason is not None and (not through_stalls or self.dead() is not None):
                raise LoopDown(reason)
            if time.monotonic() >= deadline:
                return None
            time.sleep(0.01)

    # --- requests -----------------------------------------------------------------------

    def request_start(self, scenario: str, config: EmulatorConfig, mode: str | None,
                      snapshot_at_s: float | None = None) -> int:
        """Start `config` (validated) in the loop; returns the generation it will have.
        ``snapshot_at_s``: when the loop keeps its snapshot for the restitution's interval
        (app/runs/uncertainty.py; from the pre-flight's ideal run), None for none.

        Raises RunnerBusy when a run is starting or running.
        """
        with self._state_lock:
            snap = self.snapshot()
            busy = self._status(snap)
            if busy in ("starting", "running"):
                raise RunnerBusy(f"a scenario is already {busy}; stop it first")
            gen = max(snap["generation"], self._pending_gen) + 1  # requests not yet seen
            ring = self._new_ring(gen, config, mode, snap["generation"])
            self._send(("start", scenario, config, mode, ring.name, snapshot_at_s))
            self._pending, self._pending_gen = "starting", gen
            return gen

    def _new_ring(self, gen: int, config: EmulatorConfig, mode: str | None,
                  published: int) -> RunTelemetry:
        """The telemetry ring of run ``gen``; the rings of runs before ``gen − 1`` go,
        but none the loop may still have to open (requests it has not reached yet:
        generations after the ``published`` one)."""
        ring = RunTelemetry(config, mode)
        with self._ring_lock:
            old = self._rings.pop(gen, None)
            self._rings[gen] = ring
            stale = [g for g in self._rings if g < min(gen - 1, published)]
            for g in stale:
                self._rings.pop(g).release()
            if old is not None:
                old.release()
        return ring

    def _release_rings(self) -> None:
        with self._ring_lock:
            for ring in self._rings.values():
                ring.release()
            self._rings.clear()

    def run_telemetry(self) -> tuple[dict, RunTelemetry | None, int, Any]:
        """(the latest state, the ring of its run or None, the number of the first row
        copied, a copy of the ring's committed rows or None): read here, in the web
        process; the loop is not asked."""
        snap = self.snapshot()
        ring = self.ring_of(snap)
        if ring is None:
            return snap, None, 0, None
        return snap, ring, *ring.numbered_rows()

    def ring_of(self, snap: dict) -> RunTelemetry | None:
        """The telemetry ring of the run of state ``snap`` (None before any start)."""
        with self._ring_lock:
            return self._rings.get(snap.get("generation", -1))

    def request_stop(self) -> None:
        """Stop the run; to a stalled loop too, which takes it first when it runs again."""
        self._send(("stop",), through_stall=True)

    def request_reset(self, scenario: str, config: EmulatorConfig, mode: str | None) -> int:
        with self._state_lock:
            snap = self.snapshot()
            gen = max(snap["generation"], self._pending_gen) + 1  # requests not yet seen
            ring = self._new_ring(gen, config, mode, snap["generation"])
            self._send(("reset", scenario, config, mode, ring.name))
            self._pending, self._pending_gen = "idle", gen
            return gen

    def post(self, command: Command) -> None:
        """Queue a Push / HandAnchor; the loop applies it before its next cycle.

        Raises RunnerBusy when nothing runs and ValueError for a bad satellite index.
        """
        reason = self.fault()
        if reason is not None:
            raise LoopDown(reason)
        snap = self.snapshot()
        if self.status != "running":
            raise RunnerBusy(f"no scenario is running (status {self.status!r})")
        n_sat = snap["n_satellites"]
        if not 0 <= command.satellite < n_sat:
            raise ValueError(
                f"satellite must be between 1 and {n_sat}, got {command.satellite + 1}"
            )
        self._send(("cmd", command))

    def post_nowait(self, command: Command) -> bool:
        """Like :meth:`post` but never raises (gizmo callbacks); False when dropped."""
        try:
            self.post(command)
        except (RunnerBusy, ValueError, RunnerError, OSError):
            return False
        return True
