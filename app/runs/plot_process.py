"""A headless run's figures drawn in a process of their own while the run's process
finishes (the uncertainty's replicates, telemetry.csv, metrics.json), joined before the
run returns: where a second core is free, most of the plots cost the run no wall time.

:func:`prestart` forks the process before the loop starts: it imports matplotlib (half a
second) while the loop runs on the other core. Once the loop has ended,
:meth:`PlotProcess.begin` copies the run's telemetry into memory the two processes share
(mapped before the fork, sized for the run's telemetry buffer: nothing the size of the
telemetry goes through the pipe, so a process that has stopped answering cannot block the
run) and sends it the row count and the metrics as they are then (the restitution's
interval not yet in them; :func:`start` does both at once). While the run's replicates
go on, it draws what the final metrics cannot change, on two cores (itself and a process
it forks, matplotlib imported: :func:`_side_by_side`): each planned figure without text
whole, each with text (the metrics) all but its text (app/runs/plots.py render_panels).
Then it waits for the final metrics (:meth:`PlotProcess.finish`), plans again and writes
every figure as :func:`app.runs.plots.plot_run` does: a figure drawn early is taken as it
is only where its signature (everything the drawing reads) is the final plan's, a
figure's panels only where all but its text is (its text's strip is drawn then); any
other is drawn whole then. The files are the same bytes a drawing in the run's own
process writes.

A failure to write is reported back as it happened (OSError, ValueError: the caller then
writes the plots elsewhere, as for any file of a run), with nothing half written left in
the folder; a process that died (None from :meth:`~PlotProcess.finish`) leaves the caller
to draw them itself, as does one that has not answered within :data:`FINISH_TIMEOUT_S`
(killed then), or none at all where processes cannot be forked (:func:`start` gives None).
The process reports its own failures as an answer, never as a traceback on the run's
terminal.
"""

from __future__ import annotations

import functools
import mmap
import multiprocessing
import pickle
import sys
import time
from pathlib import Path

import numpy as np

from app.runs.replicate_pool import apart
from app.runs.signals import as_helper_process

__all__ = ["FINISH_TIMEOUT_S", "PlotProcess", "prestart", "start"]

FINISH_TIMEOUT_S = 120.0
"""How long :meth:`PlotProcess.finish` waits for the figures once the final metrics are
sent (a run's take a few seconds) before it kills the process and leaves them to the run."""
POLL_S = 0.5


class PlotProcess:
    """The forked process drawing one run's figures (:func:`start`)."""

    def __init__(self, process, conn, shared: mmap.mmap, shape: tuple[int, int]) -> None:
        self._process, self._conn = process, conn
        self._shared, self._shape = shared, shape
        self._answered = False  # (then it exits by itself)
        self._begun = False
        self._sent: bool | None = False  # the final metrics: sent; None: the send failed

    def begin(self, rows: np.ndarray, index: dict, metrics: dict, note: str = "") -> None:
        """Hand it the run's telemetry and its metrics as they are now (the loop has ended):
        it draws the figures that carry no text of metrics. Raises OSError where it cannot
        take them (more rows or columns than it was started for, or a process that has
        died: the caller then draws the figures itself)."""
        rows = np.asarray(rows, dtype=float)
        if rows.ndim != 2 or rows.shape[0] > self._shape[0] or rows.shape[1] != self._shape[1]:
            raise OSError(f"telemetry of shape {rows.shape}: the plot process was started "
                          f"for at most {self._shape}")
        _view(self._shared, self._shape)[:len(rows)] = rows
        self._conn.send((len(rows), index, metrics, note))
        self._begun = True

    def send(self, metrics: dict) -> None:
        """Send the run's final metrics now: the process draws what they change while the
        run writes its other files; :meth:`finish` then waits for the figures. Nothing
        where :meth:`begin` was not reached or they were sent already (a process gone is
        :meth:`finish`'s to see)."""
        if not self._begun or self._sent is not False:
            return
        try:
            self._conn.send(metrics)
            self._sent = True
        except (EOFError, OSError):
            self._sent = None

    def finish(self, metrics: dict) -> list[Path] | None:
        """Send the run's final metrics (unless :meth:`send` did: the figures are then
        those of the metrics it sent), wait for its figures: the paths written; raises
        the OSError or ValueError that kept them from being written; None if the process
        died first, failed, or gave no answer within :data:`FINISH_TIMEOUT_S` (it is then
        killed; the caller draws them; also where :meth:`begin` was not reached)."""
        if not self._begun:
            self.close()
            return None
        try:
            self.send(metrics)
            if not self._sent:
                raise OSError("the final metrics could not be sent")
            answer = self._answer(time.monotonic() + FINISH_TIMEOUT_S)
        except (EOFError, OSError):
            answer = None
        finally:
            self.close()
        if answer is None or answer[0] == "died":
            return None
        if answer[0] == "ok":
            return [Path(p) for p in answer[1]]
        kind, message = answer[1], answer[2]
        raise (OSError if kind == "OSError" else ValueError)(message)

    def _answer(self, deadline: float):
        """The process's answer; None if it died without one or the deadline passed."""
        while True:
            left_s = deadline - time.monotonic()
            if left_s <= 0.0:
                return None
            if self._conn.poll(min(POLL_S, left_s)):
                answer = self._conn.recv()  # (EOFError if it died: its end closed)
                self._answered = True
                return answer
            if not self._process.is_alive() and not self._conn.poll(0):
                return None

    def close(self) -> None:
        """Free the pipe and end the process: once it has exited after its answer to
        :meth:`finish`, else at once (finish not reached: the run failed before its
        figures; or no answer in time)."""
        self._conn.close()
        self._shared.close()
        if self._answered:
            self._process.join(timeout=5.0)
        if self._process.is_alive():
            self._process.kill()
        self._process.join()


