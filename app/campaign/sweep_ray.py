"""Running a sweep's runs as Ray tasks (app/campaign/sweep.py plans them, keeps the table).

With no address, Ray starts on this machine for the sweep and stops at its end; with one,
the sweep joins that Ray cluster (``ray start --head`` there) and leaves it running. Each
run is one task (``max_retries=1``: a worker that dies is retried once) that returns only
its row's outcome (the metrics), never its telemetry; a hil run of two or more satellites
gets its ideal reference from a task computed once per configuration (apart from the seed)
and shared by the runs of every seed; the next configurations' ideal runs start while the
runs of the one before them are under way (a worker never idles waiting for one while
another could be computed; a local Ray's first one is computed while Ray starts, in a
process forked from the driver). Rows are appended to results.csv as runs end; Ctrl+C
cancels what is under way and keeps them.
"""

from __future__ import annotations

import os
import pickle
import re
import socket
import sys
import threading
import time
from collections import OrderedDict, deque
from contextlib import contextmanager
from pathlib import Path

from app.campaign.leftovers import descendants, end_leftovers, live_name
from app.campaign.sweep import (
    ResultsTable,
    Run,
    SweepPlan,
    compute_ideal,
    execute_run,
    lost_outcome,
    read_results,
    row_of,
    status_counts,
    unresolved_outcome,
)
from app.runs.replicate_pool import Apart, apart
from app.runs.report import write_json
from app.runs.signals import held_stops, interrupts_held, reassert_handlers

CONNECT_TIMEOUT_S = 20.0
"""How long joining a cluster may take before the sweep gives up (Ray's own connect
retries for minutes)."""
PROBE_TIMEOUT_S = 5.0
"""The TCP connect to the head's port, before Ray is asked to join."""
OBJECT_STORE_BYTES = 256 * 2**20
"""A local Ray's object store: runs return only their metrics."""
IDEAL_CACHE = 64
"""Ideal references kept for runs still to come (runs of one configuration are adjacent)."""
IDEAL_APART_TIMEOUT_S = 300.0
"""How long the first ideal run, computed apart while Ray starts, is waited for (a
pre-flight and its forecast take seconds) before a Ray task computes it instead."""
RAY_STOP_WAIT_S = 0.5
"""How long a stop that came while Ray starts waits to see whether Ray's GCS ends with it
(a SIGTERM ends it within a tenth of a second)."""
LOOKAHEAD_RUNS = 256
"""How far ahead of the runs under way the sweep looks for ideal references to start."""


def run_sweep(plan: SweepPlan, out_dir: Path, *, address: str | None = None,
              workers: int | None = None, resume: bool = False, keep: str = "metrics",
              quiet: bool = False) -> dict:
    """Run a planned sweep into out_dir (results.csv, summary.json, runs/<run-id>/); its
    summary. Starts Ray only if a run is left to do."""
    out_dir.mkdir(parents=True, exist_ok=True)
    table = ResultsTable(out_dir / "results.csv", plan.columns(), resume)
    t0 = time.perf_counter()
    summary = {"runs_planned": plan.count, "skipped": 0, "ran": 0, "ideal_runs": 0,
               "ideal_runs_ahead": 0, "ideal_runs_apart": 0,
               "address": address or "local", "workers": None, "interrupted": False}
    pending = _pending(plan, table, summary)
    first = next(pending, None)
    try:
        if first is not None:
            _execute(plan, [first], pending, table, out_dir, summary, address=address,
                     workers=workers, keep=keep, quiet=quiet)
    except KeyboardInterrupt:
        summary["interrupted"] = True
        raise
    finally:
        table.close()
        if table.path.exists():  # not when Ray could not start: nothing to continue
            _write_summary(out_dir, table, summary, time.perf_counter() - t0)
    return summary


