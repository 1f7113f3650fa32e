"""What the REST API and the viser GUI can ask of the emulator (one place, both use it).

Every request is validated completely before anything is handed to the runner, so a bad
request changes nothing.
"""

from __future__ import annotations

import copy
import math
import threading
import time
from concurrent.futures import Future
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from app.backend.downloads import DownloadWorker
from app.backend.memory import give_back_memory
from app.backend.ring import COUNTER_BYTES, RingSpaceError, check_ring_space, ring_bytes
from app.backend.runner import Runner, RunnerBusy
from app.config import ConfigError, EmulatorConfig, merge_overrides
from app.runs.preflight import PreflightRefused
from app.runs.store import DEFAULT_KEEP_RUNS, RunStore
from app.scenarios import load_scenario, scenario_descriptions, scenario_names
from app.sim.hand import HandAnchor, Push
from app.sim.scaling import scaling_of
from app.sim.telemetry import loop_columns

__all__ = ["EmulatorService", "RunnerBusy", "UnknownScenario", "InvalidRequest",
           "StopQueued", "StillStarting", "push_limit", "push_max_dv", "course_exit",
           "twist_limit", "push_max_dw"]

MAX_PUSH_FORCE_N = 100.0  # the F/T sensor's default range: no push is ever larger
MAX_PUSH_TORQUE_NM = 10.0  # the F/T sensor's default torque range: no twist is larger
NOISE_SIGMAS = 6.0
"""The push limit keeps this many standard deviations of the sensor's noise free: a
reading beyond 6 sigma on one of 3 axes at 500 Hz comes about once in a week."""
PUSH_END_MARGIN_S = 0.1
"""A push counts as pushing until this long (scenario time) after its end as the state
showed it: the state lags the loop by a few cycles."""
MAX_PUSH_DURATION_S = 5.0
CSV_CHUNK_ROWS = 2048
"""Rows read and formatted at a time for a CSV download."""
CSV_CACHE_BYTES = 16 << 20
"""The formatted CSV kept for the next reader (:class:`CsvChunks`): a 30 s one-arm run's."""
DEFAULT_TRACKING_ERROR_M = 0.05
"""``[loop] max_tracking_error_m``'s default, at which MAX_PUSH_DV_MPS was measured."""
COURSE_HORIZON_S = 60.0
"""A push may not bring the moment a satellite's course leaves its arm's safety volume or
reach any sooner within this long (or the run's time left, if shorter); the state warns
of a course that leaves within it (the operator has that long to brake it)."""
COURSE_STEP_S = 0.01
"""The predicted course is checked at this spacing (a satellite at 0.1 m/s moves 1 mm)."""
MOTION_MARGIN = 0.5
"""The push's velocity change may be this fraction of the smallest one measured to be
followed (benchmarks/push_follow.py)."""
MAX_PUSH_DV_MPS = 0.1
"""The largest velocity change (m/s, lab) the pushes under way on a satellite may give it
at ``[loop] max_tracking_error_m`` = 0.05 m (it scales with that bound): MOTION_MARGIN of
the smallest Δv an arm followed in benchmarks/push_follow.py."""
DEFAULT_TRACKING_ERROR_RAD = 0.25
"""``[loop] max_tracking_error_rad``'s default, at which MAX_PUSH_DW_RADPS was measured."""
MAX_PUSH_DW_RADPS = 0.24
"""The largest angular-velocity change (rad/s) the pushes under way on a satellite may give
it at ``[loop] max_tracking_error_rad`` = 0.25 rad (it scales with that bound):
MOTION_MARGIN of the smallest step the ceiling arm of free-floating followed less well,
0.48 rad/s about body x (attitude error 57 mrad, 1.3 mrad at 0.24 rad/s; about body z
0.75 rad/s kept it under 5 mrad) in benchmarks/twist_follow.py."""
FORECASTS_KEPT = 32
"""Forecasts kept (each the configuration's JSON and a small result): every scenario in
both modes, so that a page or client switching between them does not wait again."""
MAX_BAG_MESSAGES = 60_000
"""A bag from the web app holds at most about this many messages (~10 s to write here):
a long run's bag is thinned below the rate asked for. `run --bag` has no such bound."""


MAX_WEB_RING_BYTES = 128 << 20
"""The most telemetry a run of the web app keeps (its ring): /api/metrics and the zip's
metrics read it whole into the web process, whose memory it thus bounds."""


def check_web_ring(config: EmulatorConfig, mode: str | None) -> None:
    """InvalidRequest, naming loop.telemetry_capacity, for a ring over MAX_WEB_RING_BYTES."""
    size = ring_bytes(config, mode)
    if size > MAX_WEB_RING_BYTES:
        row_bytes = (size - COUNTER_BYTES) // config.loop.telemetry_capacity
        raise InvalidRequest(
            f"loop.telemetry_capacity: {config.loop.telemetry_capacity} rows of "
            f"{row_bytes // 8} values are {size / 2**20:.1f} MiB; the web app keeps at most "
            f"{MAX_WEB_RING_BYTES >> 20} MiB of a run's telemetry, "
            f"{(MAX_WEB_RING_BYTES - COUNTER_BYTES) // row_bytes} rows of this run "
            f"(a headless orbit-emulator run keeps every cycle, up to 1 GiB)")


class UnknownScenario(LookupError):
    pass


class InvalidRequest(ValueError):
    """A request that is well-formed JSON but invalid; the message names the field."""


class StopQueued(RuntimeError):
    """A stop sent to a stalled loop: it ends the run as soon as the loop runs again."""

    def __init__(self, message: str, state: dict) -> None:
        super().__init__(message)
        self.state = state


class StillStarting(RuntimeError):
    """A start whose run was still starting when the start request stopped waiting."""

    def __init__(self, message: str, state: dict) -> None:
        super().__init__(message)
        self.state = state


@dataclass(frozen=True)
class _PushRecord:
    """A push the service accepted (what the next push's checks count)."""

    generation: int
    satellite: int  # 1-based
    start_s: float  # scenario time as the state showed it at acceptance
    duration_s: float
    force_N: float  # magnitude
    dv_R: np.ndarray  # the velocity change it gives (R, lab m/s)
    torque_Nm: float = 0.0  # magnitude of its twist
    dw_radps: float = 0.0  # the most angular-velocity change it can give (rad/s)


def _start_settings(config: EmulatorConfig) -> dict[str, Any]:
    """The settings the page offers to change before a start, as the scenario has them."""
    return {"altitude_m": config.orbit.altitude_m,
            "velocity_mps": list(config.satellites[0].velocity_mps),
            "kp_lin": config.vfdm.kp_lin, "kp_rot": config.vfdm.kp_rot,
            "duration_s": config.loop.duration_s, "mode": config.loop.mode,
            "rails": config.rail_settings()}


