"""The loop process: the Emulator runs paced at its loop rate in a process of its own.

:class:`LoopCore` owns the Emulator (see :mod:`app.backend.runner` for why a process, and
for :class:`~app.backend.runner.Runner`, its proxy in the web process). It

* polls the command pipe between cycles: commands (:class:`~app.sim.hand.Push`,
  :class:`~app.sim.hand.HandAnchor`) go to ``Emulator.post``, control requests (start /
  stop / reset) begin or end a run;
* publishes a snapshot (a plain dict) every ``snapshot_every`` cycles through the shared
  memory channel of :mod:`app.backend.snapshots`;
* records each cycle's telemetry row into the run's ring in shared memory
  (:mod:`app.backend.ring`), which the web process reads without asking.

Pacing: cycle k is due to start at ``t0 + k·dt`` and must finish by ``t0 + (k+1)·dt``
(its deadline); a cycle that finishes later is a deadline miss. The loop sleeps until
``spin_s`` before the next start, then spins. When it falls more than ``max_lag_s``
behind (a stalled machine) it drops the backlog and restarts the schedule from now
instead of running a burst of catch-up cycles (counted in ``resyncs``).

:func:`_loop_main` is the process entry point.
"""

from __future__ import annotations

import logging
import os
import select
import time
import traceback
from collections.abc import Callable
from multiprocessing import shared_memory
from typing import Any

import numpy as np

from app.backend import snapshots
from app.backend.ring import attach_ring
from app.backend.snapshots import SnapshotWriter
from app.config import EmulatorConfig
from app.runs.metrics import noise_spin_warnings, passivity_metrics
from app.runs.uncertainty import run_interval
from app.sim.loop import Emulator
from app.sim.rotations import matrix_to_quat, quat_to_matrix
from app.sim.scaling import scaling_of, summary_line

log = logging.getLogger("orbit_emulator.runner")

_TIMING_WINDOW = 5000  # cycles kept for the p50 / p99 of the cycle time (10 s at 500 Hz)


class _StartInterrupted(Exception):
    """A stop, reset, start or shutdown arrived while a run was starting."""


