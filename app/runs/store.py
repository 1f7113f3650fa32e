"""The runs store: every web run kept on disk, one folder per run, as a headless run's.

A run's folder, under the store's root (``serve --runs-dir``, default ``runs/web``), is
named by its start time (UTC, to the millisecond) and its scenario, e.g.
``20261126T052345123Z-collision``, and holds what a headless run writes there
(telemetry.csv, metrics.json, the plots) and more:

* ``run.json``: what the runs list shows: scenario, mode, seed, start and end time,
  status (``running`` while it goes; ``interrupted`` once found so after the server that
  recorded it stopped), its reason, the headline figures (:func:`headline`);
* ``config.json``: the run's whole configuration with its mode (as in run.zip);
* ``telemetry.csv``: appended to as the run goes (:class:`TelemetryAppender`);
* ``metrics.json`` and ``summary.txt`` once the run ended; then the plots;
* ``replay.html``: the run's 3D replay (its first 10 minutes at most), written by the web
  app when the scene's recording of the run ends.

Retention is bounded: at most ``keep_runs`` runs and, if set, ``max_bytes`` of them; the
oldest go first (:meth:`RunStore.prune`), never a run still recording.

File I/O only: no web imports; the web side is app/backend/recorder.py.
"""

from __future__ import annotations

import datetime as dt
import json
import logging
import os
import re
import shutil
from pathlib import Path

import numpy as np

from app.runs.report import csv_row_format, json_safe, run_summary

__all__ = ["DEFAULT_KEEP_RUNS", "DEFAULT_RUNS_DIR", "REPLAY_FILE", "BadRecord", "BadRunName",
           "RunNotFound", "RunStore", "TelemetryAppender", "check_file_name", "check_record",
           "check_run_id", "headline", "write_plots"]

log = logging.getLogger("orbit_emulator.runs")

DEFAULT_RUNS_DIR = Path("runs/web")
DEFAULT_KEEP_RUNS = 100
RUN_FILE = "run.json"
REPLAY_FILE = "replay.html"
"""A run's 3D replay (app/backend/replay.py), written when the scene's recording ends."""
RUN_ID = re.compile(r"^\d{8}T\d{9}Z-[a-z0-9][a-z0-9-]{0,62}$")
"""A run's id: its start time (UTC, milliseconds) and its scenario (a suffix -2, -3 ... if
two runs began in the same millisecond)."""
FILE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,127}$")
LIVE_STATUSES = ("starting", "running")
"""A run.json with one of these statuses is still being recorded (or was, by a server
that has since stopped: :meth:`RunStore.recover`)."""


class BadRunName(ValueError):
    """A run id or file name that is not one (the message says what one looks like)."""


class RunNotFound(LookupError):
    """No such run in the store, or no such file in the run's folder."""


class BadRecord(ValueError):
    """A run whose run.json is not a run's record (not an object, or a field of the wrong
    type): left out of the list, named."""


RECORD_FIELDS = {"scenario": (str,), "mode": (str,), "seed": (int,), "started_at": (str,),
                 "ended_at": (str,), "duration_s": (int, float), "status": (str,),
                 "reason": (str,), "headline": (dict,)}
"""run.json's fields the list reads, with their types (each may also be null)."""


def check_record(record, run_id: str) -> dict:
    """``record`` (a run.json read) if it is a run's record; BadRecord naming the run and
    the field otherwise."""
    if not isinstance(record, dict):
        raise BadRecord(f"run {run_id!r}: its {RUN_FILE} is not a run's record (a JSON "
                        f"object), it is {type(record).__name__}")
    for name, types in RECORD_FIELDS.items():
        value = record.get(name)
        if value is not None and (not isinstance(value, types) or isinstance(value, bool)):
            raise BadRecord(f"run {run_id!r}: its {RUN_FILE} has {name} = {value!r}, not "
                            f"{' or '.join(t.__name__ for t in types)}")
    return record