class EmulatorService:
    """Builds emulators from scenarios + overrides and drives one :class:`Runner`."""

    def __init__(self, default_scenario: str | None = None, runs_dir: str | Path | None = None,
                 keep_runs: int = DEFAULT_KEEP_RUNS, max_run_bytes: int | None = None,
                 run_plots: bool = True, **runner_kwargs: Any) -> None:
        """``runs_dir``: where every run is written as it goes (app/runs/store.py; the
        newest ``keep_runs`` kept, and at most ``max_run_bytes`` of them; ``run_plots``
        False: their plots not drawn); None: not written."""
        names = scenario_names()
        self.default_scenario = default_scenario or (
            "collision" if "collision" in names else names[0]
        )
        self._build_lock = threading.Lock()
        self._forecast_lock = threading.Lock()
        self._forecasts: dict = {}
        """The pre-flight's ideal reference (with its forecast) per configuration and mode."""
        self._answers: dict = {}
        """What /forecast answered per configuration and mode."""
        self._preflight_lock = threading.Lock()
        self._preflights: dict = {}
        self.pending_start: tuple[str, str] | None = None
        """(scenario, mode) of a start in its pre-flight (seconds: the panels say so)."""
        config = load_scenario(self.default_scenario)
        self.last_config: EmulatorConfig = config
        self._last_run: tuple[str, EmulatorConfig, str | None] = (
            self.default_scenario, config, None)
        """(scenario, config, mode) of the last start or reset: what a reset restarts."""
        self.runner = Runner(config, scenario=self.default_scenario, **runner_kwargs)
        self._reads = SharedReads(self.state)
        self._worker = DownloadWorker()  # the zip and the bag are built in a process
        self._csv_chunks = CsvChunks(CSV_CACHE_BYTES)
        self._push_lock = threading.Lock()
        self._pushes: list[_PushRecord] = []
        """Every push accepted in the current run (their velocity changes add up; those
        under way, :meth:`_under_way`, also their forces)."""
        self._limits: tuple[Any, list[float]] = (None, [])
        self._reference: tuple[Any, dict | None] = (None, None)
        """(the ring of the run started last, the pre-flight's ideal collision it is
        compared with)."""
        self.recorder = None
        if runs_dir is not None:
            from app.backend.recorder import RunRecorder

            store = RunStore(runs_dir, keep_runs, max_run_bytes)
            self.recorder = RunRecorder(self.runner, store, self.metrics_for,
                                        draw_plots=run_plots)
            self.recorder.on_forecast = self._forecast_came

    # --- lifecycle ----------------------------------------------------------------------

    def start_thread(self) -> None:
        self.runner.start_thread()
        if self.recorder is not None:
            self.recorder.start()

    def shutdown(self) -> None:
        if self.recorder is not None:
            self.recorder.stop()
        self._worker.shutdown()
        self.runner.shutdown()

    # --- queries --------------------------------------------------------------------------

    @staticmethod
    def scenarios() -> list[dict[str, str]]:
        return [{"name": n, "description": d, "settings": _start_settings(load_scenario(n))}
                for n, d in scenario_descriptions().items()]

    def state(self) -> dict[str, Any]:
        """The loop's latest state; status "fault" with the reason while the loop process
        is dead or stalled."""
        snap = {**self.runner.snapshot(), "push_limits_N": self.push_limits_N(),
                "push_max_dv_mps": self.push_max_dv_mps(),
                "twist_limits_Nm": self.twist_limits_Nm(),
                "push_max_dw_radps": self.push_max_dw_radps()}
        fault = self.runner.fault()
        if fault is not None:
            snap.update(status="fault", reason=fault)
        if snap.get("interval"):
            snap["interval"] = self._with_systematic(snap)
        course = self._course_warnings(snap)
        unrecorded = None if self.recorder is None else self.recorder.warning()
        if unrecorded is not None:  # (a full disk, a runs folder gone or unwritable)
            course.append(unrecorded)
        if course:
            snap["warnings"] = [*snap.get("warnings", []), *course]
        return snap

    def _with_systematic(self, snap: dict) -> dict:
        """The loop's interval of the run of ``snap`` widened by the chain's systematic
        error from its forecast (app.runs.uncertainty.add_systematic; the noise's alone
        while the forecast is not known), as /api/metrics has it."""
        from app.runs.uncertainty import add_systematic

        ring, reference = self._reference
        forecast = (reference or {}).get("forecast") \
            if ring is not None and ring is self.runner.ring_of(snap) else None
        interval = copy.deepcopy(snap["interval"])
        add_systematic(interval, forecast)
        return interval

    def _course_warnings(self, state: dict) -> list[str]:
        """A warning per carried satellite of a running hil run whose force-free course
        leaves its arm's safety volume or reach within COURSE_HORIZON_S (or the run's time
        left): the run would stop unless a push brakes it."""
        if state.get("status") != "running" or state.get("mode") != "hil":
            return []
        horizon_s = min(COURSE_HORIZON_S, state["duration_s"] - state["t_s"])
        out = []
        for k in sorted({rob["satellite"] for rob in state.get("robots", [])}):
            try:
                exit_s, where = course_exit(state, self.last_config, k, np.zeros(3),
                                            horizon_s)
            except (KeyError, IndexError, ValueError):  # a state of another layout
                continue
            if exit_s <= horizon_s:
                out.append(f"satellite {k}'s course leaves {where.removeprefix('out of ')} in "
                           f"{exit_s:.1f} s: the run stops then unless a push brakes it")
        return out

    def push_limits_N(self) -> list[float]:
        """Each satellite's push limit in the current run (:func:`push_limit`)."""
        config = self.last_config
        if self._limits[0] is not config:
            self._limits = (config, [round(push_limit(config, i)[0], 3)
                                     for i in range(len(config.satellites))])
        return self._limits[1]

    def push_max_dv_mps(self) -> list[float]:
        """Each satellite's push velocity-change limit in the current run
        (:func:`push_max_dv`)."""
        config = self.last_config
        return [round(push_max_dv(config)[0], 4) for _ in config.satellites]

    def twist_limits_Nm(self) -> list[float]:
        """Each satellite's twist limit in the current run (:func:`twist_limit`)."""
        config = self.last_config
        return [round(twist_limit(config, i)[0], 3) for i in range(len(config.satellites))]

    def push_max_dw_radps(self) -> list[float]:
        """Each satellite's push angular-velocity-change limit in the current run
        (:func:`push_max_dw`)."""
        config = self.last_config
        return [round(push_max_dw(config)[0], 4) for _ in config.satellites]

    def _refuse_if_busy(self) -> None:
        """RunnerBusy while a healthy loop is starting or running a run (what
        request_start refuses too; a faulted loop is replaced, not busy)."""
        status = self.runner.status
        if status in ("running", "starting") and self.runner.fault() is None:
            raise RunnerBusy(f"a scenario is already {status}; stop it first")

    def _revive(self, config: EmulatorConfig, name: str, mode: str | None) -> None:
        """A dead or stalled loop process is replaced before a start or a reset."""
        if self.runner.fault() is not None:
            self.runner.restart(config, name, mode)

    def config_for(self, name: str, overrides: dict | None = None) -> EmulatorConfig:
        """Scenario `name` with `overrides` merged and validated (UnknownScenario /
        InvalidRequest)."""
        if name not in scenario_names():
            raise UnknownScenario(
                f"unknown scenario {name!r}; choose one of {scenario_names()}"
            )
        config = load_scenario(name)
        if overrides:
            if not isinstance(overrides, dict):
                raise InvalidRequest("body: config overrides must be a JSON object")
            try:
                config = merge_overrides(config, overrides)
            except ConfigError as err:
                raise InvalidRequest(str(err)) from None
            except (KeyError, IndexError, TypeError, AttributeError) as err:
                raise InvalidRequest(f"invalid configuration override: {err}") from None
        return config

    def build(self, name: str, overrides: dict | None = None, mode: str | None = None):
        """The validated config and mode of a run (what Emulator() would refuse, too)."""
        config = self.config_for(name, overrides)
        if mode is not None and mode not in ("hil", "ideal"):
            raise InvalidRequest(f"mode: must be 'hil' or 'ideal', got {mode!r}")
        if (mode or config.loop.mode) == "hil" and not config.robots:
            raise InvalidRequest("robots: hil mode needs at least one [[robots]] entry")
        check_web_ring(config, mode)
        try:
            check_ring_space(config, mode)
        except RingSpaceError as err:
            raise InvalidRequest(str(err)) from None
        return config, mode

    def preflight(self, config: EmulatorConfig, mode: str | None,
                  ) -> tuple[float | None, dict | None]:
        """Refuse a hil start whose predicted course leaves an arm's reach, safety volume
        or speed (app/runs/preflight.py; InvalidRequest naming the robot, time and
        limit); else (when the run keeps its snapshot for the restitution's interval,
        before the contact the prediction has, None: none; the pre-flight's ideal
        collision the run is compared with, as a headless run's: None without one)."""
        if (mode or config.loop.mode) != "hil":
            return None, None
        from app.runs.uncertainty import snapshot_time_s

        reference = self._checked_reference(config, mode)[0]
        if reference is None or len(config.satellites) < 2:
            return None, reference
        return snapshot_time_s(config, reference), reference

    def _checked_reference(self, config: EmulatorConfig, mode: str | None,
                           with_forecast: bool = False) -> tuple[dict | None, float]:
        """(the pre-flight's ideal collision reference, as a headless run computes it:
        app.runs.headless.checked_reference, with its ``forecast`` where asked or already
        computed; the seconds it took), cached per configuration and mode;
        InvalidRequest when the pre-flight refuses. A start does not wait for the
        forecast (seconds, minutes at a high loop rate): its metrics carry it when the
        page (or a client) asked for it before (/forecast)."""
        key = (config.model_dump_json(), mode)
        with self._forecast_lock:
            cached = self._forecasts.get(key)
        if cached is not None and (not with_forecast or not cached[0]  # (no contact)
                                   or "forecast" in cached[0]):
            return cached
        from app.runs.headless import checked_reference, collision_of, headless_config
        from app.runs.preflight import preflight

        t0 = time.perf_counter()
        duration = config.loop.duration_s
        try:  # sized as a headless run's, where that is valid; else the pre-flight
            sized = headless_config(config, duration)  # refuses it by name
        except ConfigError:
            sized = config
        try:
            if with_forecast:
                reference = checked_reference(sized, duration)
            else:  # the same without the forecast
                prediction = preflight(sized, duration)
                reference = None if len(config.satellites) < 2 or prediction is None \
                    else collision_of(prediction)
        except PreflightRefused as err:
            raise InvalidRequest(str(err)) from None
        with self._forecast_lock:
            while len(self._forecasts) >= FORECASTS_KEPT:  # the oldest goes
                del self._forecasts[next(iter(self._forecasts))]
            self._forecasts[key] = (reference, time.perf_counter() - t0)
            return self._forecasts[key]

    def _preflight_cached(self, config: EmulatorConfig, mode: str | None,
                          ) -> tuple[float | None, dict | None]:
        """preflight(), remembered per configuration and mode (the last 32; it takes 2 to
        9 s): a Start after the page's forecast of the same choice starts at once. A second
        asker of the same one waits for the first one's answer; others do not wait."""
        key = (config.model_dump_json(), mode or config.loop.mode)
        with self._preflight_lock:
            answer = self._preflights.get(key)
            mine = answer is None
            if mine:
                while len(self._preflights) >= FORECASTS_KEPT:  # the oldest goes
                    del self._preflights[next(iter(self._preflights))]
                answer = self._preflights[key] = Future()
        if mine:
            try:
                answer.set_result(self.preflight(config, mode))
            except InvalidRequest as err:  # a refusal is an answer too
                answer.set_exception(err)
            except BaseException as err:  # not one: the next asker tries again
                with self._preflight_lock:
                    self._preflights.pop(key, None)
                answer.set_exception(err)
                raise
        return answer.result()

    def _forecast_came(self, ideal: dict, forecast: dict) -> None:
        """The forecast of ideal collision ``ideal`` (computed after a run whose start did
        not wait for it): a copy of ``ideal`` with it takes its place everywhere the
        service keeps it (the reference of the run that is there, whose /api/metrics is
        computed anew; the forecasts' and pre-flights' caches), so that every copy of the
        run's metrics, and the next /forecast or Start of its configuration, have it.
        (A copy: other threads may be reading ``ideal``.)"""
        new = {**ideal, "forecast": forecast}
        with self._forecast_lock:
            for key, (reference, wall_s) in list(self._forecasts.items()):
                if reference is ideal:
                    self._forecasts[key] = (new, wall_s)
        with self._preflight_lock:
            for key, answer in list(self._preflights.items()):
                if answer.done() and answer.exception() is None \
                        and answer.result()[1] is ideal:
                    replaced = Future()
                    replaced.set_result((answer.result()[0], new))
                    self._preflights[key] = replaced
        with self._build_lock:  # (a start sets it under this lock)
            ring, reference = self._reference
            if reference is ideal:
                self._reference = (ring, new)
        self._reads.forget()

    def forecast(self, name: str, overrides: dict | None = None,
                 mode: str | None = None) -> dict[str, Any]:
        """Before Start: the pre-flight of scenario ``name`` as it would start, with the
        restitution's forecast spread (app/runs/uncertainty.py; ``collision_forecast`` None
        without a contact, or in ideal mode); refused as a start would be. Cached per
        configuration: the forecast takes seconds."""
        config, mode = self.build(name, overrides, mode)
        key = (config.model_dump_json(), mode)
        with self._forecast_lock:
            if key in self._answers:
                return self._answers[key]
        t0 = time.perf_counter()  # (the pre-flight of a start may have computed it)
        reference = None
        if (mode or config.loop.mode) == "hil":
            reference = self._checked_reference(config, mode, with_forecast=True)[0]
        answer = {"scenario": name, "mode": mode or config.loop.mode,
                  "collision_forecast": (reference or {}).get("forecast"),
                  "wall_s": time.perf_counter() - t0}
        self._preflight_cached(config, mode)  # the start's own check, ready for Start
        with self._forecast_lock:
            while len(self._answers) >= FORECASTS_KEPT:  # the oldest goes
                del self._answers[next(iter(self._answers))]
            return self._answers.setdefault(key, answer)

    # --- commands ---------------------------------------------------------------------

    def start(
        self, name: str, overrides: dict | None = None, mode: str | None = None,
        wait_s: float = 60.0,
    ) -> dict[str, Any]:
        """Start scenario `name`; returns the state once running (or finished: a run that
        ended before the answer), or the failure's state (status "error" or
        "safety_stop"). A hil start is pre-flighted whatever the loop's state: a faulted
        loop still shows its last status (say "running"), and the start replaces it.
        RunnerBusy when the run did not start after all: overtaken by a reset or another
        start, or stopped during its start-up; StillStarting after ``wait_s``."""
        with self._build_lock:
            config, mode = self.build(name, overrides, mode)  # 404 / 422 before 409
            self._refuse_if_busy()  # 409 before a pre-flight's seconds
            self.pending_start = (name, mode or config.loop.mode)
            try:
                snapshot_at_s, reference = self._preflight_cached(config, mode)
                if self.recorder is not None:
                    self.recorder.settle()  # the last run's rows, before a new loop
                self._revive(config, name, mode)
                gen = self.runner.request_start(name, config, mode, snapshot_at_s)
            finally:
                self.pending_start = None
            ring = self.runner.ring_of({"generation": gen})
            self._reference = (ring, reference)
            if self.recorder is not None and ring is not None:
                self.recorder.begin(ring, name, config, mode, reference, snapshot_at_s,
                                    generation=gen)
            self._csv_chunks.clear()  # a new run: the last one's CSV is let go
            self.last_config, self._last_run = config, (name, config, mode)
        # the loop publishes the new generation first as "starting", then running /
        # error / safety_stop; a stall on the way is waited through (the start goes on
        # when the loop does), a dead loop is a 503
        snap = self.runner.wait_for(
            lambda s: s["generation"] > gen or (s["generation"] == gen
                                                and s["status"] != "starting"),
            wait_s, through_stalls=True)
        if snap is None:
            raise StillStarting(
                f"scenario {name!r} is still starting after {wait_s:g} s; it runs when it "
                f"is ready (POST /api/stop ends it)", self.state())
        if snap["generation"] > gen:
            raise RunnerBusy(
                f"scenario {name!r} did not start: a reset or another start overtook it "
                f"(the emulator is now at run {snap['generation']}, status "
                f"{snap['status']!r})")
        if snap["status"] == "stopped":
            raise RunnerBusy(f"scenario {name!r} did not start: {snap['reason']}")
        return self.state()

    def stop(self) -> dict[str, Any]:
        """Stop the run; returns the state once stopped. To a stalled loop the stop is
        queued (StopQueued): the loop takes it first when it runs again, so a run never
        goes on after a stop; to a dead one LoopDown (nothing runs)."""
        stalled = self.runner.fault()
        self.runner.request_stop()
        if stalled is not None:
            raise StopQueued(
                f"{stalled}: the stop is queued and ends the run as soon as the loop "
                f"runs again (POST /api/reset replaces the loop process)", self.state())
        self.runner.wait_until(lambda s: s["status"] not in ("running", "starting"), 10.0,
                               through_stalls=True)
        return self.state()

    def reset(self, name: str | None = None, mode: str | None = None) -> dict[str, Any]:
        """Back to t = 0, idle: the scenario, settings and mode of the last start or reset
        (a name given: that scenario as its file has it, in ``mode``)."""
        with self._build_lock:
            if name is None:
                name, config, mode = self._last_run
            else:
                config, mode = self.build(name, mode=mode)
            if self.recorder is not None:
                self.recorder.settle()  # the run's last rows, before the reset ends it
            self._revive(config, name, mode)
            gen = self.runner.request_reset(name, config, mode)
            self._csv_chunks.clear()
            self.last_config, self._last_run = config, (name, config, mode)
        self.runner.wait_until(lambda s: s["generation"] >= gen, 10.0)
        return self.state()

    def push(self, satellite: int, force_N, duration_s: float,
             point_m=None, torque_Nm=None) -> dict[str, Any]:
        """A push on satellite `satellite` (1-based), force in R, at point_m (body axes,
        from the COM; the COM if None), with a twist torque_Nm (body axes, about the COM;
        none if None); validated here."""
        state = self.state()
        if state["status"] == "starting":  # the checks below need the run's own state
            raise RunnerBusy("the scenario is starting: push once it runs")
        force = validate_push(satellite, force_N, duration_s, state["n_satellites"])
        point = (0.0, 0.0, 0.0) if point_m is None else validate_point(
            point_m, state["layout"]["satellites"][satellite - 1][1])
        torque = (0.0, 0.0, 0.0) if torque_Nm is None else validate_torque(torque_Nm)
        with self._push_lock:  # the check and the record of a push, one at a time
            self._pushes = [p for p in self._pushes if p.generation == state["generation"]]
            self._within_push_limit(state, satellite, math.hypot(*force))
            if any(torque):
                self._within_twist_limit(state, satellite, torque, force, point)
            dv_R = self._push_dv_R(satellite, force, duration_s)
            dw = self._push_dw_radps(satellite, force, point, torque, duration_s)
            if any(torque):
                self._within_push_turn(state, satellite, dw, torque)
            self._within_push_motion(state, satellite, dv_R)
            self.runner.post(Push(satellite=satellite - 1, force_R_N=force,
                                  duration_s=duration_s, point_B_m=point,
                                  torque_B_Nm=torque))
            record = _PushRecord(state["generation"], satellite, state["t_s"], duration_s,
                                 math.hypot(*force), dv_R, math.hypot(*torque), dw)
            self._pushes.append(record)
        return {"satellite": satellite, "force_N": list(force), "duration_s": duration_s,
                "point_m": list(point), "torque_Nm": list(torque), "t_s": self.state()["t_s"]}

    def _within_twist_limit(self, state: dict, satellite: int, torque, force,
                            point) -> None:
        """InvalidRequest when this twist and those still twisting the same satellite, with
        the moment of this push's force about the sensor, would add up beyond its twist
        limit (:func:`twist_limit`): the F/T torque reading would clip, and the ODS would
        get less than the hand gave."""
        under_way = self._under_way(state, satellite)
        twisting = sum(p.torque_Nm for p in under_way)
        limit_Nm, why = twist_limit(self.last_config, satellite - 1)
        lever_m = _sensor_lever_m(self.last_config, satellite - 1) + math.hypot(*point)
        own_Nm = math.hypot(*torque) + math.hypot(*force) * lever_m
        if own_Nm + twisting > limit_Nm:
            moment = (f" (with its force's moment {math.hypot(*force) * lever_m:.2f} N m "
                      f"about the sensor)" if any(force) else "")
            already = f" with {twisting:.2f} N m already twisting it" if twisting else ""
            raise InvalidRequest(
                f"torque_Nm: magnitude {own_Nm:.2f} N m{moment}{already} exceeds satellite "
                f"{satellite}'s twist limit {limit_Nm:.2f} N m ({why})")

    def _push_dw_radps(self, satellite: int, force, point, torque,
                       duration_s: float) -> float:
        """The most angular-velocity change (rad/s) a push can give the ODS satellite:
        torque_scale (|torque| + |point| |force|) duration / its smallest principal moment
        of inertia (Eq. 7, a bound over the axes)."""
        config = self.last_config
        inertia = float(np.min(config.satellites[satellite - 1].principal_inertia()))
        moment = math.hypot(*torque) + math.hypot(*point) * math.hypot(*force)
        return scaling_of(config).torque_scale * moment * duration_s / inertia

    def _within_push_turn(self, state: dict, satellite: int, dw: float,
                          torque=(0.0, 0.0, 0.0)) -> None:
        """InvalidRequest when the push with a twist, with the pushes still under way on
        the satellite and the spin it has now, could turn it faster than its arm follows
        (:func:`push_max_dw`); a twist against its spin (slowing it) is let through.
        Only for a satellite an arm carries in a running run (hil)."""
        if state["status"] != "running" or state["mode"] != "hil" or not any(
                rob["satellite"] == satellite for rob in state["robots"]):
            return
        turning = sum(p.dw_radps for p in self._under_way(state, satellite))
        omega = np.asarray(state["satellites"][satellite - 1]["omega_radps"], float)
        spin = float(np.linalg.norm(omega))
        if spin > 0.0 and float(np.dot(omega, torque)) < 0.0:
            spin = 0.0  # against the spin: it slows the satellite first
        limit, why = push_max_dw(self.last_config)
        if dw + turning + spin > limit * (1.0 + 1e-9):
            already = f" with {turning:.3f} rad/s already under way" if turning else ""
            now = f" on top of its spin of {spin:.3f} rad/s" if spin else ""
            raise InvalidRequest(
                f"torque_Nm, duration_s: the push changes satellite {satellite}'s angular "
                f"velocity by up to {dw:.3f} rad/s{already}{now}, beyond its angular-"
                f"velocity limit {limit:.3f} rad/s ({why})")

    def _under_way(self, state: dict, satellite: int) -> list[_PushRecord]:
        """The run's pushes on ``satellite`` still under way (until PUSH_END_MARGIN_S
        after their end)."""
        return [p for p in self._pushes if p.satellite == satellite
                and p.start_s + p.duration_s + PUSH_END_MARGIN_S > state["t_s"]]

    def _within_push_limit(self, state: dict, satellite: int, force_N: float) -> None:
        """InvalidRequest when this push and those still pushing the same satellite would
        add up beyond its push limit (:func:`push_limit`)."""
        pushing = sum(p.force_N for p in self._under_way(state, satellite))
        limit_N, why = push_limit(self.last_config, satellite - 1)
        if force_N + pushing > limit_N:
            already = f" with {pushing:.1f} N already pushing it" if pushing else ""
            raise InvalidRequest(
                f"force_N: magnitude {force_N:.1f} N{already} exceeds satellite "
                f"{satellite}'s push limit {limit_N:.1f} N ({why})")

    def _push_dv_R(self, satellite: int, force, duration_s: float) -> np.ndarray:
        """The velocity change (R, lab m/s) a push gives the ODS satellite:
        force_scale F T / m (the ODS's law, app/sim/scaling.py)."""
        config = self.last_config
        per_N = scaling_of(config).force_scale / config.satellites[satellite - 1].mass_kg
        return per_N * duration_s * np.asarray(force, float)

    def _within_push_motion(self, state: dict, satellite: int, dv_R: np.ndarray) -> None:
        """InvalidRequest when the push would move the satellite beyond what its arm can
        follow (:func:`push_max_dv`, with the pushes still under way on it) or send its
        course out of its arm's safety volume or reach within the horizon
        (:func:`course_exit`) where it did not leave before. Only for a satellite an arm
        carries in a running run (hil): nothing else can stop on a push's motion."""
        if state["status"] != "running" or state["mode"] != "hil" or not any(
                rob["satellite"] == satellite for rob in state["robots"]):
            return
        under_way = self._under_way(state, satellite)
        dv = float(np.linalg.norm(dv_R))
        pushing = sum(float(np.linalg.norm(p.dv_R)) for p in under_way)
        limit, why = push_max_dv(self.last_config)
        if dv + pushing > limit * (1.0 + 1e-9):  # (a push at the limit, computed back)
            already = f" with {pushing:.3f} m/s already under way" if pushing else ""
            raise InvalidRequest(
                f"force_N, duration_s: the push changes satellite {satellite}'s velocity by "
                f"{dv:.3f} m/s{already}, beyond its velocity-change limit {limit:.3f} m/s "
                f"({why})")
        net_before = sum((p.dv_R for p in self._pushes if p.satellite == satellite),
                         np.zeros(3))
        net = float(np.linalg.norm(net_before + dv_R))
        if net > limit * (1.0 + 1e-9) and net > float(np.linalg.norm(net_before)):
            raise InvalidRequest(
                f"force_N, duration_s: the pushes of this run would change satellite "
                f"{satellite}'s velocity by {net:.3f} m/s together (their vector sum, "
                f"{float(np.linalg.norm(net_before)):.3f} m/s before this one), beyond its "
                f"velocity-change limit {limit:.3f} m/s ({why}); a push against them is "
                f"taken")
        t_s = state["t_s"]
        left_R = sum((p.dv_R * min(1.0, max(0.0, (p.start_s + p.duration_s - t_s)
                                                 / p.duration_s)) for p in under_way),
                     np.zeros(3))  # the part of the pushes under way still to come
        horizon_s = min(COURSE_HORIZON_S, state["duration_s"] - t_s)
        if horizon_s <= 0.0:
            return
        before_s, _ = course_exit(state, self.last_config, satellite, left_R, horizon_s)
        after_s, where = course_exit(state, self.last_config, satellite, left_R + dv_R,
                                     horizon_s)
        if after_s <= horizon_s and after_s < before_s - 0.5 * COURSE_STEP_S:
            sooner = "" if math.isinf(before_s) else f" (it left in {before_s:.1f} s before)"
            raise InvalidRequest(
                f"force_N, duration_s: the push sends satellite {satellite} {where} in "
                f"{after_s:.1f} s on its course (CW, from its state now){sooner}, within the "
                f"{horizon_s:.1f} s horizon ({COURSE_HORIZON_S:g} s or the run's time left): "
                f"the run would stop")

    def hand(self, satellite0: int, anchor_W_m, point_B_m=(0.0, 0.0, 0.0),
             attitude_W_wxyz=None) -> bool:
        """Gizmo: move the virtual hand of satellite `satellite0` (0-based), holding it at
        point_B_m (body axes, from the COM), turned to attitude_W_wxyz (the gizmo's
        orientation; None: no twist); None lets go. It presses and twists, never pulls
        (app/sim/hand.py)."""
        anchor = None if anchor_W_m is None else tuple(float(v) for v in anchor_W_m)
        point = tuple(float(v) for v in point_B_m)
        wxyz = None if attitude_W_wxyz is None else tuple(float(v) for v in attitude_W_wxyz)
        if anchor is not None and not all(math.isfinite(v) for v in anchor + point
                                          + (wxyz or ())):
            return False
        if wxyz is not None and (len(wxyz) != 4 or not any(wxyz)):
            return False
        return self.runner.post_nowait(HandAnchor(satellite=satellite0, anchor_W_m=anchor,
                                                  point_B_m=point, attitude_W_wxyz=wxyz))

    # --- heavier reads --------------------------------------------------------------------

    def exclusive(self, compute):
        """compute() in the heavy reads' turn: one at a time, so that many clients asking
        for big files cost one core at most (the other stays the loop's)."""
        return self._reads.exclusive(compute)

    def telemetry_csv(self):
        """The current run's telemetry CSV, as encoded chunks (the header first) for a
        streamed response: read from the shared ring CHUNK_ROWS rows at a time and
        formatted as they go, so that a download holds one chunk, never the whole text
        (a 1 GiB ring is gigabytes of text). Rows committed after the call are not in it."""
        from app.runs.report import csv_row_format

        snap = self.runner.snapshot()
        ring = self.runner.ring_of(snap)
        columns = ring.columns if ring is not None else loop_columns(
            len(snap["satellites"]), len(snap["robots"]))
        yield (",".join(columns) + "\n").encode()
        if ring is None:
            return
        fmt = csv_row_format(len(columns))
        cache = self._csv_chunks
        try:
            for k, (number, rows) in enumerate(ring.chunks(CSV_CHUNK_ROWS)):
                if k == 0:
                    cache.forget_before(ring.path, number)
                whole = len(rows) == CSV_CHUNK_ROWS  # (aligned: the same rows every read)
                data = cache.get(ring.path, number) if whole else None
                if data is None:
                    data = "".join(fmt % row for row in map(tuple, rows.tolist())).encode()
                    if whole:
                        cache.put(ring.path, number, data)
                yield data
        finally:
            give_back_memory()

    def _rows_of(self, snap: dict, ring, rows) -> tuple[list[str], np.ndarray]:
        """(columns, rows) of the current run; none yet before the first start."""
        if ring is not None:
            return ring.columns, rows
        columns = loop_columns(len(snap["satellites"]), len(snap["robots"]))
        return columns, np.empty((0, len(columns)))

    def metrics(self) -> dict[str, Any]:
        """The current run's metrics (computed here, from the shared ring and the state the
        loop published; the cycle times are those of its last 10 s)."""
        return self._reads.get("metrics", self._metrics)

    def _metrics(self, read=None) -> dict[str, Any]:
        snap, ring, _, rows = read or self.runner.run_telemetry()
        columns, rows = self._rows_of(snap, ring, rows)
        config = ring.config if ring is not None else self.last_config
        fault = self.runner.fault()  # a dead or stalled loop: its run is not "running"
        status = "fault" if fault is not None else snap["status"]
        error = fault if fault is not None else (
            snap.get("reason") if status == "error" else None)
        ideal = self._reference[1] if ring is not None and self._reference[0] is ring else None
        return self.metrics_for(snap, config, columns, rows, status, error, ideal)

    @staticmethod
    def metrics_for(snap: dict | None, config: EmulatorConfig, columns: list[str],
                    rows: np.ndarray, status: str, error: str | None,
                    ideal: dict | None) -> dict[str, Any]:
        """The metrics.json of a run of the loop: its rows, the last state it published
        (``snap``; None: none was seen), its status and error, and the ideal run's
        collision it is compared with (the pre-flight's, as a headless run's)."""
        from app.runs.metrics import RunFacts, metrics_of

        snap = snap or {}
        loop = snap.get("loop") or {"cycles": 0, "wall_s": 0.0}
        cycles = loop["cycles"]
        facts = RunFacts(
            mode=snap.get("mode", "hil" if any(c.startswith("rob") for c in columns)
                          else "ideal"),
            status=status, cycles=cycles, wall_s=loop["wall_s"],
            cycle_time_us={"p50": loop["cycle_time_us"]["p50"] if cycles else None,
                           "p99": loop["cycle_time_us"]["p99"] if cycles else None},
            safety_stop=snap.get("safety_stop"), passivity=snap.get("passivity"),
            arm_of={r["satellite"] - 1: k for k, r in enumerate(snap.get("robots", []))},
            capture=snap.get("capture"),
            error=error if status in ("error", "fault") else None)
        index = {name: k for k, name in enumerate(columns)}
        metrics = metrics_of(config, rows, index, facts, ideal)
        interval, coll = snap.get("interval"), metrics.get("collision")
        if interval and coll and coll["pair"] == interval["pair"] \
                and coll["restitution"] == interval["restitution"]:  # the loop's, after the run
            for key in ("restitution_sd", "restitution_interval_95", "uncertainty"):
                coll[key] = copy.deepcopy(interval[key])
            from app.runs.uncertainty import add_systematic

            add_systematic(coll, metrics.get("collision_forecast"))
        return metrics

    def run_archive(self) -> Path:
        """The current (or last) run to take home, as a zip file (the caller deletes it):
        telemetry.csv, metrics.json, summary.txt, config.json (the run's whole
        configuration, with its mode) and the plots of a headless run. Built one at a time
        (the heavy reads' turn) by a worker process of its own that reads the shared ring
        (app/backend/downloads.py): the web process holds neither the rows nor the zip."""
        metrics = self.metrics()  # (shared with /api/metrics; takes the turn itself)
        return self._reads.exclusive(lambda: self._run_archive(metrics))

    def _run_archive(self, metrics: dict) -> Path:
        from app.backend.downloads import build_archive, temporary_zip

        snap, config, columns, ring = self._download_source()
        path = temporary_zip("orbit-emulator-run-")
        try:
            self._worker.run(build_archive, str(path), snap, config, columns, ring, metrics)
        except BaseException:
            path.unlink(missing_ok=True)
            raise
        return path

    def run_bag(self, rate_hz: float) -> tuple[Path, float]:
        """The current (or last) run as a ROS 2 bag (MCAP; app/runs/bag.py), zipped into a
        temporary file (the caller deletes it), and the rate it was written at: at most
        rate_hz messages per topic and second of scenario time, and fewer where the run is
        long (:data:`MAX_BAG_MESSAGES`). Built one at a time (the heavy reads' turn) by a
        worker process, as the zip: a bag costs ~0.15 ms a message."""
        return self._reads.exclusive(lambda: self._run_bag(rate_hz))

    def _run_bag(self, rate_hz: float) -> tuple[Path, float]:
        from app.backend.downloads import build_bag, temporary_zip

        snap, config, columns, ring = self._download_source()
        path = temporary_zip("orbit-emulator-bag-")
        try:
            written_hz = self._worker.run(build_bag, str(path), snap, config, columns, ring,
                                          rate_hz, MAX_BAG_MESSAGES)
        except BaseException:
            path.unlink(missing_ok=True)
            raise
        return path, written_hz

    def stored_bag(self, folder: Path, rate_hz: float) -> tuple[Path, float]:
        """A run kept on disk (its folder) as a ROS 2 bag, zipped into a temporary file
        (the caller deletes it), and the rate written (as :meth:`run_bag`, from its
        telemetry.csv: app/backend/downloads.py build_stored_bag); built by the download
        worker in the heavy reads' turn."""
        from app.backend.downloads import build_stored_bag, temporary_zip

        def build() -> tuple[Path, float]:
            path = temporary_zip("orbit-emulator-bag-")
            try:
                return path, self._worker.run(build_stored_bag, str(path), str(folder),
                                              rate_hz, MAX_BAG_MESSAGES)
            except BaseException:
                path.unlink(missing_ok=True)
                raise
        return self._reads.exclusive(build)

    def _download_source(self):
        """(state, config, columns, the ring's file or None) of the current run."""
        snap = self.runner.snapshot()
        ring = self.runner.ring_of(snap)
        if ring is None:
            columns = loop_columns(len(snap["satellites"]), len(snap["robots"]))
            return snap, self.last_config, columns, None
        return snap, ring.config, ring.columns, ring.reader()


