"""Headless runs: a scenario end to end, writing telemetry.csv, metrics.json and plots."""

from __future__ import annotations

import functools
import os
import shutil
import stat
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from app.config import EmulatorConfig, merge_overrides
from app.runs import plot_process
from app.runs.bag import check_bag_dir, replace_bag_dir, write_bag
from app.runs.forecast_cache import NOT_KEPT, cached_forecast, cached_reference, keep_reference
from app.runs.metrics import collision_metrics, compute_metrics, contact_pair
from app.runs.plots import FIGURES, FIGURES_FILE, plot_run
from app.runs.preflight import check_drift, preflight
from app.runs.report import write_json, write_telemetry_csv
from app.runs.signals import held_stops, interrupts_held
from app.runs.uncertainty import add_systematic, forecast, snapshot_time_s, spread_of_run
from app.sim.loop import Emulator


@dataclass
class RunResult:
    """What :func:`run_scenario` returns: the loop as it ended (its telemetry included),
    the run's metrics.json as a dict, and the files written."""

    emulator: Emulator
    metrics: dict
    files: list[Path]
    unwritten: RunFilesNotWritten | None = None
    """What could not be written where asked (and where it went instead)."""


class RunFailed(RuntimeError):
    """A headless run raised after its start-up: what it recorded up to then is written,
    its metrics.json with status "error" and the reason (``result``)."""

    def __init__(self, reason: str, result: RunResult) -> None:
        super().__init__(reason)
        self.result = result


def ideal_collision(config: EmulatorConfig, duration_s: float) -> dict:
    """The collision metrics of the same scenario run in ideal mode (the reference); {}
    when the ideal run has no contact."""
    em = Emulator(config, mode="ideal")
    em.run(duration_s)
    return collision_of(em)


def collision_of(em: Emulator) -> dict:
    """The collision metrics of an ideal run that ran; {} without contact."""
    rows, index = em.telemetry.rows(), em.telemetry.index
    pair = contact_pair(rows, index, em.n_sat) if em.n_sat >= 2 and len(rows) else None
    return {} if pair is None else collision_metrics(rows, index, em.dt_s, *pair) or {}


def checked_reference(config: EmulatorConfig, duration_s: float,
                      with_ideal: bool = True, processes: int = 1) -> dict | None:
    """Before a hil run: its pre-flight (app/runs/preflight.py; raises PreflightRefused naming
    the robot, the time and the limit), and from the same ideal run the collision
    reference a run with two or more satellites is compared with (None when it needs
    none). Nothing of the run itself has started.

    Once a setting has passed (the same configuration but its seed, duration and code),
    its reference is read back (app/runs/forecast_cache.py :func:`cached_reference`): the
    pre-flight, its ideal run and the forecast do not depend on the seed. ``processes``:
    how many processes run the forecast's replicates (app/runs/replicate_pool.py)."""
    if not with_ideal:
        preflight(config, duration_s)
        return None
    kept = cached_reference(config, duration_s)
    if kept is not NOT_KEPT:
        return kept
    reference = _checked_reference(config, duration_s, processes)
    keep_reference(config, duration_s, reference)
    return reference


def _checked_reference(config: EmulatorConfig, duration_s: float,
                       processes: int = 1) -> dict | None:
    """:func:`checked_reference` computed (with the ideal reference)."""
    prediction = preflight(config, duration_s)
    if len(config.satellites) < 2:
        return None
    if prediction is None:  # no robots: no pre-flight, but a reference still
        return ideal_collision(config, duration_s)
    reference = collision_of(prediction)  # at the run's rate (two satellites)
    if reference:  # the fidelity forecast (app/runs/uncertainty.py), in metrics.json,
        # once per setting (app/runs/forecast_cache.py)
        reference["forecast"] = cached_forecast(
            config, reference, functools.partial(forecast, processes=processes))
        check_drift(config, prediction, reference)  # the noise's drift after the contact
    return reference


