"""The heavy downloads (the run's zip, its ROS 2 bag), built in a process of their own.

A zip needs every row at once (its plots), a bag the rows it keeps and rosbags: built in
the web process they took it from 622 MiB to 1.8 GiB for a 179k-row run, and much of it
stayed. Here each is built by a fresh worker process (spawned, one task, then it exits and
its memory is the system's again) that reads the run's ring from its file
(:class:`app.backend.ring.RingFile`) and writes a temporary zip file, which the server then
streams from disk. The web process itself holds neither the rows nor the file.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import re
import tempfile
import threading
import time
import zipfile
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

import numpy as np

from app.backend.ring import CHUNK_ROWS, RingFile
from app.config import EmulatorConfig
from app.runs.report import csv_row_format, json_safe

__all__ = ["DownloadWorker", "build_archive", "build_bag", "build_stored_bag", "temporary_zip"]


def temporary_zip(prefix: str) -> Path:
    """A new, empty temporary file for a download (the caller deletes it)."""
    fd, name = tempfile.mkstemp(prefix=prefix, suffix=".zip")
    os.close(fd)
    return Path(name)


def _empty_rows(columns) -> np.ndarray:
    return np.empty((0, len(columns)))


def build_archive(path: str, snap: dict, config: EmulatorConfig, columns: list[str],
                  ring: RingFile | None, metrics: dict) -> None:
    """The run's zip at ``path``: telemetry.csv (formatted a chunk at a time),
    metrics.json, summary.txt, config.json and the headless run's figures (plots/, with
    their list plots/figures.json: app/runs/plots.py figures_of)."""
    from app.runs.plots import plot_run
    from app.runs.report import run_summary

    rows = ring.numbered_rows()[1] if ring is not None else _empty_rows(columns)
    fmt = csv_row_format(len(columns))
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf, \
            tempfile.TemporaryDirectory() as tmp:
        with zf.open("telemetry.csv", "w", force_zip64=True) as csv:
            csv.write((",".join(columns) + "\n").encode())
            for i in range(0, len(rows), CHUNK_ROWS):
                csv.write("".join(fmt % row for row in map(
                    tuple, rows[i:i + CHUNK_ROWS].tolist())).encode())
        zf.writestr("metrics.json", json.dumps(json_safe(metrics), indent=2))
        zf.writestr("summary.txt", run_summary(metrics) + "\n")
        zf.writestr("config.json", json.dumps(
            {"scenario": snap["scenario"], "mode": snap["mode"],
             "config": config.model_dump(mode="json")}, indent=2))
        index = {name: k for k, name in enumerate(columns)}
        for plot in plot_run(rows, index, Path(tmp), config, metrics,
                             note=metrics["scaling"]["text"]):
            zf.write(plot, f"plots/{plot.name}")


def build_bag(path: str, snap: dict, config: EmulatorConfig, columns: list[str],
              ring: RingFile | None, rate_hz: float, max_messages: int) -> float:
    """The run's ROS 2 bag (app/runs/bag.py), zipped at ``path``; the rate written: at most
    rate_hz messages per topic and second of scenario time, and fewer where the run is
    long (about max_messages in all). Only the rows kept are held, read a chunk at a
    time."""
    rows = _empty_rows(columns)
    if ring is not None:
        rows, rate_hz = bag_rows(ring, snap, rate_hz, max_messages)
    _zip_bag(path, config, columns, rows)
    return rate_hz


def _zip_bag(path: str, config: EmulatorConfig, columns: list[str], rows: np.ndarray) -> None:
    """The bag of ``rows`` (app/runs/bag.py write_bag, every row given), zipped at ``path``
    as bag/metadata.yaml and bag/bag.mcap."""
    from app.runs.bag import write_bag

    with tempfile.TemporaryDirectory() as tmp, \
            zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as zf:
        bag = write_bag(Path(tmp) / "bag", config, rows,
                        {name: k for k, name in enumerate(columns)}, None)
        for part in sorted(bag.iterdir()):
            zf.write(part, f"bag/{part.name}")


def build_stored_bag(path: str, folder: str, rate_hz: float, max_messages: int) -> float:
    """The ROS 2 bag of a run kept on disk (app/runs/store.py: its telemetry.csv and
    config.json), zipped at ``path``, as :func:`build_bag` makes the current run's: at
    most rate_hz messages per topic and second of scenario time, fewer where the run is
    long (about max_messages in all); the rate written. The CSV is read twice a line at a
    time (its times, then the rows kept), so only the rows kept are held."""
    from app.runs.bag import thinning_step
    from app.runs.store import read_telemetry_every, run_config, telemetry_span

    telemetry = Path(folder) / "telemetry.csv"
    config = run_config(Path(folder))
    columns, n_rows, dt_s, span_s = telemetry_span(telemetry)
    n_sat = sum(1 for c in columns if re.fullmatch(r"sat\d+_x_m", c))
    n_rob = sum(1 for c in columns if re.fullmatch(r"rob\d+_x_m", c))
    per_row = 2 + 3 * n_sat + 3 * n_rob  # /clock, /tf, and per satellite and arm
    step = 1
    if n_rows >= 2 and dt_s > 0:
        rate_hz = min(rate_hz, max_messages / (per_row * max(span_s, 1e-9)))
        step = thinning_step(rate_hz, dt_s)
        rate_hz = 1.0 / (step * dt_s)
    _, rows = read_telemetry_every(telemetry, step, n_rows)  # (a running run grows)
    _zip_bag(path, config, columns, rows)
    return rate_hz


def bag_rows(ring: RingFile, snap: dict, rate_hz: float,
             max_messages: int) -> tuple[np.ndarray, float]:
    """(the rows a bag keeps, the rate written): every step-th row of the ring from its
    first, step the least whose rate is at most rate_hz and that keeps the bag within
    max_messages (app.runs.bag.thinning_step)."""
    from app.runs.bag import thinning_step

    head = tail = None
    for first, rows in ring.chunks():
        head = (first, rows) if head is None else head
        tail = rows
    if head is None or len(head[1]) < 2:
        return (head[1] if head is not None else np.empty((0, ring.n_columns))), rate_hz
    first, rows = head
    per_row = 2 + 3 * len(snap["satellites"]) + 3 * len(snap["robots"])  # /clock, /tf
    span_s = max(float(tail[-1, 0] - rows[0, 0]), 1e-9)
    rate_hz = min(rate_hz, max_messages / (per_row * span_s))
    dt_s = float(rows[1, 0] - rows[0, 0])
    step = thinning_step(rate_hz, dt_s)
    kept = [chunk[(first - number) % step::step] for number, chunk in ring.chunks()]
    return np.concatenate(kept), 1.0 / (step * dt_s)


def exit_with_parent(parent_pid: int) -> None:
    """In the worker: exit as soon as the web process that started it is gone (a kill -9
    of the server once left the worker, and through it the run's shared memory, behind)."""
    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=watch, daemon=True, name="exit-with-parent").start()


class DownloadWorker:
    """Runs :func:`build_archive` / :func:`build_bag` in a fresh spawned process each
    (one at a time: the caller holds the heavy reads' turn)."""

    def __init__(self) -> None:
        self._pool: ProcessPoolExecutor | None = None
        self._lock = threading.Lock()

    def run(self, fn, *args):
        with self._lock:
            if self._pool is None:
                self._pool = ProcessPoolExecutor(
                    max_workers=1, mp_context=mp.get_context("spawn"), max_tasks_per_child=1,
                    initializer=exit_with_parent, initargs=(os.getpid(),))
            pool = self._pool
        try:
            return pool.submit(fn, *args).result()
        except BrokenProcessPool:  # the worker died (e.g. killed for memory): a new one next
            with self._lock:
                if self._pool is pool:
                    self._pool = None
            raise RuntimeError("the download's worker process died before it finished; "
                               "try again") from None

    def shutdown(self) -> None:
        with self._lock:
            pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=False, cancel_futures=True)