class CsvChunks:
    """The formatted CSV of the newest whole chunks of one ring, up to ``budget`` bytes:
    eight clients polling the CSV of a 30 s run format only the rows new since the last
    read, not the whole ring each, and the memory it costs stays bounded (the oldest
    chunks go first; a read of another ring, or clear(), empties it)."""

    def __init__(self, budget: int) -> None:
        self.budget = budget
        self._lock = threading.Lock()
        self._ring: str | None = None
        self._chunks: dict[int, bytes] = {}
        self._bytes = 0

    def clear(self) -> None:
        with self._lock:
            self._ring, self._chunks, self._bytes = None, {}, 0

    def get(self, ring: str, number: int) -> bytes | None:
        with self._lock:
            return self._chunks.get(number) if ring == self._ring else None

    def forget_before(self, ring: str, number: int) -> None:
        """Let go of the chunks before row ``number``: the ring no longer streams them
        (it wrapped), so no read will ask for them again."""
        with self._lock:
            if ring == self._ring:
                for old in [k for k in self._chunks if k < number]:
                    self._bytes -= len(self._chunks.pop(old))

    def put(self, ring: str, number: int, data: bytes) -> None:
        with self._lock:
            if ring != self._ring:
                self._ring, self._chunks, self._bytes = ring, {}, 0
            if number in self._chunks or len(data) > self.budget:
                return
            self._chunks[number] = data
            self._bytes += len(data)
            while self._bytes > self.budget:  # the oldest rows go first
                self._bytes -= len(self._chunks.pop(min(self._chunks)))


