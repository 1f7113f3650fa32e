"""The real-time runner: the Emulator runs paced at its loop rate in a process of its own.

Why a process and not a thread: the loop needs the GIL for every cycle, and any thread
holding it (the web server, viser's event loop, the scene) that gets preempted by another
busy process (a browser rendering WebGL in software runs at nice -8) keeps the loop
waiting for milliseconds: a priority inversion no thread priority can fix. Measured on a
2-core machine with a browser connected: 10-60 % deadline misses with a thread, well
under 1 % with the process.

The loop process (:class:`LoopCore`) owns the Emulator. Everything else talks to it
through :class:`Runner`, its proxy in the web process:

* commands (:class:`~app.sim.loop.Push`, :class:`~app.sim.loop.HandAnchor`) and control
  requests (start / stop / reset) go down a pipe; the loop polls it between cycles and
  hands commands to ``Emulator.post``;
* the loop publishes a snapshot (a plain dict) every ``snapshot_every`` cycles into
  shared memory (two slots and a sequence number: the writer never waits for a reader,
  a reader retries when the writer lapped it);
* heavy reads (telemetry rows, metrics) are request/response over the pipes; the loop
  answers between two cycles.

Pacing: cycle k is due to start at ``t0 + k·dt`` and must finish by ``t0 + (k+1)·dt``
(its deadline); a cycle that finishes later is a deadline miss. The loop sleeps until
``spin_s`` before the next start, then spins. When it falls more than ``max_lag_s``
behind (a stalled machine) it drops the backlog and restarts the schedule from now
instead of running a burst of catch-up cycles (counted in ``resyncs``).
"""

from __future__ import annotations

import itertools
import logging
import multiprocessing as mp
import os
import pickle
import struct
import threading
import time
import traceback
from collections.abc import Callable
from multiprocessing import shared_memory
from typing import Any

import numpy as np

from app.config import EmulatorConfig
from app.sim.hand import Command
from app.sim.loop import Emulator
from app.sim.rotations import matrix_to_quat, quat_to_matrix

log = logging.getLogger("orbit_emulator.runner")

#: Statuses reported by the runner: the emulator's own plus "starting" (moving the
#: arms to their start poses) and "error" (an exception in the loop; see ``reason``).
RUNNER_STATUSES = ("idle", "starting", "running", "finished", "safety_stop", "stopped", "error")

_TIMING_WINDOW = 5000  # cycles kept for the p50 / p99 of the cycle time (10 s at 500 Hz)
_SLOT_BYTES = 1 << 20  # one snapshot slot in shared memory
_HEADER = struct.Struct("<QQQ")  # sequence number, length of slot 0, length of slot 1
_SLOT0 = 64


class RunnerBusy(RuntimeError):
    """A request that needs the runner idle (start) or running (push) came at a bad time."""


class RunnerError(RuntimeError):
    """The loop process failed to answer a request."""


# --- the loop process --------------------------------------------------------------------


class SnapshotWriter:
    def __init__(self, shm: shared_memory.SharedMemory) -> None:
        self.buf = shm.buf
        self.seq = 0

    def write(self, snap: dict) -> None:
        data = pickle.dumps(snap, protocol=pickle.HIGHEST_PROTOCOL)
        if len(data) > _SLOT_BYTES:  # pragma: no cover - snapshots are a few kB
            raise ValueError(f"snapshot of {len(data)} bytes does not fit its slot")
        nxt = self.seq + 1
        slot = nxt % 2
        start = _SLOT0 + slot * _SLOT_BYTES
        self.buf[start:start + len(data)] = data
        _, l0, l1 = _HEADER.unpack_from(self.buf, 0)
        lens = [l0, l1]
        lens[slot] = len(data)
        _HEADER.pack_into(self.buf, 0, nxt, lens[0], lens[1])
        self.seq = nxt


def read_snapshot(buf) -> tuple[int, dict | None]:
    """(sequence, snapshot) from shared memory; (0, None) before the first write."""
    for _ in range(100):
        seq, l0, l1 = _HEADER.unpack_from(buf, 0)
        if seq == 0:
            return 0, None
        slot = seq % 2
        length = (l0, l1)[slot]
        start = _SLOT0 + slot * _SLOT_BYTES
        data = bytes(buf[start:start + length])
        seq2 = _HEADER.unpack_from(buf, 0)[0]
        if seq2 - seq < 2:  # the writer did not come back to this slot meanwhile
            try:
                return seq, pickle.loads(data)
            except Exception:  # torn read: retry
                pass
        time.sleep(0.0005)
    raise RunnerError("could not read a consistent snapshot")


