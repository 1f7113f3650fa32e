"""Every web run written to disk as it goes (the runs store, app/runs/store.py).

:class:`RunRecorder` lives in the web process. When the service starts a run it opens the
run's folder (:meth:`RunRecorder.begin`) and keeps the run's telemetry ring open (an open
file of its own: a ring the runner lets go of, or a loop process that dies, leaves its
rows readable). Every ``period_s`` (0.25 s) a thread appends the rows the loop committed
since to the run's telemetry.csv, flushed, so a killed server loses at most the last
quarter second. When the run ends (finished, stopped, a safety stop, an error, a dead
loop, or replaced by a reset) the recorder writes its metrics.json (with the pre-flight's
ideal run as the comparison: what /api/metrics and run.zip give), waits a little for the
restitution's interval the loop computes after the run, and has a worker process draw the
plots from the telemetry.csv on disk.

A disk that fails (full: ENOSPC; or the runs folder gone or unwritable) never stops the
loop's run: a run whose folder cannot be made goes on unrecorded (the state's warnings say
so); a run whose telemetry.csv cannot be written stops being recorded at its last whole
row, and its run.json says so (``recording: "failed"``, ``recording_error``), once the disk
takes it. Each is logged once.
"""

from __future__ import annotations

import datetime as dt
import json
import logging
import multiprocessing as mp
import os
import queue
import shutil
import threading
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from app.backend.downloads import exit_with_parent
from app.backend.replay import replay_html, replay_title
from app.backend.ring import RingFile, RunTelemetry
from app.backend.runner import Runner, RunnerError
from app.config import EmulatorConfig
from app.runs.report import write_json
from app.runs.store import (
    REPLAY_FILE,
    RUN_FILE,
    RunNotFound,
    RunStore,
    TelemetryAppender,
    now_utc,
    read_telemetry,
    write_plots,
)

log = logging.getLogger("orbit_emulator.recorder")

__all__ = ["FLUSH_PERIOD_S", "INTERVAL_WAIT_S", "RunRecorder"]

FLUSH_PERIOD_S = 0.25
"""The new rows of the run are appended to its telemetry.csv this often."""
INTERVAL_WAIT_S = 30.0
"""After a hil run with a contact ends, its metrics wait this long at most for the
restitution's interval the loop computes (a second or two); a new run does not wait."""
LIVE = ("starting", "running")
GENERATIONS_KEPT = 16
"""The runs whose loop generation is remembered, for their replays (which the scene ends
when the run ends, or when the next run replaces it)."""

MetricsFn = Callable[..., dict]


@dataclass
class _Active:
    """The run being recorded."""

    run_id: str
    folder: Path
    ring: RunTelemetry
    fd: int
    reader: RingFile
    appender: TelemetryAppender
    config: EmulatorConfig
    mode: str
    ideal: dict | None
    expect_interval: bool
    next_row: int = 0
    rows_lost: int = 0
    last_snap: dict | None = None
    phase: str = "recording"  # then "interval": ended, waiting for the interval
    ended: dt.datetime | None = None
    status: tuple[str, str | None] = ("running", None)
    deadline: float = 0.0
    extra: dict = field(default_factory=dict)
    record_error: str | None = None
    """Why the run stopped being recorded (its telemetry.csv could not be written)."""
    disk_logged: bool = False
    generation: int | None = None
    """The loop generation of the run: a state of an older one is the loop not yet having
    taken this run (it stalled), not a run that replaced it."""