def check_run_id(run_id: str) -> str:
    """``run_id`` if it is a run's id (BadRunName otherwise: nothing else is ever looked
    up, so no path outside the store can be named)."""
    if not isinstance(run_id, str) or not RUN_ID.fullmatch(run_id):
        raise BadRunName(f"run id {run_id!r}: not a run's id (its start time and scenario, "
                         f"like 20261126T052345123Z-collision)")
    return run_id


def check_file_name(name: str) -> str:
    """``name`` if it can name a file of a run's folder (one name, no path)."""
    if not isinstance(name, str) or not FILE_NAME.fullmatch(name) or ".." in name:
        raise BadRunName(f"file name {name!r}: not a file of a run (one name: letters, "
                         f"digits, '.', '_', '-')")
    return name


def now_utc() -> dt.datetime:
    return dt.datetime.now(dt.timezone.utc)


def _write_json_atomic(path: Path, data: dict) -> None:
    """``data`` as JSON at ``path``, whole or not at all (a kill mid-write leaves the old)."""
    _write_text_atomic(path, json.dumps(json_safe(data), indent=2, allow_nan=False) + "\n")


def _write_text_atomic(path: Path, text: str) -> None:
    """``text`` at ``path``, whole or not at all: written to a temporary name, renamed; a
    failed write (a full disk) leaves the old file and no temporary one."""
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        tmp.write_text(text)
        os.replace(tmp, path)
    except BaseException:
        try:
            tmp.unlink(missing_ok=True)
        except OSError:  # (not a file of ours)
            pass
        raise