class SharedReads:
    """The heavy reads (metrics, telemetry CSV), computed one at a time and shared.

    One at a time: on a two-core machine the other core stays the loop's, whatever the
    number of clients. Shared: a client that asks while the run is in the same state
    (generation and status) gets the last answer if no cycle ran since, or if it is at most
    ``max_age_s`` old; a run that finished, stopped or was replaced is computed anew, so
    its last rows are never missed. Eight clients polling cost about one computation per
    ``max_age_s``, and hold one answer in memory, not eight.
    """

    def __init__(self, snapshot, max_age_s: float = 0.5) -> None:
        self._snapshot = snapshot
        self.max_age_s = max_age_s
        self._lock = threading.Lock()
        self._last: dict[str, tuple] = {}

    def exclusive(self, compute):
        """compute() in the heavy reads' turn (one at a time), not kept."""
        with self._lock:
            try:
                return compute()
            finally:
                give_back_memory()

    def forget(self) -> None:
        """The answers kept are computed anew at the next ask (what they are computed
        from changed without a cycle: a run's forecast came after it)."""
        with self._lock:
            self._last.clear()

    def get(self, name: str, compute):
        with self._lock:
            snap = self._snapshot()
            state, cycles = (snap["generation"], snap["status"]), snap["loop"]["cycles"]
            now = time.monotonic()
            last = self._last.get(name)
            if last is not None and last[0] == state and (
                    last[1] == cycles or now - last[2] <= self.max_age_s):
                return last[3]
            try:
                value = compute()
            finally:
                give_back_memory()
            self._last[name] = (state, cycles, now, value)
            return value