def _pending(plan: SweepPlan, table: ResultsTable, summary: dict):
    """The plan's runs not yet in the table (and each run once: equal configurations
    are one run)."""
    seen = set()
    for run in plan.runs():
        if run.run_id in table.done or run.run_id in seen:
            summary["skipped"] += 1
            continue
        seen.add(run.run_id)
        yield run


def _execute(plan, first: list[Run], pending, table, out_dir, summary, *, address, workers,
             keep, quiet) -> None:
    from tqdm import tqdm

    early = None if address else _ideal_apart(first[0])  # while a local Ray starts
    try:
        ray = start_ray(address, workers)
    except BaseException:
        _drop(early)
        raise
    try:
        cpus = int(ray.cluster_resources().get("CPU", 1))
        summary["workers"] = min(cpus, workers) if workers else cpus
        # runs submitted at once: two per worker keeps them busy; on a cluster, --workers
        # caps the runs under way (locally Ray itself has only that many CPUs)
        window = workers if (address and workers) else 2 * summary["workers"]
        run_task = ray.remote(num_cpus=1, max_retries=1)(execute_run)
        ideal_task = ray.remote(num_cpus=1, max_retries=1)(compute_ideal)
        ideals: OrderedDict = OrderedDict()
        if early is not None:  # resolved (ray.put) when its first run is submitted
            ideals[first[0].ideal_id] = early
        ahead: set = set()  # configurations whose ideal started before their runs
        in_flight: dict = {}
        upcoming = _Lookahead(first, pending)
        bar = tqdm(total=plan.count - summary["skipped"], unit="run", file=sys.stderr,
                   disable=quiet, smoothing=0.1)
        counts = status_counts([])
        try:
            while True:
                _prefetch_ideals(upcoming, ideals, ahead, ideal_task, summary)
                while len(in_flight) < window:
                    run = upcoming.pop()
                    if run is None:
                        break
                    if run.config is None:  # its settings are not valid together
                        _finish(plan, run, unresolved_outcome(run), table, out_dir, keep)
                        counts["error"] += 1
                        bar.update(1)
                        continue
                    ideal = None
                    if run.ideal_id is not None:
                        if isinstance(ideals.get(run.ideal_id), Apart):
                            _resolve_apart(ideals, run, ideal_task, ray, summary)
                        ideal = _ideal_ref(ideals, run, ideal_task, summary)
                        ahead.discard(run.ideal_id)
                    ref = run_task.remote(run.config, ideal, keep,
                                          str(out_dir / "runs" / run.run_id))
                    in_flight[ref] = run
                bar.total = plan.count - summary["skipped"]
                if not in_flight:
                    break
                done, _ = ray.wait(list(in_flight), num_returns=1, timeout=1.0)
                for ref in done:
                    run = in_flight.pop(ref)
                    try:
                        outcome = ray.get(ref)
                    except ray.exceptions.RayError as err:
                        outcome = lost_outcome(err)
                    _finish(plan, run, outcome, table, out_dir, keep)
                    summary["ran"] += 1
                    counts[outcome["status"]] = counts.get(outcome["status"], 0) + 1
                    bar.update(1)
                    bar.set_postfix({k: v for k, v in counts.items() if v}, refresh=False)
        except KeyboardInterrupt:
            # no ray.cancel: a forced cancel racing a task's reply aborts Ray 2.60's core
            # ("Tried to complete task that was not pending"); the shutdown below ends this
            # driver, and with it the tasks it owns (a local Ray's workers, too)
            raise
        finally:
            bar.close()
    finally:
        with interrupts_held():  # Ray stopped whole, then the stop acts
            _drop(early)
            _shutdown(ray)


class _Lookahead:
    """The runs still to submit, with the next LOOKAHEAD_RUNS of them in view."""

    def __init__(self, first: list[Run], pending):
        self._buffer = deque(first)
        self._pending = pending

    def pop(self) -> Run | None:
        """The next run to submit (None when there is none)."""
        return self._buffer.popleft() if self._buffer else next(self._pending, None)

    def ahead(self):
        """The runs to come, nearest first, LOOKAHEAD_RUNS at most."""
        while len(self._buffer) < LOOKAHEAD_RUNS:
            run = next(self._pending, None)
            if run is None:
                break
            self._buffer.append(run)
        return iter(self._buffer)