def run_scenario(
    config: EmulatorConfig,
    mode: str | None = None,
    duration_s: float | None = None,
    out_dir: str | Path | None = None,
    progress=None,
    with_ideal: bool = True,
    bag: bool = False,
    bag_rate_hz: float | None = None,
    ideal: dict | None = None,
    preflight_done: bool = False,
    plots_apart: bool = False,
    processes: int = 1,
) -> RunResult:
    """Run a scenario headless; with out_dir, write its telemetry, metrics and plots (and
    with ``bag`` a ROS 2 bag, ``out_dir/bag``: :func:`app.runs.bag.write_bag`).

    The telemetry buffer is sized to hold the whole run, so nothing recorded is dropped;
    on a safety stop the run ends there and everything up to it is written. A hil run
    with two or more satellites is compared with its ideal run unless ``with_ideal`` is
    False; ``ideal``: that run's :func:`ideal_collision`, if already computed (it does not
    depend on the seed), else it is computed here. A hil run is refused before it starts
    when its pre-flight fails (PreflightRefused), unless ``preflight_done`` (the caller
    ran :func:`checked_reference`). A run that raises once started ends there: RunFailed,
    after its files are written (status "error"); one its start-up refuses (e.g. a start
    pose not found) raises as it is. ``plots_apart``: the plots are drawn in a process of
    their own while this one finishes the run (app/runs/plot_process.py; the same files).
    ``processes``: how many processes run the replicates of its pre-flight's forecast and
    of its interval (app/runs/replicate_pool.py; the same results).
    """
    duration_s = duration_s or config.loop.duration_s
    config = headless_config(config, duration_s)
    hil = (mode or config.loop.mode) == "hil"
    if hil and not preflight_done:
        reference = checked_reference(config, duration_s, with_ideal, processes)
        ideal = reference if ideal is None else ideal
    em = Emulator(config, mode=mode)
    if em.mode == "hil":  # the uncertainty's snapshot, before the predicted contact
        em.snapshot_at_s = snapshot_time_s(config, ideal)
    plotter = None
    if out_dir is not None and plots_apart:  # matplotlib imported while the loop runs
        try:
            plotter = plot_process.prestart(
                out_dir, em.config, (em.telemetry.capacity, len(em.columns)),
                guard=_whole_or_none)
        except OSError:  # no process to be had (EAGAIN, ENOMEM): drawn here
            plotter = None
    t0 = time.perf_counter()
    failure = interrupted = None
    try:
        failure = _run(em, duration_s, progress)
    except KeyboardInterrupt as err:  # Ctrl+C (or SIGTERM, app/runs/signals.py) in the loop:
        interrupted = err             # what it recorded is written, then it goes on up
        em.status = "interrupted"
    finally:
        wall_s = time.perf_counter() - t0
        # a stop from here on waits for the record: the metrics first (the ideal run's
        # comparison may take seconds), then the files; the interval is then left out
        with held_stops("interrupted: the run's record is written first") as stopped:
            if with_ideal and em.mode == "hil" and len(config.satellites) >= 2:
                if ideal is None:
                    ideal = ideal_collision(config, duration_s)
            else:
                ideal = None
            error = None if failure is None else f"{type(failure).__name__}: {failure}"
            metrics = compute_metrics(em, wall_s, ideal_collision=ideal, error=error)
            if plotter is not None:  # drawing while the replicates run
                try:
                    plotter.begin(em.telemetry.rows(), em.telemetry.index, metrics,
                                  note=metrics["scaling"]["text"])
                except OSError:  # it died: drawn here
                    plotter.close()
                    plotter = None
        try:
            if failure is None and interrupted is None:
                if stopped:
                    interrupted = KeyboardInterrupt()
                    _no_interval(em, metrics, "was interrupted: none")
                else:
                    interrupted = _add_uncertainty(em, metrics, processes)
            files, unwritten = [], None
            if out_dir is not None:
                try:
                    files = write_run_files(em, metrics, out_dir, bag=bag,
                                            bag_rate_hz=bag_rate_hz, plotter=plotter)
                except RunFilesNotWritten as err:
                    files, unwritten = err.files, err
        finally:
            if plotter is not None:
                plotter.close()
    if interrupted is not None:
        raise interrupted
    if failure is not None:
        raise RunFailed(error, RunResult(em, metrics, files, unwritten)) from failure
    return RunResult(em, metrics, files, unwritten)