def start(rows: np.ndarray, index: dict, out_dir: str | Path, config, metrics: dict,
          note: str = "", guard=None) -> PlotProcess | None:
    """:func:`prestart` and :meth:`PlotProcess.begin` at once (the loop has ended)."""
    process = prestart(out_dir, config, np.shape(rows), guard)
    if process is not None:
        try:
            process.begin(rows, index, metrics, note)
        except BaseException:
            process.close()
            raise
    return process


def prestart(out_dir: str | Path, config, shape: tuple[int, int],
             guard=None) -> PlotProcess | None:
    """Fork the process that draws the run's figures into ``out_dir`` (module doc) before
    the loop: it imports matplotlib, then waits for :meth:`PlotProcess.begin`. ``shape``:
    the most telemetry it will be given (the run's buffer: capacity × columns).
    ``guard(write, folder)``: how the files are written (app/runs/headless.py: whole, or
    nothing left in the folder). None where processes cannot be forked (the caller
    draws); raises the OSError of a fork that failed (EAGAIN, ENOMEM)."""
    if "fork" not in multiprocessing.get_all_start_methods():
        return None
    for stream in (sys.stdout, sys.stderr):  # nothing the run printed is written twice
        if stream is not None:  # by the child (None: a descriptor the caller closed)
            stream.flush()
    shape = (int(shape[0]), int(shape[1]))
    shared = mmap.mmap(-1, max(1, 8 * shape[0] * shape[1]))  # anonymous, shared with the fork
    context = multiprocessing.get_context("fork")
    ours, theirs = context.Pipe()
    process = context.Process(target=_draw, args=(theirs, shared, shape, Path(out_dir), config,
                                                  guard, ours), daemon=True)
    try:
        process.start()
    except BaseException:
        ours.close()
        shared.close()
        raise
    finally:
        theirs.close()
    return PlotProcess(process, ours, shared, shape)


def _view(shared: mmap.mmap, shape: tuple[int, int]) -> np.ndarray:
    """The shared telemetry as rows (shape), no copy."""
    return np.frombuffer(shared, dtype=float, count=shape[0] * shape[1]).reshape(shape)


def _draw(conn, shared: mmap.mmap, shape: tuple[int, int], out_dir: Path, config, guard,
          runs_end=None) -> None:
    """The process's work (module doc). Whatever it raises is answered as ("died",
    reason) and ends it with exit status 1, quietly (the run then draws the figures).
    ``runs_end``: the run's end of the pipe, closed here (the fork's copy would keep
    the run's going away from being seen)."""
    as_helper_process()  # an interrupt is the run's to handle
    if runs_end is not None:
        runs_end.close()
    try:
        from app.runs.plots import pyplot

        pyplot()  # while the run's loop runs
        try:
            count, index, metrics, note = conn.recv()
        except (EOFError, OSError):  # the run ended before its loop did
            return
        rows = _view(shared, shape)[:count].copy()
        answer = _drawn(conn, rows, index, out_dir, config, metrics, note, guard)
    except BaseException as err:  # noqa: BLE001 - the run draws them; no second traceback
        _send(conn, ("died", f"{type(err).__name__}: {err}"))
        sys.exit(1)
    if answer is not None:
        _send(conn, answer)