class LoopCore:
    """Runs in the loop process: owns the Emulator, paces it, answers requests."""

    def __init__(self, cmd_conn, resp_conn, shm_name: str, config: EmulatorConfig,
                 scenario: str, mode: str, settings: dict) -> None:
        self.cmd_conn = cmd_conn
        self.resp_conn = resp_conn
        self.shm = shared_memory.SharedMemory(name=shm_name)
        self.writer = SnapshotWriter(self.shm)
        self.snapshot_every = max(1, int(settings.get("snapshot_every", 10)))
        self.spin_s = float(settings.get("spin_s", 0.0003))
        self.max_lag_s = float(settings.get("max_lag_s", 0.1))
        self.scheduling = boost_priority(settings.get("rt_priority", 10),
                                         settings.get("nice", -10))
        self.status = "idle"
        self.reason: str | None = None
        self.scenario = scenario
        self.em = Emulator(config, mode=mode)
        self.generation = 0
        self.shutdown = False
        self._reset_timing()
        if settings.get("warm_up", True):
            warm_up(config)
        self.publish()

    # --- control --------------------------------------------------------------------

    def _reset_timing(self) -> None:
        self.cycle_ns = np.zeros(_TIMING_WINDOW, dtype=np.int64)
        self.cycle_count = 0
        self.deadline_misses = 0
        self.resyncs = 0
        self.max_late_us = 0.0
        self.wall_s = 0.0
        self.timing = {"p50": 0.0, "p99": 0.0, "max": 0.0}

    def serve(self) -> None:
        try:
            while not self.shutdown:
                if self.cmd_conn.poll(0.05 if self.status != "running" else 0):
                    self.handle(self.cmd_conn.recv())
                elif self.status == "running":
                    self.run_paced()
        except (EOFError, KeyboardInterrupt, BrokenPipeError):
            pass  # the web process went away
        except Exception as err:  # pragma: no cover - last resort
            self.fail(err)
        finally:
            self.shm.close()

    def handle(self, msg: tuple) -> None:
        """One message from the web process (may end a paced run)."""
        kind = msg[0]
        if kind == "cmd":
            if self.status == "running":
                try:
                    self.em.post(msg[1])
                except ValueError as err:
                    log.warning("command rejected: %s", err)
        elif kind == "start":
            _, scenario, config, mode = msg
            self.begin(scenario, config, mode, prepare=True)
        elif kind == "reset":
            _, scenario, config, mode = msg
            self.begin(scenario, config, mode, prepare=False)
        elif kind == "stop":
            if self.status in ("running", "starting"):
                if self.em.status == "running":
                    self.em.status = "stopped"
                self.status, self.reason = "stopped", "stopped by the operator"
                self.publish()
        elif kind == "read":
            _, req_id, what = msg
            try:
                result = (True, self.read(what))
            except Exception as err:
                result = (False, f"{type(err).__name__}: {err}")
            self.resp_conn.send(("resp", req_id, *result))
        elif kind == "shutdown":
            self.shutdown = True

    def read(self, what: str) -> Any:
        if what == "telemetry":
            return list(self.em.telemetry.columns), self.em.telemetry.rows()
        if what == "metrics":
            from app.metrics import compute_metrics

            return compute_metrics(self.em, self.wall_s)
        raise ValueError(f"unknown read {what!r}")

    def begin(self, scenario: str, config: EmulatorConfig, mode: str | None,
              prepare: bool) -> None:
        self.status = "starting" if prepare else "idle"
        self.reason = None
        self.generation += 1
        try:
            em = Emulator(config, mode=mode)
        except Exception as err:
            self.fail(err)
            return
        self.scenario, self.em = scenario, em
        self._reset_timing()
        self.publish()
        if not prepare:
            return
        try:
            em.prepare()
        except Exception as err:
            self.fail(err)
            return
        if em.status == "running":
            self.status = "running"
        else:
            self.status = em.status
            self.reason = (em.safety_stop or {}).get("reason")
        self.publish()

    def fail(self, err: BaseException) -> None:
        msg = f"{type(err).__name__}: {err}"
        log.error("emulator loop error: %s\n%s", msg, traceback.format_exc())
        self.status = "error"
        self.reason = msg
        try:
            self.publish()
        except Exception:  # pragma: no cover
            log.exception("could not publish the error state")

    # --- the paced loop ---------------------------------------------------------------

    def run_paced(self) -> None:
        em = self.em
        dt_ns = int(round(em.dt_s * 1e9))
        spin_ns = int(self.spin_s * 1e9)
        max_lag_ns = int(self.max_lag_s * 1e9)
        duration_s = em.config.loop.duration_s - 0.5 * em.dt_s
        perf = time.perf_counter_ns
        poll = self.cmd_conn.poll
        wall0 = time.monotonic() - self.wall_s
        t0 = perf()
        k = n = 0
        while not self.shutdown:
            start_ns = t0 + k * dt_ns
            # commands and requests between cycles; they may end this run
            while poll():
                self.handle(self.cmd_conn.recv())
                if self.status != "running" or self.em is not em:
                    return
            wait = start_ns - perf()
            if wait > spin_ns:
                time.sleep((wait - spin_ns) * 1e-9)
            while perf() < start_ns:
                pass
            c0 = perf()
            try:
                em.step()
            except Exception as err:
                self.fail(err)
                return
            c1 = perf()
            self.cycle_ns[self.cycle_count % _TIMING_WINDOW] = c1 - c0
            self.cycle_count += 1
            late = c1 - (start_ns + dt_ns)
            if late > 0:
                self.deadline_misses += 1
                self.max_late_us = max(self.max_late_us, late / 1e3)
            k += 1
            n += 1
            if c1 - (t0 + k * dt_ns) > max_lag_ns:  # hopelessly behind: restart schedule
                t0, k = c1, 0
                self.resyncs += 1
            self.wall_s = time.monotonic() - wall0
            if em.status == "running" and em.t_s >= duration_s:
                em.status = "finished"
                self.reason = f"reached the scenario duration ({em.config.loop.duration_s:g} s)"
            if em.status != "running":
                self.status = em.status
                if em.safety_stop:
                    self.reason = em.safety_stop.get("reason")
                self.publish()
                return
            if n % self.snapshot_every == 0:
                self.publish()

    # --- snapshots --------------------------------------------------------------------

    def _timing(self) -> dict[str, float]:
        n = min(self.cycle_count, _TIMING_WINDOW)
        # percentiles cost ~100 us: refresh them every 250 cycles only
        if n and (self.cycle_count % 250 < self.snapshot_every or n < 250):
            window = self.cycle_ns[:n]
            p50, p99 = np.percentile(window, [50, 99])
            self.timing = {"p50": float(p50) / 1e3, "p99": float(p99) / 1e3,
                           "max": float(window.max()) / 1e3}
        return self.timing

    def publish(self) -> None:
        self.writer.write(self.build_snapshot())

    def build_snapshot(self) -> dict[str, Any]:
        em = self.em
        ods = em.ods
        cfg = em.config
        T_W_R = em.T_W_R
        R_W_R = T_W_R[:3, :3]
        sats = []
        for i, s in enumerate(cfg.satellites):
            T_W_S = em.satellite_pose_W(i)
            sats.append({
                "name": s.name,
                "material": s.material,
                "size_m": list(s.size_m),
                "position_m": ods.position_m[i].tolist(),
                "velocity_mps": ods.velocity_mps[i].tolist(),
                "attitude_wxyz": ods.attitude_wxyz[i].tolist(),
                "omega_radps": ods.omega_rel_radps[i].tolist(),
                "applied_force_N": em.applied_force_R[i].tolist(),
                "position_W_m": T_W_S[:3, 3].tolist(),
                "attitude_W_wxyz": matrix_to_quat(T_W_S[:3, :3]).tolist(),
            })
        robots = []
        for arm in em.arms:
            p_R, q_R = em.mockup_pose_R(arm)
            robots.append({
                "name": cfg.robots[arm.index].name,
                "satellite": arm.satellite + 1,
                "q_rad": arm.servo.state.q_rad.tolist(),
                "mockup_position_m": p_R.tolist(),
                "mockup_attitude_wxyz": q_R.tolist(),
                "mockup_position_W_m": (R_W_R @ p_R + T_W_R[:3, 3]).tolist(),
                "mockup_attitude_W_wxyz": matrix_to_quat(R_W_R @ quat_to_matrix(q_R)).tolist(),
                "tracking_error_m": float(np.linalg.norm(p_R - ods.position_m[arm.satellite])),
                "ft_raw": arm.last_raw_S.tolist(),
                "ft_processed": arm.last_processed.tolist(),
            })
        timing = self._timing()
        cycles = self.cycle_count
        return {
            "generation": self.generation,
            "scenario": self.scenario,
            "mode": em.mode,
            "status": self.status,
            "reason": self.reason,
            "safety_stop": em.safety_stop,
            "t_s": float(ods.t_s),
            "duration_s": cfg.loop.duration_s,
            "n_satellites": em.n_sat,
            "satellites": sats,
            "robots": robots,
            "contact_active": bool(em.contact_active),
            "layout": {
                "T_W_R": T_W_R.tolist(),
                "arms": [[cfg.robots[a.index].name, a.T_W_B.tolist()] for a in em.arms],
                "satellites": [[s.name, list(s.size_m), s.material] for s in cfg.satellites],
            },
            "loop": {
                "rate_hz": cfg.loop.rate_hz,
                "cycles": cycles,
                "cycle_time_us": {"p50": timing["p50"], "p99": timing["p99"],
                                  "max": timing["max"]},
                "deadline_misses": self.deadline_misses,
                "deadline_miss_ratio": self.deadline_misses / cycles if cycles else 0.0,
                "max_late_us": self.max_late_us,
                "resyncs": self.resyncs,
                "wall_s": self.wall_s,
                "scheduling": self.scheduling,
                "pid": os.getpid(),
            },
        }