def _add_uncertainty(em: Emulator, metrics: dict,
                     processes: int = 1) -> KeyboardInterrupt | None:
    """The restitution's interval from the replicates of the contact window
    (app/runs/uncertainty.py); if they fail, or are interrupted (the KeyboardInterrupt is
    returned, for the caller to raise once the record is written), the run's record is
    written all the same, with a warning and no interval."""
    coll = metrics.get("collision")
    if coll is None or em.snapshot is None:
        return None
    try:
        spread_of_run(em, coll, processes=processes)
        add_systematic(coll, metrics.get("collision_forecast"))
    except (Exception, KeyboardInterrupt) as err:  # noqa: BLE001 - the record matters more
        if isinstance(err, KeyboardInterrupt):
            _no_interval(em, metrics, "was interrupted: none")
            return err
        _no_interval(em, metrics, f"failed: {type(err).__name__}: {err}")
    return None


def _no_interval(em: Emulator, metrics: dict, why: str) -> None:
    """A run with a contact to bound whose interval is not computed: no interval, and a
    warning that says why (``the restitution's interval <why>``)."""
    coll = metrics.get("collision")
    if coll is None or em.snapshot is None:
        return
    coll["restitution_sd"] = coll["restitution_interval_95"] = coll["uncertainty"] = None
    coll["restitution_systematic"] = coll["restitution_bias_noisy"] = None
    coll["warnings"].append(f"the restitution's interval {why}")


def _run(em: Emulator, duration_s: float, progress) -> Exception | None:
    """Run ``em``: what it raised once started (its status then "error"), else None. What
    its start-up raises (nothing ran) is raised as it is."""
    try:
        em.run(duration_s, progress=progress)
    except Exception as err:
        if em.status != "running":
            raise
        em.status = "error"
        return err
    return None


def headless_config(config: EmulatorConfig, duration_s: float) -> EmulatorConfig:
    """The configuration with its telemetry sized to hold a whole headless run of
    duration_s (and no more: a sweep's worker runs many)."""
    cycles = max(int(round(duration_s * config.loop.rate_hz)) + 2, TELEMETRY_MIN_ROWS)
    if cycles > config.loop.telemetry_capacity:  # validated: the 1 GiB bound
        return merge_overrides(config, {"loop": {"telemetry_capacity": cycles}})
    if cycles < config.loop.telemetry_capacity:  # smaller is always valid
        return config.model_copy(update={
            "loop": config.loop.model_copy(update={"telemetry_capacity": cycles})})
    return config


TELEMETRY_MIN_ROWS = 100
"""The least telemetry capacity a configuration takes ([loop] telemetry_capacity)."""


RUN_FILES = ("telemetry.csv", "metrics.json", FIGURES_FILE,
             *(f"{name}.png" for name in FIGURES))
"""The files a headless run may write in its output folder (and ``bag/`` with --bag)."""


class RunFilesNotWritten(OSError):
    """Some of a run's files could not be written where asked; each was written in
    ``fallback`` instead where it could be (``files``: every path written)."""

    def __init__(self, problems: list[str], files: list[Path], fallback: Path | None) -> None:
        super().__init__("; ".join(problems))
        self.problems, self.files, self.fallback = problems, files, fallback


def check_run_files(out_dir: str | Path, bag: bool = False) -> None:
    """Before a run: each file it will write in ``out_dir`` is absent or a regular file
    that may be replaced (ValueError naming the path otherwise), so that no run is wasted
    on an output it cannot write."""
    out = Path(out_dir)
    for name in RUN_FILES:
        path = out / name
        try:
            info = os.stat(path)
        except FileNotFoundError:
            continue
        except OSError as err:
            raise ValueError(f"{path}: cannot be written: {err.strerror or err}") from None
        if not stat.S_ISREG(info.st_mode):
            kind = "a directory" if stat.S_ISDIR(info.st_mode) else "not a regular file"
            raise ValueError(f"{path}: exists and is {kind}; the run writes a file there: "
                             f"move it away or choose another --out")
        if not os.access(path, os.W_OK):
            raise ValueError(f"{path}: exists and is not writable; the run replaces it")
    if bag:
        check_bag_dir(out / "bag")


