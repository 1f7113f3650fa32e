"""What the REST API and the viser GUI can ask of the emulator (one place, both use it).

Every request is validated completely before anything is handed to the runner, so a bad
request changes nothing.
"""

from __future__ import annotations

import math
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from app.backend.downloads import DownloadWorker
from app.backend.ring import COUNTER_BYTES, RingSpaceError, check_ring_space, ring_bytes
from app.backend.runner import Runner, RunnerBusy
from app.config import ConfigError, EmulatorConfig, merge_overrides
from app.preflight import PreflightRefused, preflight
from app.scenarios import load_scenario, scenario_descriptions, scenario_names
from app.sim.hand import HandAnchor, Push
from app.sim.telemetry import loop_columns

__all__ = ["EmulatorService", "RunnerBusy", "UnknownScenario", "InvalidRequest"]

MAX_PUSH_FORCE_N = 100.0  # the F/T sensor's range
MAX_PUSH_DURATION_S = 5.0
CSV_CHUNK_ROWS = 2048
"""Rows read and formatted at a time for a CSV download."""
CSV_CACHE_BYTES = 16 << 20
"""The formatted CSV kept for the next reader (:class:`CsvChunks`): a 30 s one-arm run's."""
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


class EmulatorService:
    """Builds emulators from scenarios + overrides and drives one :class:`Runner`."""

    def __init__(self, default_scenario: str | None = None, **runner_kwargs: Any) -> None:
        names = scenario_names()
        self.default_scenario = default_scenario or (
            "collision" if "collision" in names else names[0]
        )
        self._build_lock = threading.Lock()
        config = load_scenario(self.default_scenario)
        self.last_config: EmulatorConfig = config
        self._last_run: tuple[str, EmulatorConfig, str | None] = (
            self.default_scenario, config, None)
        """(scenario, config, mode) of the last start or reset: what a reset restarts."""
        self.runner = Runner(config, scenario=self.default_scenario, **runner_kwargs)
        self._reads = SharedReads(self.runner.snapshot)
        self._worker = DownloadWorker()  # the zip and the bag are built in a process
        self._csv_chunks = CsvChunks(CSV_CACHE_BYTES)

    # --- lifecycle ----------------------------------------------------------------------

    def start_thread(self) -> None:
        self.runner.start_thread()

    def shutdown(self) -> None:
        self._worker.shutdown()
        self.runner.shutdown()

    # --- queries --------------------------------------------------------------------------

    @staticmethod
    def scenarios() -> list[dict[str, str]]:
        return [{"name": n, "description": d} for n, d in scenario_descriptions().items()]

    def state(self) -> dict[str, Any]:
        """The loop's latest state; status "fault" with the reason while the loop process
        is dead or stalled."""
        snap = self.runner.snapshot()
        fault = self.runner.fault()
        if fault is not None:
            snap = {**snap, "status": "fault", "reason": fault}
        return snap

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

    @staticmethod
    def preflight(config: EmulatorConfig, mode: str | None) -> None:
        """Refuse a hil start whose predicted course leaves an arm's reach, safety volume
        or speed (app/preflight.py; InvalidRequest naming the robot, time and limit)."""
        if (mode or config.loop.mode) != "hil":
            return
        try:
            preflight(config, config.loop.duration_s)
        except PreflightRefused as err:
            raise InvalidRequest(str(err)) from None

    # --- commands ---------------------------------------------------------------------

    def start(
        self, name: str, overrides: dict | None = None, mode: str | None = None,
        wait_s: float = 60.0,
    ) -> dict[str, Any]:
        """Start scenario `name`; returns the state once running (or failed to start). A
        hil start is pre-flighted whatever the loop's state: a faulted loop still shows
        its last status (say "running"), and the start replaces it."""
        with self._build_lock:
            config, mode = self.build(name, overrides, mode)  # 404 / 422 before 409
            self._refuse_if_busy()  # 409 before a pre-flight's seconds
            self.preflight(config, mode)
            self._revive(config, name, mode)
            gen = self.runner.request_start(name, config, mode)
            self._csv_chunks.clear()  # a new run: the last one's CSV is let go
            self.last_config, self._last_run = config, (name, config, mode)
        # the loop publishes the new generation first as "starting", then running /
        # error / safety_stop
        self.runner.wait_until(
            lambda s: s["generation"] >= gen and s["status"] != "starting", wait_s
        )
        return self.state()

    def stop(self) -> dict[str, Any]:
        self.runner.request_stop()
        self.runner.wait_until(lambda s: s["status"] not in ("running", "starting"), 10.0)
        return self.state()

    def reset(self, name: str | None = None, mode: str | None = None) -> dict[str, Any]:
        """Back to t = 0, idle: the scenario, settings and mode of the last start or reset
        (a name given: that scenario as its file has it, in ``mode``)."""
        with self._build_lock:
            if name is None:
                name, config, mode = self._last_run
            else:
                config, mode = self.build(name, mode=mode)
            self._revive(config, name, mode)
            gen = self.runner.request_reset(name, config, mode)
            self._csv_chunks.clear()
            self.last_config, self._last_run = config, (name, config, mode)
        self.runner.wait_until(lambda s: s["generation"] >= gen, 10.0)
        return self.state()

    def push(self, satellite: int, force_N, duration_s: float,
             point_m=None) -> dict[str, Any]:
        """A push on satellite `satellite` (1-based), force in R, at point_m (body axes,
        from the COM; the COM if None); validated here."""
        state = self.state()
        force = validate_push(satellite, force_N, duration_s, state["n_satellites"])
        point = (0.0, 0.0, 0.0) if point_m is None else validate_point(
            point_m, state["layout"]["satellites"][satellite - 1][1])
        self.runner.post(Push(satellite=satellite - 1, force_R_N=force, duration_s=duration_s,
                              point_B_m=point))
        return {"satellite": satellite, "force_N": list(force), "duration_s": duration_s,
                "point_m": list(point), "t_s": self.state()["t_s"]}

    def hand(self, satellite0: int, anchor_W_m, point_B_m=(0.0, 0.0, 0.0)) -> bool:
        """Gizmo: move the virtual hand of satellite `satellite0` (0-based), holding it at
        point_B_m (body axes, from the COM); None lets go."""
        anchor = None if anchor_W_m is None else tuple(float(v) for v in anchor_W_m)
        point = tuple(float(v) for v in point_B_m)
        if anchor is not None and not all(math.isfinite(v) for v in anchor + point):
            return False
        return self.runner.post_nowait(HandAnchor(satellite=satellite0, anchor_W_m=anchor,
                                                  point_B_m=point))

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
        from app.report import csv_row_format

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
            for number, rows in ring.chunks(CSV_CHUNK_ROWS):
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
        from app.metrics import RunFacts, metrics_of

        snap, ring, _, rows = read or self.runner.run_telemetry()
        columns, rows = self._rows_of(snap, ring, rows)
        config = ring.config if ring is not None else self.last_config
        loop = snap["loop"]
        facts = RunFacts(
            mode=snap["mode"], status=snap["status"], cycles=loop["cycles"],
            wall_s=loop["wall_s"],
            cycle_time_us={"p50": loop["cycle_time_us"]["p50"] if loop["cycles"] else None,
                           "p99": loop["cycle_time_us"]["p99"] if loop["cycles"] else None},
            safety_stop=snap["safety_stop"], passivity=snap.get("passivity"),
            arm_of={r["satellite"] - 1: k for k, r in enumerate(snap["robots"])},
            capture=snap.get("capture"),
            error=snap.get("reason") if snap["status"] == "error" else None)
        index = {name: k for k, name in enumerate(columns)}
        return metrics_of(config, rows, index, facts)

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
        """The current (or last) run as a ROS 2 bag (MCAP; app/bag.py), zipped into a
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

    def _download_source(self):
        """(state, config, columns, the ring's file or None) of the current run."""
        snap = self.runner.snapshot()
        ring = self.runner.ring_of(snap)
        if ring is None:
            columns = loop_columns(len(snap["satellites"]), len(snap["robots"]))
            return snap, self.last_config, columns, None
        return snap, ring.config, ring.columns, ring.reader()


def give_back_memory() -> None:
    """Hand the memory freed by a heavy read back to the system (glibc's malloc_trim):
    without it the allocator keeps what the copies of a big ring used, and the web
    process's resident size stays tens of MiB up after each download."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):  # not glibc: nothing to do
        pass


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