def _read_json(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _folder_bytes(folder: Path) -> int:
    total = 0
    for path in folder.rglob("*"):
        try:
            if path.is_file():
                total += path.stat().st_size
        except OSError:
            pass
    return total


def headline(metrics: dict | None) -> dict:
    """The figures the runs list shows: per satellite the largest tracking error and the
    velocity change; the restitution against the ideal run's, with its 95 % interval;
    capture; whether the success criteria were met; how many warnings."""
    if not metrics:
        return {}
    coll = metrics.get("collision") or {}
    capture = metrics.get("capture") or {}
    success = metrics.get("success") or {}
    return {
        "position_error_max_m": [s.get("position_error_max_m")
                                 for s in metrics.get("satellites", [])],
        "delta_v_mps": [s.get("delta_v_mps") for s in metrics.get("satellites", [])],
        "restitution": coll.get("restitution"),
        "restitution_ideal": coll.get("restitution_ideal"),
        "restitution_error": coll.get("restitution_error"),
        "restitution_interval_95": coll.get("restitution_interval_95"),
        "captured": capture.get("captured") if capture else None,
        "success": success.get("passed") if success else None,
        "warnings": len(metrics.get("warnings") or []) + len(coll.get("warnings") or []),
    }


class TelemetryAppender:
    """A run's telemetry.csv, appended to as the rows come (the header first): each
    :meth:`append` reaches the system before it returns (no buffer of its own), so a killed
    process loses nothing it appended; :meth:`close` also syncs it to the disk. Rows as a
    headless run writes them (%.12g).

    Whole rows only: a write that fails part-way (a full disk: ENOSPC) is cut back to the
    last whole row and raises; the rows of that call are not written (never half, never
    twice). ``file``: the open file (binary, unbuffered) the rows are written to."""

    def __init__(self, path: Path, columns: list[str]) -> None:
        self.path = path
        self.columns = list(columns)
        self._fmt = csv_row_format(len(columns))
        self.file = open(path, "ab", buffering=0)  # noqa: SIM115 - kept open
        self._size = self.file.seek(0, os.SEEK_END)  # the bytes of whole rows
        self.rows_written = 0
        if self._size == 0:
            self._write(",".join(columns) + "\n")

    def append(self, rows: np.ndarray) -> None:
        """Write ``rows`` whole, or none of them (OSError, the file as it was)."""
        if len(rows):
            self._write("".join(self._fmt % row for row in map(tuple, rows.tolist())))
            self.rows_written += len(rows)

    def _write(self, text: str) -> None:
        data = memoryview(text.encode("ascii"))
        done = 0
        try:
            while done < len(data):
                done += self.file.write(data[done:]) or 0
        except OSError:
            try:  # back to the last whole row (appends go on from there)
                os.ftruncate(self.file.fileno(), self._size)
            except OSError:
                pass
            raise
        self._size += len(data)

    def close(self) -> None:
        if self.file.closed:
            return
        try:
            os.fsync(self.file.fileno())
        except OSError:
            pass
        try:
            self.file.close()
        except OSError:
            pass


def read_telemetry(path: Path) -> tuple[list[str], np.ndarray]:
    """(columns, rows) of a run's telemetry.csv; a last line cut short by a kill is left
    out."""
    with open(path, encoding="ascii") as f:
        columns = f.readline().strip().split(",")
        lines = list(_complete_lines(f, len(columns)))
    if not lines:
        return columns, np.empty((0, len(columns)))
    return columns, np.loadtxt(lines, delimiter=",", ndmin=2)


def _complete_lines(f, n_columns: int):
    """The rows' lines of an open telemetry.csv (its header read), a last line cut short
    by a kill left out."""
    return (line for line in f if line.endswith("\n") and line.count(",") == n_columns - 1)


def telemetry_span(path: Path) -> tuple[list[str], int, float, float]:
    """(columns, rows, the first two rows' time step, the time from the first row to the
    last) of a telemetry.csv, read a line at a time (only its time column parsed)."""
    n, t = 0, []
    last = 0.0
    with open(path, encoding="ascii") as f:
        columns = f.readline().strip().split(",")
        for line in _complete_lines(f, len(columns)):
            last = float(line.split(",", 1)[0])
            if n < 2:
                t.append(last)
            n += 1
    dt_s = t[1] - t[0] if n >= 2 else 0.0
    return columns, n, dt_s, (last - t[0] if n else 0.0)


def read_telemetry_every(path: Path, step: int, max_rows: int | None = None,
                         ) -> tuple[list[str], np.ndarray]:
    """(columns, every step-th row from the first) of a telemetry.csv, among its first
    ``max_rows`` rows: only the rows kept are parsed and held."""
    kept = []
    with open(path, encoding="ascii") as f:
        columns = f.readline().strip().split(",")
        for k, line in enumerate(_complete_lines(f, len(columns))):
            if max_rows is not None and k >= max_rows:
                break
            if k % step == 0:
                kept.append(line)
    if not kept:
        return columns, np.empty((0, len(columns)))
    return columns, np.loadtxt(kept, delimiter=",", ndmin=2)


def run_config(folder: Path):
    """The EmulatorConfig a run in ``folder`` ran with (its config.json, in the mode it ran
    in, which the start may have chosen)."""
    from app.config import EmulatorConfig

    saved = _read_json(Path(folder) / "config.json") or {}
    config = EmulatorConfig.model_validate(saved["config"])
    if saved.get("mode"):
        config = config.model_copy(update={"loop": config.loop.model_copy(
            update={"mode": saved["mode"]})})
    return config


def write_plots(folder: str) -> list[str]:
    """The run's plots (app/runs/plots.py, as a headless run's) in its folder, from its
    telemetry.csv and metrics.json; the names written. Run in a worker process."""
    from app.runs.plots import plot_run

    folder_path = Path(folder)
    if not (folder_path / RUN_FILE).is_file():  # deleted meanwhile (retention, DELETE)
        return []
    metrics = _read_json(folder_path / "metrics.json") or {}
    config = run_config(folder_path)
    columns, rows = read_telemetry(folder_path / "telemetry.csv")
    index = {name: k for k, name in enumerate(columns)}
    note = (metrics.get("scaling") or {}).get("text", "")
    paths = plot_run(rows, index, folder_path, config, metrics, note=note)
    return [p.name for p in paths]


class RunStore:
    """The runs kept under ``root`` (created if missing)."""

    def __init__(self, root: str | Path = DEFAULT_RUNS_DIR, keep_runs: int = DEFAULT_KEEP_RUNS,
                 max_bytes: int | None = None, create: bool = True) -> None:
        if keep_runs < 1:
            raise ValueError(f"keep_runs: must be at least 1, got {keep_runs}")
        if max_bytes is not None and max_bytes <= 0:
            raise ValueError(f"max_bytes: must be positive, got {max_bytes}")
        self.root = Path(root)
        self.keep_runs, self.max_bytes = keep_runs, max_bytes
        if create:
            self.root.mkdir(parents=True, exist_ok=True)
        elif not self.root.is_dir():
            raise RunNotFound(f"no runs directory {str(self.root)!r} (serve --runs-dir "
                              f"writes one; default {DEFAULT_RUNS_DIR})")

    def retention(self) -> str:
        """The retention rule, in words (the page and `serve --help` say it)."""
        size = "" if self.max_bytes is None else f" and at most {self.max_bytes / 2**20:g} MiB"
        return (f"the newest {self.keep_runs} runs{size} are kept in {self.root}; "
                f"older ones are deleted, oldest first")

    # --- making a run --------------------------------------------------------------------

    def create(self, scenario: str, mode: str, config: dict, seed: int | None,
               started: dt.datetime | None = None, **facts) -> str:
        """A new run's folder with its run.json (status "running") and config.json; its
        id. The oldest runs beyond the retention go first."""
        started = started or now_utc()
        slug = re.sub(r"[^a-z0-9-]+", "-", scenario.lower()).strip("-")[:60] or "run"
        stamp = started.strftime("%Y%m%dT%H%M%S") + f"{started.microsecond // 1000:03d}Z"
        run_id, k = f"{stamp}-{slug}", 1
        self.root.mkdir(parents=True, exist_ok=True)  # (again, if it was deleted meanwhile)
        while True:
            try:
                (self.root / run_id).mkdir()
                break
            except FileExistsError:
                k += 1
                run_id = f"{stamp}-{slug}-{k}"
        folder = self.root / run_id
        try:
            _write_json_atomic(folder / "config.json",
                               {"scenario": scenario, "mode": mode, "config": config})
            _write_json_atomic(folder / RUN_FILE, {
                "id": run_id, "scenario": scenario, "mode": mode, "seed": seed,
                "started_at": started.isoformat(timespec="milliseconds"), "ended_at": None,
                "duration_s": None, "status": "running", "reason": None,
                "server_pid": os.getpid(), "headline": {}, **facts})
        except OSError:  # (a full disk): no folder without its record
            shutil.rmtree(folder, ignore_errors=True)
            raise
        self.prune(keep={run_id})
        return run_id

    def folder(self, run_id: str) -> Path:
        """The folder of run ``run_id`` (BadRunName / RunNotFound)."""
        folder = self.root / check_run_id(run_id)
        if not (folder / RUN_FILE).is_file():
            raise RunNotFound(f"no run {run_id!r} in {self.root}")
        return folder

    def update(self, run_id: str, **fields) -> dict:
        """run.json of ``run_id`` with ``fields`` changed; the new record."""
        folder = self.folder(run_id)
        record = _read_json(folder / RUN_FILE)
        if not isinstance(record, dict):  # (a run.json spoiled by hand)
            record = {"id": run_id}
        record.update(fields)
        _write_json_atomic(folder / RUN_FILE, record)
        return record

    def finish(self, run_id: str, metrics: dict, status: str, reason: str | None,
               ended: dt.datetime | None = None) -> dict:
        """The run ended: its metrics.json and summary.txt, and run.json with its end,
        status, reason and headline figures."""
        folder = self.folder(run_id)
        _write_json_atomic(folder / "metrics.json", metrics)
        try:
            _write_text_atomic(folder / "summary.txt", run_summary(json_safe(metrics)) + "\n")
        except (KeyError, TypeError, ValueError):  # a partial record: the summary can wait
            pass
        return self.update(run_id, status=status, reason=reason,
                           ended_at=(ended or now_utc()).isoformat(timespec="milliseconds"),
                           duration_s=metrics.get("duration_s"), headline=headline(metrics))

    # --- reading -------------------------------------------------------------------------

    def ids(self) -> list[str]:
        """Every run's id, oldest first (ids sort by start time)."""
        try:
            names = [p.name for p in self.root.iterdir()]
        except (FileNotFoundError, NotADirectoryError):  # deleted: no runs (until the next)
            return []
        return sorted(n for n in names
                      if RUN_ID.fullmatch(n) and (self.root / n / RUN_FILE).is_file())

    def runs(self) -> list[dict]:
        """Each run's run.json, newest first, with ``replay``: whether its replay.html is
        kept. A run.json that is not a run's record is left out, with a warning naming
        it (logged)."""
        out = []
        for run_id in reversed(self.ids()):
            record = _read_json(self.root / run_id / RUN_FILE)
            if record is None:
                continue
            try:
                check_record(record, run_id)
            except BadRecord as err:
                log.warning("%s; left out of the runs list", err)
                continue
            out.append({**record, "id": run_id,
                        "replay": (self.root / run_id / REPLAY_FILE).is_file()})
        return out

    def files(self, run_id: str) -> list[str]:
        """The names of the files in the run's folder (its subfolders, such as a bag, are
        not served one file at a time)."""
        folder = self.folder(run_id)
        return sorted(p.name for p in folder.iterdir()
                      if p.is_file() and FILE_NAME.fullmatch(p.name))

    def run(self, run_id: str) -> dict:
        """run.json of ``run_id`` with its ``metrics`` (None before it ended) and ``files``."""
        folder = self.folder(run_id)
        record = check_record(_read_json(folder / RUN_FILE) or {}, run_id)
        return {**record, "id": run_id, "metrics": _read_json(folder / "metrics.json"),
                "config": _read_json(folder / "config.json"),
                "files": self.files(run_id)}

    def file(self, run_id: str, name: str) -> Path:
        """The path of file ``name`` of run ``run_id``: only a regular file right in its
        folder (BadRunName / RunNotFound, naming it)."""
        check_file_name(name)
        folder = self.folder(run_id)
        path = folder / name
        if name not in self.files(run_id) or path.is_symlink():
            raise RunNotFound(f"run {run_id!r} has no file {name!r}")
        return path

    # --- retention ----------------------------------------------------------------------

    def delete(self, run_id: str) -> None:
        shutil.rmtree(self.folder(run_id))

    def prune(self, keep: set[str] = frozenset()) -> list[str]:
        """Delete the oldest runs beyond ``keep_runs`` (and ``max_bytes``), never those in
        ``keep`` (the runs being recorded); the ids deleted."""
        ids = self.ids()
        gone = []
        while len(ids) > self.keep_runs:
            victim = next((i for i in ids if i not in keep), None)
            if victim is None:
                break
            ids.remove(victim)
            shutil.rmtree(self.root / victim, ignore_errors=True)
            gone.append(victim)
        if self.max_bytes is not None:
            sizes = {i: _folder_bytes(self.root / i) for i in ids}
            total = sum(sizes.values())
            for victim in [i for i in ids if i not in keep]:
                if total <= self.max_bytes:
                    break
                shutil.rmtree(self.root / victim, ignore_errors=True)
                total -= sizes[victim]
                gone.append(victim)
        return gone

    def recover(self) -> list[str]:
        """Runs left "running" by a server that is gone (killed, or its machine stopped):
        marked "interrupted", with what they recorded kept; the ids."""
        found = []
        for record in self.runs():
            if record.get("status") not in LIVE_STATUSES:
                continue
            pid = record.get("server_pid")
            if pid == os.getpid() or (isinstance(pid, int) and _alive(pid)
                                      and pid != os.getpid() and _same_server(pid)):
                continue
            self.update(record["id"], status="interrupted", reason=(
                "the server that recorded it stopped before the run ended; its telemetry "
                "up to then is kept"))
            found.append(record["id"])
        return found


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _same_server(pid: int) -> bool:
    """Whether process ``pid`` looks like an orbit-emulator server still recording (a pid
    reused by another program does not)."""
    try:
        cmdline = Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return False
    return b"orbit" in cmdline or b"pytest" in cmdline or b"uvicorn" in cmdline