def warm_up(config: EmulatorConfig) -> None:
    """Run a throwaway emulator a few cycles: the first cycle in a process costs ~12 ms
    (JIT and lazy initialisation), which would be a burst of deadline misses."""
    em = Emulator(config)
    em.prepare(settle_s=0.02)
    for _ in range(3):
        em.step()


def boost_priority(rt_priority: int | None, nice: int | None) -> str:
    """Best effort: SCHED_FIFO for this (single-threaded) process, else a better nice
    value; without privileges (CAP_SYS_NICE) it keeps the default. The loop sleeps most
    of each period and spins at most ``spin_s``; the kernel's RT throttling still leaves
    5 % of each CPU to everything else."""
    if rt_priority:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(int(rt_priority)))
            return f"SCHED_FIFO {int(rt_priority)}"
        except (OSError, AttributeError):
            pass
    if nice is not None:
        try:
            os.setpriority(os.PRIO_PROCESS, 0, int(nice))
            return f"nice {int(nice)}"
        except (OSError, AttributeError):
            pass
    return "default"


def _loop_main(cmd_conn, resp_conn, shm_name, config, scenario, mode, settings) -> None:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s loop: %(message)s")
    core = LoopCore(cmd_conn, resp_conn, shm_name, config, scenario, mode, settings)
    core.serve()