class RunRecorder:
    """Writes the service's runs into ``store`` as they go (thread-safe)."""

    def __init__(self, runner: Runner, store: RunStore, metrics_fn: MetricsFn,
                 period_s: float = FLUSH_PERIOD_S, draw_plots: bool = True) -> None:
        """``draw_plots``: False leaves each run's plots undrawn (``plots`` stays
        "pending" in run.json; the next server that starts with it draws them)."""
        self.runner, self.store = runner, store
        self.draw_plots = draw_plots
        self._metrics_fn = metrics_fn
        self._worker: ProcessPoolExecutor | None = None  # draws the plots; made on first use
        self.period_s = period_s
        self._lock = threading.RLock()
        self._run: _Active | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._plots: queue.SimpleQueue = queue.SimpleQueue()
        self._plotter: threading.Thread | None = None
        self._plotting = threading.Event()
        self._names_lock = threading.Lock()  # (not the recording's lock: the scene's
        self._generations: dict[int, tuple[str, str, str]] = {}  # thread takes this one)
        """Loop generation -> (run id, scenario, mode) of the runs begun last."""
        self._replay_writers: list[threading.Thread] = []
        self._unwritten: list[Callable[[], Any]] = []
        """Writes of runs' records a failing disk refused, tried again every period."""
        self._unrecorded: str | None = None
        """Why the latest run is not recorded (its folder could not be made)."""
        self._last_error: str | None = None
        self._ideals: dict[str, dict] = {}
        """Run id -> the pre-flight's ideal collision it is compared with (the service's
        object, which :meth:`_share_forecast` hands back with the forecast)."""
        self.on_forecast: Callable[[dict, dict], None] | None = None
        """Called with (a run's ideal collision, the forecast computed after the run): the
        service then compares its runs with the ideal collision and the forecast."""

    # --- lifecycle ----------------------------------------------------------------------

    def start(self) -> None:
        """The recording thread, and the plots' thread, which first finishes the runs a
        server that stopped left: an interrupted run gets its metrics from what it
        recorded, a run whose plots were not drawn gets them."""
        for run_id in self.store.recover():
            log.warning("run %s was left unfinished by a server that stopped", run_id)
            self._plots.put(("recover", run_id))
        for record in self.store.runs():
            if record.get("plots") == "pending" and record.get("status") != "interrupted":
                self._plots.put(("plots", record["id"]))
        self._thread = threading.Thread(target=self._main, name="run-recorder", daemon=True)
        self._thread.start()
        self._plotter = threading.Thread(target=self._plot_main, name="run-plots",
                                         daemon=True)
        self._plotter.start()

    def stop(self, plots_wait_s: float = 30.0) -> None:
        """The server stops: the run being recorded is flushed and ended ("stopped" if it
        was still running), its plots drawn if they can be within plots_wait_s."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
        with self._lock:
            run = self._run
            if run is not None:
                self._flush(run)
                if run.phase == "recording":
                    snap = run.last_snap or {}
                    status = snap.get("status", "running")
                    if status in LIVE:
                        self._end(run, "stopped", "the server stopped during the run")
                    else:
                        self._end(run, status, snap.get("reason"))
                self._final(run)
            self._retry_unwritten()
        with self._names_lock:
            writers = list(self._replay_writers)
        for writer in writers:  # the replays being written
            writer.join(10.0)
        self._plots.put(None)  # the plots not drawn yet are drawn by the next server
        if self._plotter is not None:
            self._plotter.join(plots_wait_s)
        if self._worker is not None:
            self._worker.shutdown(wait=False, cancel_futures=True)

    def active_id(self) -> str | None:
        with self._lock:
            return None if self._run is None else self._run.run_id

    # --- a run --------------------------------------------------------------------------

    def begin(self, ring: RunTelemetry, scenario: str, config: EmulatorConfig,
              mode: str | None, ideal: dict | None, snapshot_at_s: float | None,
              generation: int | None = None) -> str | None:
        """Record the run whose telemetry ring is ``ring`` (just requested; its loop
        ``generation``, which names its 3D replay: :meth:`save_replay`); the run recorded
        before is ended first. Its id; None if its folder could not be made (the run goes
        on unrecorded: :meth:`warning` says why)."""
        mode = mode or config.loop.mode
        with self._lock:
            self.settle(replaced=True)
            try:
                run_id, folder, appender = self._make_folder(ring, scenario, config, mode,
                                                             ideal)
            except OSError as err:
                self._unrecorded = (f"this run is not recorded: its folder could not be "
                                    f"made in {str(self.store.root)!r}: "
                                    f"{err.strerror or err}")
                log.error("%s", self._unrecorded)
                return None
            self._unrecorded = None
            fd = os.open(ring.path, os.O_RDONLY | os.O_CLOEXEC)  # the ring, kept readable
            reader = RingFile(f"/proc/{os.getpid()}/fd/{fd}", ring.capacity,
                              len(ring.columns))
            self._run = _Active(
                run_id=run_id, folder=folder, ring=ring, fd=fd, reader=reader,
                appender=appender, config=config, mode=mode, ideal=ideal,
                expect_interval=mode == "hil" and snapshot_at_s is not None,
                generation=generation)
            with self._names_lock:
                if ideal is not None:
                    self._ideals[run_id] = ideal
                    while len(self._ideals) > GENERATIONS_KEPT:
                        del self._ideals[next(iter(self._ideals))]
                if generation is not None:
                    self._generations[generation] = (run_id, scenario, mode)
                    while len(self._generations) > GENERATIONS_KEPT:
                        del self._generations[next(iter(self._generations))]
            return run_id

    def _make_folder(self, ring: RunTelemetry, scenario: str, config: EmulatorConfig,
                     mode: str, ideal: dict | None) -> tuple[str, Path, TelemetryAppender]:
        """A new run's folder with its records and telemetry.csv's header (OSError: none
        left)."""
        run_id = self.store.create(scenario, mode, config.model_dump(mode="json"),
                                   config.loop.seed)
        folder = self.store.folder(run_id)
        try:
            if ideal is not None:  # what an interrupted run is compared with, later
                write_json(folder / "ideal.json", ideal)
            return run_id, folder, TelemetryAppender(folder / "telemetry.csv", ring.columns)
        except OSError:
            shutil.rmtree(folder, ignore_errors=True)
            raise

    def warning(self) -> str | None:
        """Why the latest run is not (or no longer) being recorded, if it is not."""
        with self._lock:
            if self._run is not None:
                return self._run.record_error
            return self._unrecorded

    def save_replay(self, generation: int, recording: bytes, truncated: bool) -> None:
        """The scene's recording of run ``generation`` (app/backend/replay.py) is done:
        written to the run's folder as replay.html, the standalone file that plays
        offline, by a thread of its own (the scene's thread, which calls this, goes on)."""
        with self._names_lock:
            known = self._generations.get(generation)
        if known is None:  # a run not recorded (a reset's idle scene, say)
            return
        writer = threading.Thread(target=self._write_replay, args=(*known, recording,
                                                                   truncated),
                                  name="run-replay", daemon=True)
        with self._names_lock:
            self._replay_writers = [w for w in self._replay_writers if w.is_alive()]
            self._replay_writers.append(writer)
        writer.start()

    def _write_replay(self, run_id: str, scenario: str, mode: str, recording: bytes,
                      truncated: bool) -> None:
        try:
            folder = self.store.folder(run_id)
            page = replay_html(recording, replay_title(scenario, mode, truncated))
            tmp = folder / f".{REPLAY_FILE}.tmp"
            try:
                tmp.write_text(page, encoding="utf-8")
                os.replace(tmp, folder / REPLAY_FILE)
            except OSError:  # (a full disk): no temporary file left
                try:
                    tmp.unlink(missing_ok=True)
                except OSError:
                    pass
                raise
            if not (folder / RUN_FILE).is_file():  # deleted meanwhile: no leftovers
                shutil.rmtree(folder, ignore_errors=True)
        except (RunNotFound, OSError) as err:  # deleted (retention, DELETE) meanwhile
            log.info("the replay of run %s was not kept: %s", run_id, err)

    def settle(self, replaced: bool = False) -> None:
        """Flush the run being recorded now; end it if it is over, or (``replaced``) if a
        new run takes its place."""
        with self._lock:
            run = self._run
            if run is None:
                return
            self._tick(run)
            if replaced and self._run is run:
                if run.phase == "recording":
                    snap = run.last_snap or {}
                    if snap.get("status", "running") in LIVE:
                        self._end(run, "stopped", "a reset or a new run ended it")
                    else:
                        self._end(run, snap["status"], snap.get("reason"))
                self._final(run)

    # --- the thread ---------------------------------------------------------------------

    def _main(self) -> None:
        while not self._stop.wait(self.period_s):
            try:
                with self._lock:
                    self._retry_unwritten()
                    if self._run is not None:
                        self._tick(self._run)
                self._last_error = None
            except Exception as err:  # noqa: BLE001 - the recorder must go on for the next run
                if repr(err) != self._last_error:  # once, not every period
                    log.exception("recording the run failed")
                self._last_error = repr(err)

    def _retry_unwritten(self) -> None:
        """The records a failing disk refused, written now if it takes them (in order)."""
        while self._unwritten:
            try:
                self._unwritten[0]()
            except OSError:
                return
            except RunNotFound:  # deleted meanwhile
                pass
            self._unwritten.pop(0)

    def _store_write(self, run: _Active, what: str, fn: Callable[[], Any]) -> None:
        """``fn()``, a write of the run's records; on a disk error logged (once a run) and
        kept to try again (:meth:`_retry_unwritten`)."""
        if self._unwritten:  # in order: after those waiting
            self._unwritten.append(fn)
            return
        try:
            fn()
        except OSError as err:
            self._disk_failed(run, f"its {what} could not be written", err)
            self._unwritten.append(fn)

    def _disk_failed(self, run: _Active, what: str, err: OSError) -> None:
        if not run.disk_logged:
            run.disk_logged = True
            log.error("run %s: %s: %s (the run goes on; its records are written when the "
                      "disk takes them)", run.run_id, what, err.strerror or err)

    def _tick(self, run: _Active) -> None:
        """Flush the new rows; move the run on if it ended."""
        try:
            snap = self.runner.snapshot()
        except RunnerError:
            snap = None
        dead = self.runner.dead()
        mine = snap is not None and self.runner.ring_of(snap) is run.ring
        if mine:
            run.last_snap = snap
        replaced = snap is not None and not mine and (
            run.generation is None or snap.get("generation", -1) > run.generation)
        self._flush(run)
        if run.phase == "recording":
            last = run.last_snap or {}
            if dead is not None:
                self._end(run, "fault", dead)
                self._final(run)
            elif replaced:  # a reset, a new loop (an older state: not taken yet, wait)
                status = last.get("status", "running")
                if status in LIVE:
                    self._end(run, "stopped", "a reset or a new run ended it")
                else:
                    self._end(run, status, last.get("reason"))
                self._final(run)
            elif mine and snap["status"] not in LIVE:
                self._end(run, snap["status"], snap.get("reason"))
                wait = run.expect_interval and snap["status"] in ("finished", "safety_stop")
                if wait and snap.get("interval") is None:
                    run.phase, run.deadline = "interval", time.monotonic() + INTERVAL_WAIT_S
                else:
                    self._final(run)
        elif run.phase == "interval":
            if mine and snap.get("interval") is not None:
                self._write_metrics(run)  # now with the interval
                self._final(run)
            elif not mine or dead is not None or time.monotonic() > run.deadline:
                self._final(run)

    def _flush(self, run: _Active) -> None:
        """Append the rows committed since the last flush to telemetry.csv."""
        if run.record_error is not None:  # no longer recorded
            return
        try:
            first, rows = run.reader.rows_since(run.next_row)
        except OSError:
            return
        if first > run.next_row:
            run.rows_lost += first - run.next_row
        try:
            run.appender.append(rows)
        except OSError as err:  # (a full disk): telemetry.csv ends at its last whole row
            self._recording_failed(run, err)
            return
        run.next_row = first + len(rows)

    def _recording_failed(self, run: _Active, err: OSError) -> None:
        """telemetry.csv could not be written: the run is recorded no further (its file
        keeps its whole rows), and its run.json says so."""
        t_s = (run.last_snap or {}).get("t_s")
        at = "" if t_s is None else f" at t = {t_s:.3f} s"
        run.record_error = (f"the recording stopped{at} ({run.appender.rows_written} rows "
                            f"written): telemetry.csv could not be written: "
                            f"{err.strerror or err}")
        run.appender.close()
        self._disk_failed(run, "telemetry.csv could not be written", err)
        message = run.record_error
        self._store_write(run, "run.json", lambda: self.store.update(
            run.run_id, recording="failed", recording_error=message))

    def _end(self, run: _Active, status: str, reason: str | None) -> None:
        """The run ended: its metrics.json and run.json (the plots come after)."""
        run.status, run.ended = (status, reason), now_utc()
        run.phase = "interval"
        self._write_metrics(run)

    def _write_metrics(self, run: _Active) -> None:
        status, reason = run.status
        snap = run.last_snap
        try:
            _, rows = run.reader.rows_since(0)
            metrics = self._metrics_fn(snap, run.config, run.ring.columns, rows, status,
                                       reason, run.ideal)
        except Exception as err:  # noqa: BLE001 - the record is written all the same
            log.exception("the metrics of run %s failed", run.run_id)
            metrics = {"scenario": run.config.name, "mode": run.mode, "status": status,
                       "error": f"the metrics could not be computed: {err}"}
        if run.rows_lost:
            metrics.setdefault("warnings", []).append(
                f"{run.rows_lost} rows were overwritten in the telemetry ring before they "
                f"could be written to telemetry.csv")
        extra = {}
        if run.record_error is not None:
            metrics.setdefault("warnings", []).append(run.record_error)
            extra = {"recording": "failed", "recording_error": run.record_error}
        run_id, ended = run.run_id, run.ended

        def write() -> None:
            self.store.finish(run_id, metrics, status, reason, ended)
            if extra:
                self.store.update(run_id, **extra)
        self._store_write(run, "metrics.json and run.json", write)

    def _final(self, run: _Active) -> None:
        """Let go of the run: its file synced, its ring closed, its plots queued."""
        run.appender.close()
        try:
            os.close(run.fd)
        except OSError:
            pass
        run.phase = "done"
        if self._run is run:
            self._run = None
        run_id, rows = run.run_id, run.appender.rows_written

        def write() -> None:
            self.store.update(run_id, plots="pending", telemetry_rows=rows)
            self._plots.put(("plots", run_id))
        self._store_write(run, "run.json", write)

    def _plot_main(self) -> None:
        while True:
            task = self._plots.get()
            if task is None or self._stop.is_set():
                return
            what, run_id = task
            try:
                if what == "recover":
                    self._recover(run_id)
                if not self.draw_plots:
                    continue
                folder = self.store.folder(run_id)
                names = self._draw(folder)  # (with the forecast a start did not wait for)
                self._share_forecast(run_id, folder)
                if not (folder / RUN_FILE).is_file():  # deleted while drawn: no leftovers
                    shutil.rmtree(folder, ignore_errors=True)
                    continue
                self.store.update(run_id, plots=names)
            except Exception as err:  # noqa: BLE001 - deleted meanwhile, or a plot failed
                try:
                    self.store.update(run_id, plots=f"failed: {type(err).__name__}: {err}")
                except Exception:  # noqa: BLE001 - the run is gone
                    pass

    def _share_forecast(self, run_id: str, folder: Path) -> None:
        """The forecast the worker added to the run's ideal.json, handed to the service
        (:attr:`on_forecast`): /api/metrics and run.zip of the run that is there then
        carry it too, and a later /forecast or Start of the same configuration has it at
        once."""
        with self._names_lock:
            ideal = self._ideals.pop(run_id, None)
        if ideal is None or "forecast" in ideal:
            return
        try:
            saved = json.loads((folder / "ideal.json").read_text())
        except (OSError, ValueError):
            return
        if saved.get("forecast") is not None and self.on_forecast is not None:
            self.on_forecast(ideal, saved["forecast"])

    def _draw(self, folder: Path) -> list[str]:
        """The run's plots, drawn by the recorder's worker process (:meth:`in_worker`)."""
        return self.in_worker(finish_in_worker, str(folder))

    def in_worker(self, fn, *args):
        """``fn(*args)`` in a worker process of the recorder's own, which draws the runs'
        plots (matplotlib and the rows stay out of the web process; one process for every
        run's figures, one task at a time: spawning one each time costs seconds)."""
        with self._lock:
            if self._worker is None:
                self._worker = ProcessPoolExecutor(
                    max_workers=1, mp_context=mp.get_context("spawn"),
                    initializer=exit_with_parent, initargs=(os.getpid(),))
            worker = self._worker
        try:
            return worker.submit(fn, *args).result()
        except BrokenProcessPool:  # the worker died (e.g. killed for memory): a new one next
            with self._lock:
                if self._worker is worker:
                    self._worker = None
            raise

    def _recover(self, run_id: str) -> None:
        """The metrics of a run its server left unfinished, from its telemetry.csv (status
        "interrupted"; the loop's timing and events, which the server kept, are not
        known)."""
        folder = self.store.folder(run_id)
        saved = json.loads((folder / "config.json").read_text())
        config = EmulatorConfig.model_validate(saved["config"])
        columns, rows = read_telemetry(folder / "telemetry.csv")
        ideal_path = folder / "ideal.json"
        ideal = json.loads(ideal_path.read_text()) if ideal_path.is_file() else None
        names = [s.name for s in config.satellites]
        robots = [{"satellite": names.index(r.satellite) + 1} for r in config.robots
                  if r.satellite in names] if saved["mode"] == "hil" else []
        record = self.store.run(run_id)
        metrics = self._metrics_fn({"mode": saved["mode"], "robots": robots}, config,
                                   columns, rows, "interrupted", record.get("reason"), ideal)
        ended = dt.datetime.fromtimestamp((folder / "telemetry.csv").stat().st_mtime,
                                          dt.timezone.utc)
        self.store.finish(run_id, metrics, "interrupted", record.get("reason"), ended)
        self.store.update(run_id, telemetry_rows=len(rows))

    def info(self) -> dict[str, Any]:
        return {"dir": str(self.store.root), "keep_runs": self.store.keep_runs,
                "max_bytes": self.store.max_bytes, "retention": self.store.retention(),
                "recording": self.active_id()}


def finish_in_worker(folder: str) -> list[str]:
    """In the recorder's worker process, after a run: its fidelity forecast if its start
    did not have it (:func:`add_forecast`), then its plots; the plots' names."""
    add_forecast(Path(folder))
    return write_plots(folder)


def add_forecast(folder: Path) -> None:
    """The restitution's forecast (app/runs/uncertainty.py: what a headless run's
    metrics.json has in ``collision_forecast``) of a hil run whose start did not compute
    it, added to its metrics.json, summary.txt and ideal.json."""
    from app.runs.forecast_cache import cached_forecast
    from app.runs.headless import headless_config
    from app.runs.report import run_summary
    from app.runs.uncertainty import add_systematic, forecast

    ideal_path, metrics_path = folder / "ideal.json", folder / "metrics.json"
    if not ideal_path.is_file() or not metrics_path.is_file():
        return
    ideal = json.loads(ideal_path.read_text())
    if not ideal or "forecast" in ideal:
        return
    saved = json.loads((folder / "config.json").read_text())
    config = EmulatorConfig.model_validate(saved["config"])
    try:
        config = headless_config(config, config.loop.duration_s)
    except ValueError:
        pass
    ideal["forecast"] = cached_forecast(config, ideal, forecast)
    metrics = json.loads(metrics_path.read_text())
    metrics["collision_forecast"] = ideal["forecast"]
    add_systematic(metrics.get("collision"), ideal["forecast"])
    write_json(ideal_path, ideal)
    write_json(metrics_path, metrics)
    try:
        (folder / "summary.txt").write_text(run_summary(metrics) + "\n")
    except (KeyError, TypeError, ValueError):
        pass