class LoopCore:
    """Runs in the loop process: owns the Emulator, paces it, answers requests."""

    def __init__(self, cmd_conn, shm_name: str, config: EmulatorConfig,
                 scenario: str, mode: str, settings: dict) -> None:
        self.cmd_conn = cmd_conn
        self.shm = shared_memory.SharedMemory(name=shm_name)
        self.writer = SnapshotWriter(self.shm)
        self._beats = 0
        self._warned_em, self._warnings = None, []
        self._static_em, self._static = None, {}
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
        self.interval: dict | None = None
        """The last run's restitution interval (app/runs/uncertainty.py), once computed."""
        self.shutdown = False
        self._pending: tuple | None = None  # a control message that interrupted a start
        self._rings: list = []  # the telemetry rings mapped (the current run's last)
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

    def beat(self) -> None:
        """Tell the web process the loop is alive (it watches this; app/backend/runner.py)."""
        self._beats += 1
        snapshots.beat(self.shm.buf, self._beats)

    def serve(self) -> None:
        try:
            while not self.shutdown:
                self.beat()
                if self._pending is not None:
                    msg, self._pending = self._pending, None
                    self.handle(msg)
                elif self.cmd_conn.poll(0.05 if self.status != "running" else 0):
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
            _, scenario, config, mode, ring, snapshot_at_s = msg
            self.begin(scenario, config, mode, prepare=True, ring=ring,
                       snapshot_at_s=snapshot_at_s)
        elif kind == "reset":
            _, scenario, config, mode, ring = msg
            self.begin(scenario, config, mode, prepare=False, ring=ring)
        elif kind == "stop":
            if self.status in ("running", "starting"):
                if self.em.status == "running":
                    self.em.status = "stopped"
                    self.em.record_final()
                self.status, self.reason = "stopped", "stopped by the operator"
                self.publish()
        elif kind == "shutdown":
            self.shutdown = True

    def begin(self, scenario: str, config: EmulatorConfig, mode: str | None,
              prepare: bool, ring: str | None = None,
              snapshot_at_s: float | None = None) -> None:
        """A new run (``ring``: the name of its telemetry ring in shared memory;
        ``snapshot_at_s``: when it keeps a snapshot for the restitution's interval)."""
        self.status = "starting" if prepare else "idle"
        self.reason = None
        self.generation += 1
        self.interval = None
        try:
            em = Emulator(config, mode=mode)
            if em.mode == "hil":
                em.snapshot_at_s = snapshot_at_s
            if ring is not None:
                shm, data, counters = attach_ring(ring, em.telemetry.capacity,
                                                  len(em.telemetry.columns))
                em.telemetry.use_storage(data, counters)
                del data, counters
        except Exception as err:
            self.fail(err)
            return
        self.scenario, self.em = scenario, em
        self._switch_ring(shm if ring is not None else None)
        self._reset_timing()
        self.publish()
        if not prepare:
            return
        try:
            em.prepare(tick=self._starting_tick)
        except _StartInterrupted:
            em.status = "stopped"
            self.status, self.reason = "stopped", "stopped by the operator during start-up"
            self.publish()
            return
        except Exception as err:
            self.fail(err)
            return
        if em.status == "running":
            self.status = "running"
        else:
            self.status = em.status
            self.reason = (em.safety_stop or {}).get("reason")
        self.publish()

    def _switch_ring(self, shm) -> None:
        """Keep the new run's ring mapped; unmap the old ones once nothing uses them."""
        keep = []
        for old in self._rings:
            try:
                old.close()
            except BufferError:  # still viewed (an old emulator not yet collected)
                keep.append(old)
        self._rings = keep + ([shm] if shm is not None else [])

    def _starting_tick(self) -> None:
        """Called now and then while a run starts (Emulator.prepare): the heartbeat,
        and a stop, reset, start or shutdown ends the start-up at once (a start
        or reset is then handled as if it had come after)."""
        self.beat()
        while self.cmd_conn.poll():
            msg = self.cmd_conn.recv()
            if msg[0] in ("stop", "reset", "start", "shutdown"):
                if msg[0] != "stop":
                    self._pending = msg
                raise _StartInterrupted
            # a command ("cmd") for a run that is not running yet is dropped

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
        poll = readable(self.cmd_conn)
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
            self.beat()
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
                em.record_final()
                self.status = em.status
                if em.safety_stop:
                    self.reason = em.safety_stop.get("reason")
                self.publish()
                self._interval(em)
                return
            if n % self.snapshot_every == 0:
                self.publish()

    def _interval(self, em: Emulator) -> None:
        """After a run, outside its paced cycles: the restitution's interval from the
        replicates of its contact (app/runs/uncertainty.py; a second or two, with the
        heartbeat between replicates), published as ``interval``."""
        if em.snapshot is None or em.status not in ("finished", "safety_stop"):
            return
        try:
            self.interval = run_interval(em, tick=self.beat)
        except Exception:  # noqa: BLE001 - the run's record matters more than its interval
            log.exception("the restitution's interval failed")
            self.interval = None
        if self.em is em:
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

    def _config_warnings(self, em: Emulator) -> list[str]:
        """What the operator must read before Start (computed once per emulator): a hil
        run's satellites that the F/T noise can spin (app/runs/metrics.py, as the CLI warns)."""
        if self._warned_em is not em:
            carried = [a.satellite for a in em.arms]
            self._warnings = (noise_spin_warnings(em.config, carried)
                              if em.mode == "hil" else [])
            self._warned_em = em
        return self._warnings

    def _static_parts(self, em: Emulator) -> dict[str, dict]:
        """The snapshot's parts that follow from the emulator's configuration alone (the
        panels' settings, the layout but the arms' bases): built once per emulator, not
        at every publish (they were 30 % of building one: 44 of 150 µs)."""
        if self._static_em is not em:
            cfg = em.config
            scaling = scaling_of(cfg)
            self._static = {
                "settings": {  # what the panels show (the run's, whoever started it)
                    "altitude_m": cfg.orbit.altitude_m,
                    "velocity_mps": list(cfg.satellites[0].velocity_mps),
                    "kp_lin": cfg.vfdm.kp_lin, "kp_rot": cfg.vfdm.kp_rot,
                    "duration_s": cfg.loop.duration_s,
                    "hand_stiffness_Npm": cfg.hand.stiffness_Npm,
                    "hand_max_force_N": cfg.hand.max_force_N,
                    "hand_twist_Nmprad": cfg.hand.twist_stiffness_Nmprad,
                    "hand_max_torque_Nm": cfg.hand.max_torque_Nm,
                    "deadband_force_N": cfg.wrench.deadband_force_N,
                    "deadband_torque_Nm": cfg.wrench.deadband_torque_Nm,
                    "satellite1_mass_kg": cfg.satellites[0].mass_kg,
                    "satellite1_inertia_kgm2": [float(v) for v in
                                                cfg.satellites[0].principal_inertia()],
                    "force_scale": scaling.force_scale, "torque_scale": scaling.torque_scale,
                    "scaling": summary_line(cfg),
                    "rails": cfg.rail_settings(),
                },
                "layout": {
                    "T_W_R": em.T_W_R.tolist(),
                    "rails_W_m": [_rail_ends_W(cfg.robots[a.index]) for a in em.arms],
                    "safety_boxes_W_m": [[list(cfg.robots[a.index].safety_box_min_m),
                                          list(cfg.robots[a.index].safety_box_max_m)]
                                         for a in em.arms],
                    "satellites": [[s.name, list(s.size_m), s.material]
                                   for s in cfg.satellites],
                },
            }
            self._static_em = em
        return self._static

    def build_snapshot(self) -> dict[str, Any]:
        em = self.em
        ods = em.ods
        cfg = em.config
        static = self._static_parts(em)
        layout = static["layout"]
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
                "applied_torque_Nm": em.applied_torque_B[i].tolist(),
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
                # none before the first cycle: the arm has not moved its mockup there yet
                "tracking_error_m": float(np.linalg.norm(p_R - ods.position_m[arm.satellite]))
                if self.cycle_count else None,
                "ft_raw": arm.last_raw_S.tolist(),
                "ft_processed": arm.last_processed.tolist(),
                # where the base is (it moves with a rail's carriage)
                "base_position_W_m": arm.T_W_B[:3, 3].tolist(),
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
            "settings": static["settings"],
            "n_satellites": em.n_sat,
            "satellites": sats,
            "robots": robots,
            "contact_active": bool(em.contact_active),
            "capture": em.capture_event,
            "passivity": passivity_metrics(em),
            "interval": self.interval,
            "warnings": self._config_warnings(em),
            "layout": {
                "T_W_R": layout["T_W_R"],
                # the bases move with their rails' carriages
                "arms": [[cfg.robots[a.index].name, a.T_W_B.tolist()] for a in em.arms],
                "rails_W_m": layout["rails_W_m"],
                "safety_boxes_W_m": layout["safety_boxes_W_m"],
                "satellites": layout["satellites"],
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


def readable(conn) -> Callable[[], bool]:
    """``conn.poll()`` for the paced loop: whether a message (or the pipe's end) waits, by
    one poll(2) on a poller registered once (0.5 µs; ``Connection.poll`` builds a selector
    at every call, 7 µs, and the loop asks every cycle). An end of the pipe or an error
    reads as readable, so that ``recv`` raises as it would after ``Connection.poll``."""
    poller = select.poll()
    poller.register(conn.fileno(), select.POLLIN)
    return lambda: bool(poller.poll(0))


def _rail_ends_W(robot) -> list | None:
    """The two ends of the line a robot's base travels on its rail (W), or None."""
    if robot.rail is None:
        return None
    p0, axis = np.asarray(robot.base_position_m), np.asarray(robot.rail.axis_W)
    return [(p0 + s * axis).tolist() for s in robot.rail.travel_m]


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


def _loop_main(cmd_conn, shm_name, config, scenario, mode, settings) -> None:
    logging.basicConfig(level=logging.INFO, format="%(levelname)s loop: %(message)s")
    core = LoopCore(cmd_conn, shm_name, config, scenario, mode, settings)
    core.serve()