def validate_point(point_m, size_m) -> tuple[float, float, float]:
    """A point of a satellite's box (body axes, from its COM), or InvalidRequest."""
    if len(point_m) != 3:
        raise InvalidRequest("point_m: must have 3 components")
    point = tuple(float(v) for v in point_m)
    if not all(math.isfinite(v) for v in point):
        raise InvalidRequest("point_m: must be finite numbers")
    half = [0.5 * float(s) for s in size_m]
    if any(abs(p) > h + 1e-9 for p, h in zip(point, half, strict=True)):
        raise InvalidRequest(
            f"point_m: {list(point)} is outside the satellite's box: each coordinate within "
            f"+-{[round(h, 6) for h in half]} m of its COM")
    return point


def push_limit(config: EmulatorConfig, satellite0: int) -> tuple[float, str]:
    """(the largest force (N) the pushes on satellite ``satellite0`` may add up to, how it
    was derived). A raw F/T force reading at the sensor's range stops the run
    (``[loop] stop_at_sensor_range``); on one axis of the sensor that carries the mockup
    the reading is at most |push| + m·g + |bias| + noise + the hand's force + the scripted
    pulses', so the pushes get the range less the mockup's weight, the bias,
    NOISE_SIGMAS standard deviations of noise, the operator's hand at its cap (``[hand]
    max_force_N``: it may press at any time) and the most the scenario's ``[[pulses]]``
    push that satellite at once. Never negative."""
    from app.sim.scaling import mockup_mass_kg

    sensor, satellite = config.sensor, config.satellites[satellite0]
    weight_N = mockup_mass_kg(satellite, config) * float(
        np.linalg.norm(config.lab.gravity_mps2))
    bias_N = float(np.linalg.norm(sensor.bias_force_N))
    noise_N = NOISE_SIGMAS * sensor.noise_force_N
    hand_N = config.hand.max_force_N
    pulses_N = _most_pulses_at_once_N(config, satellite.name)
    limit_N = max(0.0, sensor.range_force_N - weight_N - bias_N - noise_N - hand_N
                  - pulses_N)
    why = (f"the F/T sensor's {sensor.range_force_N:g} N range less the mockup's weight "
           f"{weight_N:.1f} N, the bias {bias_N:.1f} N, {NOISE_SIGMAS:g} sigma of noise "
           f"{noise_N:.1f} N" + (f", the scripted pulses' {pulses_N:.1f} N" if pulses_N
                                 else "") + f" and the hand's {hand_N:g} N")
    return limit_N, why


