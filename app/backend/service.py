"""What the REST API and the viser GUI can ask of the emulator (one place, both use it).

Every request is validated completely before anything is handed to the runner, so a bad
request changes nothing.
"""

from __future__ import annotations

import collections
import io
import math
import threading
import time
from typing import Any

import numpy as np

from app.backend.runner import Runner, RunnerBusy
from app.config import ConfigError, EmulatorConfig, merge_overrides
from app.preflight import PreflightRefused, preflight
from app.report import json_safe
from app.scenarios import load_scenario, scenario_descriptions, scenario_names
from app.sim.hand import HandAnchor, Push
from app.sim.telemetry import loop_columns

__all__ = ["EmulatorService", "RunnerBusy", "UnknownScenario", "InvalidRequest"]

MAX_PUSH_FORCE_N = 100.0  # the F/T sensor's range
MAX_PUSH_DURATION_S = 5.0
MAX_BAG_MESSAGES = 60_000
"""A bag from the web app holds at most about this many messages (~10 s to write here):
a long run's bag is thinned below the rate asked for. `run --bag` has no such bound."""


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
        self._forecast_lock = threading.Lock()
        self._forecasts: dict = {}
        config = load_scenario(self.default_scenario)
        self.last_config: EmulatorConfig = config
        self._last_run: tuple[str, EmulatorConfig, str | None] = (
            self.default_scenario, config, None)
        """(scenario, config, mode) of the last start or reset: what a reset restarts."""
        self.runner = Runner(config, scenario=self.default_scenario, **runner_kwargs)
        self._reads = SharedReads(self.runner.snapshot)
        self._csv: tuple[Any, CsvLines] | None = None  # (the run's ring, its CSV lines)

    # --- lifecycle ----------------------------------------------------------------------

    def start_thread(self) -> None:
        self.runner.start_thread()

    def shutdown(self) -> None:
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
        return config, mode

    @staticmethod
    def preflight(config: EmulatorConfig, mode: str | None) -> float | None:
        """Refuse a hil start whose predicted course leaves an arm's reach, safety volume
        or speed (app/preflight.py; InvalidRequest naming the robot, time and limit); else
        when the run keeps its snapshot for the restitution's interval (before the
        contact the prediction has; None: none)."""
        if (mode or config.loop.mode) != "hil":
            return None
        try:
            prediction = preflight(config, config.loop.duration_s)
        except PreflightRefused as err:
            raise InvalidRequest(str(err)) from None
        if prediction is None or prediction.n_sat < 2:
            return None
        from app.headless import collision_of
        from app.uncertainty import snapshot_time_s

        return snapshot_time_s(config, collision_of(prediction))

    def forecast(self, name: str, overrides: dict | None = None,
                 mode: str | None = None) -> dict[str, Any]:
        """Before Start: the pre-flight of scenario ``name`` as it would start, with the
        restitution's forecast spread (app/uncertainty.py; ``collision_forecast`` None
        without a contact, or in ideal mode); refused as a start would be. Cached per
        configuration: the forecast takes seconds."""
        config, mode = self.build(name, overrides, mode)
        key = (config.model_dump_json(), mode)
        with self._forecast_lock:
            if key not in self._forecasts:
                self._forecasts.clear()  # one scenario's at a time
                self._forecasts[key] = self._compute_forecast(name, config, mode)
            return self._forecasts[key]

    @staticmethod
    def _compute_forecast(name: str, config: EmulatorConfig, mode: str | None) -> dict:
        import time

        from app.headless import checked_reference, headless_config

        t0 = time.perf_counter()
        forecast = None
        if (mode or config.loop.mode) == "hil" and len(config.satellites) >= 2:
            duration = config.loop.duration_s
            try:
                reference = checked_reference(headless_config(config, duration), duration)
            except PreflightRefused as err:
                raise InvalidRequest(str(err)) from None
            forecast = (reference or {}).get("forecast")
        return {"scenario": name, "mode": mode or config.loop.mode,
                "collision_forecast": forecast, "wall_s": time.perf_counter() - t0}

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
            snapshot_at_s = self.preflight(config, mode)
            self._revive(config, name, mode)
            gen = self.runner.request_start(name, config, mode, snapshot_at_s)
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

    def telemetry_csv(self) -> list[str]:
        """The current run's telemetry as CSV lines, header first (computed here, from the
        shared ring; see CsvLines.document)."""
        return self._reads.get("telemetry", self._telemetry_csv)

    def _telemetry_csv(self, read=None) -> list[str]:
        snap, ring, first, rows = read or self.runner.run_telemetry()
        columns, rows = self._rows_of(snap, ring, rows)
        if self._csv is None or self._csv[0] is not ring:
            self._csv = (ring, CsvLines(columns))
        return self._csv[1].document(first, rows)

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
        metrics = metrics_of(config, rows, index, facts)
        interval, coll = snap.get("interval"), metrics.get("collision")
        if interval and coll and coll["pair"] == interval["pair"] \
                and coll["restitution"] == interval["restitution"]:  # the loop's, after the run
            for key in ("restitution_sd", "restitution_interval_95", "uncertainty"):
                coll[key] = interval[key]
        return metrics

    def run_archive(self) -> bytes:
        """The current (or last) run to take home, as a zip: telemetry.csv, metrics.json,
        summary.txt, config.json (the run's whole configuration, with its mode) and the
        plots of a headless run (computed here, from one read of the shared ring)."""
        return self._reads.get("archive", self._run_archive)

    def _run_archive(self) -> bytes:
        import json
        import tempfile
        import zipfile
        from pathlib import Path

        from app.plots import plot_run
        from app.report import run_summary

        read = self.runner.run_telemetry()
        snap, ring, _, rows = read
        columns, rows = self._rows_of(snap, ring, rows)
        config = ring.config if ring is not None else self.last_config
        metrics = self._metrics(read)
        buffer = io.BytesIO()
        with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED) as zf, \
                tempfile.TemporaryDirectory() as tmp:
            zf.writestr("telemetry.csv", "".join(self._telemetry_csv(read)))
            zf.writestr("metrics.json", json.dumps(json_safe(metrics), indent=2))
            zf.writestr("summary.txt", run_summary(metrics) + "\n")
            zf.writestr("config.json", json.dumps(
                {"scenario": snap["scenario"], "mode": snap["mode"],
                 "config": config.model_dump(mode="json")}, indent=2))
            index = {name: k for k, name in enumerate(columns)}
            for path in plot_run(rows, index, Path(tmp), len(snap["satellites"]),
                                 len(snap["robots"]), metrics.get("collision"),
                                 note=metrics["scaling"]["text"]):
                zf.write(path, f"plots/{path.name}")
        return buffer.getvalue()

    def run_bag(self, rate_hz: float) -> tuple[bytes, float]:
        """The current (or last) run as a ROS 2 bag (MCAP; app/bag.py), zipped, and the
        rate it was written at: at most rate_hz messages per topic and second of scenario
        time, and fewer where the run is long (:data:`MAX_BAG_MESSAGES`). Written one at a
        time (the heavy reads' turn) and not kept: a bag costs ~0.15 ms a message."""
        return self._reads.exclusive(lambda: self._run_bag(rate_hz))

    def _run_bag(self, rate_hz: float) -> tuple[bytes, float]:
        import tempfile
        import zipfile
        from pathlib import Path

        from app.bag import thinning_step, write_bag

        snap, ring, _, rows = self.runner.run_telemetry()
        columns, rows = self._rows_of(snap, ring, rows)
        config = ring.config if ring is not None else self.last_config
        if len(rows) > 1:  # a long run: fewer messages per second, the whole run
            per_row = 1 + 3 * len(snap["satellites"]) + 3 * len(snap["robots"])
            span_s = max(float(rows[-1, 0] - rows[0, 0]), 1e-9)
            rate_hz = min(rate_hz, MAX_BAG_MESSAGES / (per_row * span_s))
            dt_s = float(rows[1, 0] - rows[0, 0])
            rate_hz = 1.0 / (thinning_step(rate_hz, dt_s) * dt_s)  # the rate written
        buffer = io.BytesIO()
        with tempfile.TemporaryDirectory() as tmp, \
                zipfile.ZipFile(buffer, "w", zipfile.ZIP_STORED) as zf:
            bag = write_bag(Path(tmp) / "bag", config, rows,
                            {name: k for k, name in enumerate(columns)}, rate_hz)
            for path in sorted(bag.iterdir()):
                zf.write(path, f"bag/{path.name}")
        return buffer.getvalue(), rate_hz