# --- the proxy in the web process ----------------------------------------------------


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
        self._send_lock = threading.Lock()
        self._state_lock = threading.Lock()
        self._ids = itertools.count(1)
        self._waiting: dict[int, list] = {}
        self._proc: mp.process.BaseProcess | None = None
        self._shm: shared_memory.SharedMemory | None = None
        self._cache: tuple[int, dict] = (-1, {})
        self._pending: str | None = None  # status asked for and not yet published
        self._pending_gen = -1

    # --- lifecycle --------------------------------------------------------------------

    def start_thread(self, timeout_s: float = 60.0) -> None:
        """Start the loop process and wait for its first snapshot."""
        if self._proc is not None:
            return
        ctx = mp.get_context("spawn")  # never fork a process that runs threads
        self._shm = shared_memory.SharedMemory(create=True, size=_SLOT0 + 2 * _SLOT_BYTES)
        _HEADER.pack_into(self._shm.buf, 0, 0, 0, 0)
        cmd_parent, cmd_child = ctx.Pipe(duplex=False)  # (receive end, send end)
        resp_parent, resp_child = ctx.Pipe(duplex=False)
        config, scenario, mode = self._initial
        self._proc = ctx.Process(
            target=_loop_main, name="emulator-loop", daemon=True,
            args=(cmd_parent, resp_child, self._shm.name, config, scenario, mode,
                  self._settings),
        )
        self._proc.start()
        cmd_parent.close()
        resp_child.close()
        self._cmd = cmd_child
        self._resp = resp_parent
        self._reader = threading.Thread(target=self._read_responses, name="runner-resp",
                                        daemon=True)
        self._reader.start()
        deadline = time.monotonic() + timeout_s
        while read_snapshot(self._shm.buf)[1] is None:
            if not self._proc.is_alive():
                raise RunnerError(f"the loop process exited (code {self._proc.exitcode})")
            if time.monotonic() > deadline:
                raise RunnerError("the loop process did not start in time")
            time.sleep(0.02)

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
        for conn in (self._cmd, self._resp):
            conn.close()
        if self._shm is not None:
            self._shm.close()
            self._shm.unlink()
            self._shm = None

    @property
    def alive(self) -> bool:
        return self._proc is not None and self._proc.is_alive()

    def _send(self, msg: tuple) -> None:
        if self._proc is None:
            raise RunnerError("the loop process is not running")
        with self._send_lock:
            self._cmd.send(msg)

    def _read_responses(self) -> None:
        while True:
            try:
                msg = self._resp.recv()
            except (EOFError, OSError):
                break
            _, req_id, ok, payload = msg
            slot = self._waiting.get(req_id)
            if slot is not None:
                slot[1] = (ok, payload)
                slot[0].set()
        for slot in list(self._waiting.values()):  # wake whoever still waits
            slot[1] = (False, "the loop process exited")
            slot[0].set()

    # --- state --------------------------------------------------------------------------

    def snapshot(self) -> dict[str, Any]:
        """The latest published state (treat as read-only)."""
        if self._shm is None:
            raise RunnerError("the loop process is not running")
        seq, _ = _HEADER.unpack_from(self._shm.buf, 0)[:2]
        if seq != self._cache[0]:
            seq, snap = read_snapshot(self._shm.buf)
            self._cache = (seq, snap)
        return self._cache[1]

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

    def wait_until(self, predicate: Callable[[dict], bool], timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if predicate(self.snapshot()):
                return True
            time.sleep(0.01)
        return predicate(self.snapshot())

    # --- requests -----------------------------------------------------------------------

    def request_start(self, scenario: str, config: EmulatorConfig, mode: str | None) -> int:
        """Start `config` (validated) in the loop; returns the generation it will have.

        Raises RunnerBusy when a run is starting or running.
        """
        with self._state_lock:
            snap = self.snapshot()
            busy = self._status(snap)
            if busy in ("starting", "running"):
                raise RunnerBusy(f"a scenario is already {busy}; stop it first")
            self._pending = "starting"
            self._pending_gen = snap["generation"] + 1
            self._send(("start", scenario, config, mode))
            return self._pending_gen

    def request_stop(self) -> None:
        self._send(("stop",))

    def request_reset(self, scenario: str, config: EmulatorConfig, mode: str | None) -> int:
        with self._state_lock:
            snap = self.snapshot()
            self._pending = "idle"
            self._pending_gen = snap["generation"] + 1
            self._send(("reset", scenario, config, mode))
            return self._pending_gen

    def post(self, command: Command) -> None:
        """Queue a Push / HandAnchor; the loop applies it before its next cycle.

        Raises RunnerBusy when nothing runs and ValueError for a bad satellite index.
        """
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

    def read(self, what: str, timeout_s: float = 60.0) -> Any:
        """'telemetry' -> (columns, rows) or 'metrics' -> dict, computed by the loop
        between two cycles."""
        req_id = next(self._ids)
        slot = [threading.Event(), None]
        self._waiting[req_id] = slot
        try:
            self._send(("read", req_id, what))
            if not slot[0].wait(timeout_s):
                raise RunnerError(f"no answer to {what!r} in {timeout_s:g} s")
            ok, payload = slot[1]
        finally:
            self._waiting.pop(req_id, None)
        if not ok:
            raise RunnerError(payload)
        return payload