def _sensor_lever_m(config: EmulatorConfig, satellite0: int) -> float:
    """How far the satellite's COM is from the F/T sensor of the arm that carries it (its
    ``mockup_offset_m``; 0 for a satellite no arm carries)."""
    name = config.satellites[satellite0].name
    return max((math.hypot(*r.mockup_offset_m) for r in config.robots
                if r.satellite == name), default=0.0)


def twist_limit(config: EmulatorConfig, satellite0: int) -> tuple[float, str]:
    """(the largest torque (N m) the twists of the pushes on satellite ``satellite0`` may
    add up to, with their forces' moments about the sensor, how it was derived). Beyond
    the F/T sensor's torque range a reading clips: the range less the mockup's weight's
    moment (m g times the COM's lever from the sensor), the torque bias, NOISE_SIGMAS
    standard deviations of noise, the gizmo's twist at its cap (``[hand] max_torque_Nm``)
    and its press at its cap at the farthest point of the box (``[hand] max_force_N``
    times the lever plus the half diagonal). Never negative."""
    from app.sim.scaling import mockup_mass_kg

    sensor, satellite = config.sensor, config.satellites[satellite0]
    lever_m = _sensor_lever_m(config, satellite0)
    weight_Nm = mockup_mass_kg(satellite, config) * float(
        np.linalg.norm(config.lab.gravity_mps2)) * lever_m
    bias_Nm = float(np.linalg.norm(sensor.bias_torque_Nm))
    noise_Nm = NOISE_SIGMAS * sensor.noise_torque_Nm
    reach_m = lever_m + 0.5 * float(np.linalg.norm(satellite.size_m))
    hand_Nm = config.hand.max_torque_Nm + config.hand.max_force_N * reach_m
    limit = max(0.0, sensor.range_torque_Nm - weight_Nm - bias_Nm - noise_Nm - hand_Nm)
    why = (f"the F/T sensor's {sensor.range_torque_Nm:g} N m range less the mockup's weight's "
           f"moment {weight_Nm:.2f} N m, the bias {bias_Nm:.2f} N m, {NOISE_SIGMAS:g} sigma "
           f"of noise {noise_Nm:.2f} N m and the hand's {hand_Nm:.2f} N m")
    return limit, why