def _prefetch_ideals(upcoming: _Lookahead, ideals: OrderedDict, ahead: set, ideal_task,
                     summary: dict) -> None:
    """Start the ideal runs of the configurations to come, nearest first, so that one per
    worker is started ahead of its runs: the runs that wait for an ideal hold no worker,
    so without this a worker idles while the next configuration's ideal runs alone.
    ``ahead``: the configurations whose ideal was started ahead and none of whose runs
    has been submitted yet (kept up to date here and by the caller); bounding them, not
    the unfinished ideals, keeps the look-ahead from running away once ideals finish
    fast, and from evicting from the cache an ideal its runs still need."""
    room = min(summary["workers"], IDEAL_CACHE // 2) - len(ahead)
    for run in upcoming.ahead():
        if room <= 0:
            break
        if run.config is not None and run.ideal_id is not None and run.ideal_id not in ideals:
            _ideal_ref(ideals, run, ideal_task, summary)
            ahead.add(run.ideal_id)
            summary["ideal_runs_ahead"] += 1
            room -= 1


def _ideal_apart(run: Run) -> Apart | None:
    """The first configuration's ideal run (``compute_ideal``), started in a process
    forked from this one before a local Ray starts: Ray's start takes seconds in which no
    worker can take a task. None where the run needs none or no process can be had."""
    if run.config is None or run.ideal_id is None:
        return None
    try:
        return apart(compute_ideal, run.config)
    except OSError:
        return None


def _resolve_apart(ideals: OrderedDict, run: Run, ideal_task, ray, summary: dict) -> None:
    """The ideal run computed apart (:func:`_ideal_apart`), waited for and put into Ray's
    object store for the runs that need it; if its process died or gave no answer within
    :data:`IDEAL_APART_TIMEOUT_S` (it is then killed), a Ray task as any other's."""
    computing = ideals.pop(run.ideal_id)
    try:
        ideal = computing.result(IDEAL_APART_TIMEOUT_S)
    except (OSError, EOFError, pickle.UnpicklingError):  # it died or hung: a Ray task
        _ideal_ref(ideals, run, ideal_task, summary)
        return
    ideals[run.ideal_id] = ray.put(ideal)
    summary["ideal_runs"] += 1
    summary["ideal_runs_apart"] += 1


def _drop(computing: Apart | None) -> None:
    """Stop an ideal run computed apart, if it is still under way."""
    if computing is not None:
        computing.stop()


def _ideal_ref(ideals: OrderedDict, run: Run, ideal_task, summary: dict):
    """The ObjectRef of the run's ideal reference: submitted once per configuration."""
    if run.ideal_id in ideals:
        ideals.move_to_end(run.ideal_id)
    else:
        ideals[run.ideal_id] = ideal_task.remote(run.config)
        summary["ideal_runs"] += 1
        if len(ideals) > IDEAL_CACHE:
            ideals.popitem(last=False)
    return ideals[run.ideal_id]


def _finish(plan: SweepPlan, run: Run, outcome: dict, table: ResultsTable, out_dir: Path,
            keep: str) -> None:
    """A run's row into the table, and its metrics.json unless --keep none."""
    if keep != "none" and outcome["metrics"] is not None:
        write_json(out_dir / "runs" / run.run_id / "metrics.json", outcome["metrics"])
    table.append(row_of(plan, run, outcome))


def _write_summary(out_dir: Path, table: ResultsTable, summary: dict, wall_s: float) -> None:
    summary["rows"] = len(table.done)
    summary["counts"] = status_counts(table.done.values())
    summary["wall_s"] = round(wall_s, 3)
    summary["runs_per_minute"] = round(60.0 * summary["ran"] / wall_s, 3) if wall_s else None
    _, rows = read_results(table.path)
    rss = [float(r["worker_rss_peak_MiB"]) for r in rows if r["worker_rss_peak_MiB"]]
    summary["worker_rss_peak_MiB"] = max(rss) if rss else None
    write_json(out_dir / "summary.json", summary)


# --- Ray ---------------------------------------------------------------------------------------


def start_ray(address: str | None, workers: int | None):
    """Ray, started here (no address: for this sweep only) or joined (a
    cluster's head, HOST:PORT); the ``ray`` module. Usage statistics stay off."""
    os.environ["RAY_USAGE_STATS_ENABLED"] = "0"
    import logging

    import ray

    common = {"include_dashboard": False, "log_to_driver": False,
              "logging_level": logging.WARNING, "configure_logging": True}
    if address is None:
        # at most one worker per core here: more only share the cores and the memory
        _init_holding_signals(ray, address="local",
                              num_cpus=min(workers or os.cpu_count() or 1, os.cpu_count() or 1),
                              object_store_memory=OBJECT_STORE_BYTES, **common)
        return ray
    host, port = parse_address(address)
    probe_address(host, port)
    if "RAY_AUTH_MODE" not in os.environ and _auth_token_available():
        os.environ["RAY_AUTH_MODE"] = "token"  # as Ray does for a cluster it finds itself
    _join(ray, f"{host}:{port}", common)
    return ray


def _init_holding_signals(ray, **options) -> None:
    """``ray.init(**options)`` with a stop that comes meanwhile held until it returns
    (:func:`held_stops`); then Ray is shut down again and the sweep ends as interrupted
    (no run has started). Acted on where it came, it ended ``ray.init`` half-way: its
    agents were left running, and Ray's own SIGTERM handler exited at once (status 15).
    That handler is set through ``ray._private.utils.set_sigterm_handler``, held to
    nothing meanwhile. A stop that also ends Ray's GCS (one sent to the whole process
    group) cannot be held: ``ray.init`` would wait for the GCS, then fail or end the
    process itself (exit 1 after 60 s); the sweep ends there
    (:func:`_end_if_ray_stopped_too`), once its handler runs (a call that holds the
    interpreter delays it, up to Ray's 30 s). What Ray leaves behind is ended with the
    sweep (app/campaign/leftovers.py)."""
    with held_stops("stopping once Ray has started (a few seconds)",
                    on_stop=_end_if_ray_stopped_too) as came, _ray_sigterm_handler_held(ray):
        try:
            ray.init(**options)
        except Exception:  # the stop's doing, if one came
            if not came:
                raise
    if came:
        try:
            _shutdown(ray)
        except Exception:  # noqa: BLE001 - a Ray cut short by the stop: what is left of
            pass  # it is ended with the sweep (app/campaign/leftovers.py)
        raise KeyboardInterrupt


def _end_if_ray_stopped_too(wait_s: float = RAY_STOP_WAIT_S) -> None:
    """In a stop's handler while Ray starts: if Ray's GCS under this process is not alive
    (the stop reached it too, or it has not started), or no longer is ``wait_s`` later,
    the sweep ends at once as interrupted (130): no run has started and nothing is
    written yet; what Ray had started is ended first. Raising from a handler could land
    where Python ignores the exception (a lock's release); ``os._exit`` cannot."""
    deadline = time.monotonic() + wait_s
    while any(live_name(pid) == "gcs_server" for pid in descendants()):
        if time.monotonic() >= deadline:
            return
        time.sleep(0.02)
    print("interrupted: no run had ended", file=sys.stderr, flush=True)
    end_leftovers(set())
    os._exit(130)


@contextmanager
def _ray_sigterm_handler_held(ray):
    """``ray.init``'s own SIGTERM handler (``sys.exit`` on the spot) not installed for the
    block (main thread only: elsewhere Ray does not install it)."""
    utils = getattr(getattr(ray, "_private", None), "utils", None)
    own = getattr(utils, "set_sigterm_handler", None)
    if own is None or threading.current_thread() is not threading.main_thread():
        yield
        return
    utils.set_sigterm_handler = lambda handler: None
    try:
        yield
    finally:
        utils.set_sigterm_handler = own


def _shutdown(ray) -> None:
    """``ray.shutdown()``, then the stop signals' handlers put back in force (Ray's core
    resets SIGTERM's action to the default underneath Python: a SIGTERM then killed the
    sweep before its summary was written)."""
    try:
        ray.shutdown()
    finally:
        reassert_handlers()


def _auth_token_available() -> bool:
    """Whether this machine has a Ray authentication token (RAY_AUTH_TOKEN,
    RAY_AUTH_TOKEN_PATH or ~/.ray/auth_token): a cluster with token authentication
    (Ray's default where a token exists) admits only a driver that presents it."""
    return bool(os.environ.get("RAY_AUTH_TOKEN") or os.environ.get("RAY_AUTH_TOKEN_PATH")
                or (Path.home() / ".ray" / "auth_token").is_file())


def parse_address(address: str) -> tuple[str, int]:
    """HOST:PORT of a Ray head."""
    host, sep, port = address.strip().rpartition(":")
    if not sep or not host or not re.fullmatch(r"[0-9]{1,5}", port) or not 0 < int(port) < 65536:
        raise ValueError(f"--address: expected HOST:PORT of a Ray head (e.g. "
                         f"10.0.0.5:6379), got {address!r}")
    return host, int(port)


def probe_address(host: str, port: int) -> None:
    """A TCP connect to the head's port, so that a dead address fails in seconds."""
    try:
        with socket.create_connection((host, port), timeout=PROBE_TIMEOUT_S):
            pass
    except OSError as err:
        reason = "timed out" if isinstance(err, TimeoutError) else (err.strerror or str(err))
        raise ValueError(
            f"--address {host}:{port}: no Ray head answers there ({reason}); start one "
            f"with `ray start --head --port={port}` on that machine, or leave --address "
            f"out to run on this one") from None


def _join(ray, address: str, options: dict) -> None:
    """ray.init to the cluster, given up after CONNECT_TIMEOUT_S: Ray's own connect retries
    for minutes on a port that is open but no Ray head of this version."""
    joined = threading.Event()

    def give_up():
        if not joined.is_set():
            print(f"error: --address {address}: no Ray cluster answered within "
                  f"{CONNECT_TIMEOUT_S:g} s (is it a Ray {ray.__version__} head, started with "
                  f"`ray start --head`?)", file=sys.stderr, flush=True)
            os._exit(2)  # ray.init cannot be interrupted; nothing has started yet

    timer = threading.Timer(CONNECT_TIMEOUT_S, give_up)
    timer.daemon = True
    timer.start()
    try:
        _init_holding_signals(ray, address=address, **options)
    except Exception as err:  # noqa: BLE001 - Ray raises many kinds; all are this
        raise ValueError(f"--address {address}: cannot join the Ray cluster: "
                         f"{' '.join(str(err).split())}") from None
    finally:
        joined.set()
        timer.cancel()


def describe(summary: dict, out_dir: Path) -> str:
    """The lines the command prints at the end."""
    counts = ", ".join(f"{n} {s}" for s, n in summary["counts"].items() if n) or "no rows"
    lines = [f"{summary['rows']} of {summary['runs_planned']} runs in "
             f"{out_dir / 'results.csv'}: {counts}",
             f"this time: {summary['ran']} run(s) in {summary['wall_s']:.1f} s"
             + (f" ({summary['runs_per_minute']:.1f} runs/min on {summary['workers']} "
                f"worker(s), {summary['ideal_runs']} ideal reference run(s))"
                if summary["ran"] else "")
             + (f", {summary['skipped']} already in the table" if summary["skipped"] else "")]
    return "\n".join(lines)