def _drawn(conn, rows, index, out_dir: Path, config, metrics: dict, note: str, guard):
    """The figures drawn and written: the answer to send; None if the run ended without
    them. Whatever the final metrics cannot change is drawn on two cores while the run's
    replicates go on (:func:`_early`); then what they changed (a figure's text, mostly)."""
    from app.runs.plots import plan_figures, plot_run

    guard = guard or (lambda write, folder: write(folder))
    early = plan_figures(rows, index, config, metrics) if len(rows) else []
    done = _early(early, note)
    try:
        final = conn.recv()
    except (EOFError, OSError):  # the run ended without its figures
        return None
    plan = plan_figures(rows, index, config, final) if len(rows) else []
    rendered = _final(plan, {f.name: f for f in early}, done, note)
    try:
        paths = guard(lambda d: plot_run(rows, index, d, config, final, note,
                                         rendered=rendered), out_dir)
    except (OSError, ValueError) as err:
        message = str(err) if not isinstance(err, OSError) else (err.strerror or str(err))
        return ("error", "OSError" if isinstance(err, OSError) else "ValueError", message)
    return ("ok", [str(p) for p in paths])


def _early(figures: list, note: str) -> dict:
    """Drawn before the final metrics: each figure without text whole (its PNG), each with
    text all but its text (its panels' pixels, app/runs/plots.py render_panels); by
    (kind, name)."""
    from app.runs.plots import render, render_panels

    jobs = {(("panels" if f.text else "png"), f.name):
            (len(f.panels), functools.partial(render_panels if f.text else render, f, note))
            for f in figures}
    return _side_by_side(jobs)


def _final(plan: list, early: dict, done: dict, note: str) -> dict:
    """The final plan's figures: name -> (signature, PNG), from what was drawn early where
    the final figure is drawn alike (its signature, or but for its text its panels'),
    the rest drawn now on two cores."""
    from app.runs.plots import panels_signature, render, signature

    rendered, left = {}, {}
    for f in plan:
        was, sig = early.get(f.name), signature(f, note)
        if was is not None and not f.text and ("png", f.name) in done \
                and signature(was, note) == sig:
            rendered[f.name] = (sig, done["png", f.name])
            continue
        rendered[f.name] = (sig, None)  # drawn now: its text's strip, or all of it
        if was is not None and f.text and ("panels", f.name) in done \
                and panels_signature(was, note) == panels_signature(f, note):
            left[f.name] = (1, functools.partial(render, f, note, done["panels", f.name]))
        else:
            left[f.name] = (1 + len(f.panels), functools.partial(render, f, note))
    drawn = _side_by_side(left)
    return {name: (sig, drawn[name] if png is None else png)
            for name, (sig, png) in rendered.items()}


CHILD_TIMEOUT_S = 60.0
"""How long the second drawer (:func:`_side_by_side`) is waited for before this process
draws its share itself."""


def _side_by_side(jobs: dict) -> dict:
    """``jobs`` (key -> (weight, function)) done on two cores: key -> result. The heaviest
    here, the others in a process forked from this one (matplotlib already imported:
    app/runs/replicate_pool.py ``apart``); what it does not deliver (it failed, died, or
    took longer than :data:`CHILD_TIMEOUT_S`) is done here. The same results either way."""
    here, there = _shares(jobs)
    other = None
    if there:
        try:
            other = apart(_do_share, {key: jobs[key][1] for key in there})
        except OSError:  # no second process: all done here
            here, there = here + there, []
    try:
        out = {key: jobs[key][1]() for key in here}
    except BaseException:
        if other is not None:
            other.stop()
        raise
    if other is not None:
        try:
            theirs = other.result(CHILD_TIMEOUT_S)
        except (OSError, pickle.UnpicklingError, EOFError):
            theirs = {}
        out.update({key: theirs[key] if key in theirs else jobs[key][1]() for key in there})
    return out


def _shares(jobs: dict) -> tuple[list, list]:
    """The jobs' keys split in two of about equal weight, the heaviest in the first."""
    shares, load = ([], []), [0, 0]
    for key in sorted(jobs, key=lambda k: -jobs[k][0]):
        k = 0 if load[0] <= load[1] else 1
        shares[k].append(key)
        load[k] += jobs[key][0]
    return shares


def _do_share(share: dict) -> dict:
    """The other process's share (key -> function) done: key -> result."""
    return {key: fn() for key, fn in share.items()}


def _send(conn, answer) -> None:
    """Send ``answer`` to the run; nothing if the run is gone."""
    try:
        conn.send(answer)
    except (BrokenPipeError, EOFError, OSError):
        pass