def push_max_dw(config: EmulatorConfig) -> tuple[float, str]:
    """(the largest angular-velocity change (rad/s) the pushes under way on a carried
    satellite may add up to, how it was derived): MAX_PUSH_DW_RADPS, measured at the
    default ``[loop] max_tracking_error_rad`` (0.25 rad), scaled with the run's."""
    bound_rad = config.loop.max_tracking_error_rad
    limit = MAX_PUSH_DW_RADPS * bound_rad / DEFAULT_TRACKING_ERROR_RAD
    why = (f"{MOTION_MARGIN:g} of the smallest angular-velocity step an arm followed less "
           f"well, scaled to the {1e3 * bound_rad:g} mrad attitude bound, "
           f"benchmarks/twist_follow.py; the change is at most torque_scale x (|torque| + "
           f"|point| |force|) x duration / the smallest moment of inertia")
    return limit, why


def _most_pulses_at_once_N(config: EmulatorConfig, name: str) -> float:
    """The largest sum of the force magnitudes of the ``[[pulses]]`` on satellite `name`
    that act at the same time."""
    events = sorted((t, sign * math.hypot(*p.force_N))  # an end before a start at one t
                    for p in config.pulses if p.satellite == name
                    for t, sign in ((p.start_s, 1.0), (p.end_s, -1.0)))
    most = total = 0.0
    for _, change in events:
        total += change
        most = max(most, total)
    return most