def write_run_files(em: Emulator, metrics: dict, out_dir: str | Path, telemetry: bool = True,
                    plots: bool = True, bag: bool = False,
                    bag_rate_hz: float | None = None,
                    plotter: plot_process.PlotProcess | None = None) -> list[Path]:
    """Write what a headless run leaves in ``out_dir``: metrics.json, and as asked
    telemetry.csv, the plots and the ROS 2 bag; the paths written. ``plotter``: the
    process drawing the plots into ``out_dir`` (app/runs/plot_process.py), joined here.

    Each is written on its own: one that fails does not keep the others from being
    written, and is written into a fresh folder of the system's temporary directory
    instead; RunFilesNotWritten then says where (nothing recorded is lost silently)."""
    out = Path(out_dir)
    rows = em.telemetry.rows()
    if plotter is not None and plots:  # it draws what they change while the record is written
        plotter.send(metrics)
    writers = [("metrics.json", lambda d: [_write_json(d / "metrics.json", metrics)])]
    if telemetry:
        writers.append(("telemetry.csv", lambda d: [
            _write_csv(d / "telemetry.csv", em.columns, rows)]))
    def draw(d: Path) -> list[Path]:
        if plotter is not None and d == out:
            drawn = plotter.finish(metrics)
            if drawn is not None:
                return drawn
        return plot_run(rows, em.telemetry.index, d, em.config, metrics,
                        note=metrics["scaling"]["text"])

    if plots:
        writers.append(("plots", draw))
    if bag:
        writers.append(("bag", lambda d: [write_bag(
            replace_bag_dir(d / "bag"), em.config, rows, em.telemetry.index, bag_rate_hz)]))
    files, problems, fallback = [], [], None

    def write_one(what: str, write) -> None:
        nonlocal fallback
        try:
            files.extend(_whole_or_none(write, out))
            return
        except (OSError, ValueError) as err:
            problem = f"{out / what}: could not be written ({_reason(err)})"
        try:
            if fallback is None:
                fallback = Path(tempfile.mkdtemp(prefix="orbit-emulator-run-"))
            files.extend(_whole_or_none(write, fallback))
            problems.append(f"{problem}; written to {fallback / what} instead")
        except (OSError, ValueError) as err:
            problems.append(f"{problem}, nor in {fallback}: {_reason(err)}")

    with interrupts_held():  # the record itself whole before an interrupt acts
        for what, write in writers:
            if what in RECORD_FILES:
                write_one(what, write)
    for what, write in writers:  # then what is drawn from it
        if what not in RECORD_FILES:
            write_one(what, write)
    if fallback is not None and not any(fallback.iterdir()):  # nothing went there either
        shutil.rmtree(fallback, ignore_errors=True)
    if problems:
        raise RunFilesNotWritten(problems, files, fallback)
    return files


RECORD_FILES = ("metrics.json", "telemetry.csv")
"""What a run recorded: Ctrl+C or SIGTERM waits until each is whole (a fraction of a
second); the figures and the bag, drawn from them, may be cut short."""


def _entries(folder: Path) -> dict[str, tuple[int, int, int]]:
    """(inode, size, mtime) of each entry of ``folder``."""
    out = {}
    for path in folder.iterdir() if folder.is_dir() else ():
        try:
            info = path.lstat()
        except OSError:
            continue
        out[path.name] = (info.st_ino, info.st_size, info.st_mtime_ns)
    return out


def _whole_or_none(write, folder: Path) -> list[Path]:
    """``write(folder)``; if it fails (a full disk, say), what it created or changed in
    ``folder`` is removed before the error goes on: no truncated file is left."""
    before = _entries(folder)
    try:
        return write(folder)
    except BaseException:
        for name, entry in _entries(folder).items():
            if before.get(name) != entry:
                path = folder / name
                if path.is_dir() and not path.is_symlink():
                    shutil.rmtree(path, ignore_errors=True)
                else:
                    path.unlink(missing_ok=True)
        raise


def _reason(err: Exception) -> str:
    return (getattr(err, "strerror", None) or str(err)) if isinstance(err, OSError) else str(err)


def _write_json(path: Path, data: dict) -> Path:
    write_json(path, data)
    return path


def _write_csv(path: Path, columns, rows) -> Path:
    write_telemetry_csv(path, columns, rows)
    return path