class CsvLines:
    """One run's telemetry CSV, formatted as its rows come: each read formats only the
    rows committed since the one before (a 30 s ring took 0.7 s to format whole, every
    time), and lets go of those the ring has dropped. The bytes are those of
    :func:`app.report.telemetry_csv_text`."""

    def __init__(self, columns: list[str]) -> None:
        from app.report import csv_row_format

        self.header = ",".join(columns) + "\n"
        self.row_format = csv_row_format(len(columns))
        self.lines: collections.deque[str] = collections.deque()
        self.first = 0
        """The number (since the run began) of the row of lines[0]."""

    def text(self, first: int, rows: np.ndarray) -> str:
        """The CSV of rows numbered first, first + 1, … (a later read never starts
        earlier)."""
        return "".join(self.document(first, rows))

    def document(self, first: int, rows: np.ndarray) -> list[str]:
        """The CSV as its lines (the header first), for a response that streams them: a
        list of the cached strings, not one more copy of the text (a full 1 GiB ring is
        gigabytes of text)."""
        have = self.first + len(self.lines)
        if not self.first <= first <= have:  # a gap: begin again from these rows
            self.lines.clear()
            self.first = have = first
        fmt = self.row_format
        self.lines.extend(fmt % row for row in map(tuple, rows[have - first:].tolist()))
        while self.first < first:
            self.lines.popleft()
            self.first += 1
        return [self.header, *self.lines]


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
            return compute()

    def get(self, name: str, compute):
        with self._lock:
            snap = self._snapshot()
            state, cycles = (snap["generation"], snap["status"]), snap["loop"]["cycles"]
            now = time.monotonic()
            last = self._last.get(name)
            if last is not None and last[0] == state and (
                    last[1] == cycles or now - last[2] <= self.max_age_s):
                return last[3]
            value = compute()
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