def push_max_dv(config: EmulatorConfig) -> tuple[float, str]:
    """(the largest velocity change (lab m/s) the pushes under way on a carried satellite
    may add up to, how it was derived): MAX_PUSH_DV_MPS, measured at the default
    ``[loop] max_tracking_error_m`` (0.05 m), scaled with the run's (the arm's lag turns a
    velocity step into a proportional tracking error)."""
    bound_m = config.loop.max_tracking_error_m
    limit = MAX_PUSH_DV_MPS * bound_m / DEFAULT_TRACKING_ERROR_M
    why = (f"{MOTION_MARGIN:g} of the smallest velocity change an arm followed within "
           f"the {1e3 * bound_m:g} mm tracking-error bound, benchmarks/push_follow.py; "
           f"the change is force_scale x |force| x duration / mass")
    return limit, why


def course_exit(state: dict, config: EmulatorConfig, satellite: int, dv_R,
                horizon_s: float) -> tuple[float, str]:
    """(when the course of satellite `satellite` (1-based) first leaves the safety volume
    or the reach (HOLD_RADIUS_M from the shoulder) of an arm that carries it, within
    horizon_s, inf if it does not; what it leaves). The course: force-free CW in lab units
    (the ODS's own dynamics at the lab orbit rate k_T Omega: a straight line bends within
    seconds where the time is scaled), from the ODS state of the latest snapshot with
    dv_R (R, m/s) added now, sampled every COURSE_STEP_S."""
    from app.sim.orbital import cw_course_m, orbit_rate
    from app.sim.ur10e import HOLD_RADIUS_M, SHOULDER_B_M

    sat = state["satellites"][satellite - 1]
    W = scaling_of(config).orbit_rate_lab(orbit_rate(config.orbit.altitude_m))
    t = np.arange(0.0, horizon_s + COURSE_STEP_S, COURSE_STEP_S)
    course_R = cw_course_m(W, sat["position_m"], np.asarray(sat["velocity_mps"]) + dv_R, t)
    T_W_R = np.asarray(state["layout"]["T_W_R"])
    course_W = course_R @ T_W_R[:3, :3].T + T_W_R[:3, 3]
    first, where = np.inf, ""
    layout = state["layout"]
    for k, rob in enumerate(state["robots"]):
        if rob["satellite"] != satellite:
            continue
        lo, hi = (np.asarray(b) for b in layout["safety_boxes_W_m"][k])
        T_W_B = np.asarray(layout["arms"][k][1])
        shoulder_W = T_W_B[:3, :3] @ np.asarray(SHOULDER_B_M) + T_W_B[:3, 3]
        for out, name in (
                (np.any((course_W < lo) | (course_W > hi), axis=1),
                 f"out of {rob['name']}'s safety volume"),
                (np.linalg.norm(course_W - shoulder_W, axis=1) > HOLD_RADIUS_M,
                 f"out of {rob['name']}'s reach ({HOLD_RADIUS_M:g} m from its shoulder)")):
            if out.any() and t[np.argmax(out)] < first:
                first, where = float(t[np.argmax(out)]), name
    return first, where


def validate_torque(torque_Nm) -> tuple[float, float, float]:
    """A twist (N m, body axes) within the sensor's torque range, or InvalidRequest."""
    if len(torque_Nm) != 3:
        raise InvalidRequest("torque_Nm: must have 3 components")
    torque = tuple(float(v) for v in torque_Nm)
    if not all(math.isfinite(v) for v in torque):
        raise InvalidRequest("torque_Nm: must be finite numbers")
    norm = math.hypot(*torque)
    if norm > MAX_PUSH_TORQUE_NM:
        size = f"{norm:.2f} N m" if norm < 1e6 else (
            f"{norm:.3g} N m" if math.isfinite(norm) else "over 1e308 N m")
        raise InvalidRequest(f"torque_Nm: magnitude {size} exceeds the sensor range "
                             f"{MAX_PUSH_TORQUE_NM:g} N m")
    return torque


def validate_push(satellite, force_N, duration_s, n_satellites: int) -> tuple[float, ...]:
    if isinstance(satellite, bool) or not isinstance(satellite, int):
        raise InvalidRequest("satellite: must be an integer (1-based)")
    if not 1 <= satellite <= n_satellites:
        raise InvalidRequest(
            f"satellite: must be between 1 and {n_satellites}, got {satellite}"
        )
    if len(force_N) != 3:
        raise InvalidRequest("force_N: must have 3 components")
    force = tuple(float(v) for v in force_N)
    if not all(math.isfinite(v) for v in force):
        raise InvalidRequest("force_N: must be finite numbers")
    norm = math.hypot(*force)  # (no overflow where the plain sum of squares would)
    if norm > MAX_PUSH_FORCE_N:
        size = f"{norm:.1f} N" if norm < 1e6 else (
            f"{norm:.3g} N" if math.isfinite(norm) else "over 1e308 N")
        raise InvalidRequest(
            f"force_N: magnitude {size} exceeds the sensor range {MAX_PUSH_FORCE_N:g} N"
        )
    if not (math.isfinite(duration_s) and 0.0 < duration_s <= MAX_PUSH_DURATION_S):
        raise InvalidRequest(
            f"duration_s: must be in (0, {MAX_PUSH_DURATION_S:g}] s, got {duration_s}"
        )
    return force
