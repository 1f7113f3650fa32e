"""A headless run's figures drawn in a process of their own while the run's process
finishes (the uncertainty's replicates, telemetry.csv, metrics.json), joined before the
run returns: where a second core is free, most of the plots cost the run no wall time.

:func:`start` forks the process once the loop has ended, with the run's telemetry and its
metrics as they are then (the restitution's interval not yet in them). It imports
matplotlib and draws at once each planned figure that carries no text of metrics (the
velocities, positions, tracking errors...), then waits for the final metrics
(:meth:`PlotProcess.finish`), plans again and writes every figure as
:func:`app.runs.plots.plot_run` does: a figure drawn early is written as it is only where
its signature (everything the drawing reads) is the final plan's; any other is drawn then.
The files are the same bytes a drawing in the run's own process writes.

A failure to write is reported back as it happened (OSError, ValueError: the caller then
writes the plots elsewhere, as for any file of a run), with nothing half written left in
the folder; a process that died (None from :meth:`~PlotProcess.finish`) leaves the caller
to draw them itself.
"""

from __future__ import annotations

import multiprocessing
import signal
import sys
from pathlib import Path

import numpy as np

__all__ = ["PlotProcess", "start"]


class PlotProcess:
    """The forked process drawing one run's figures (:func:`start`)."""

    def __init__(self, process, conn) -> None:
        self._process, self._conn = process, conn

    def finish(self, metrics: dict) -> list[Path] | None:
        """Send the run's final metrics, wait for its figures: the paths written; raises
        the OSError or ValueError that kept them from being written; None if the process
        died first (the caller then draws them)."""
        try:
            self._conn.send(metrics)
            answer = self._conn.recv()
        except (EOFError, OSError):
            answer = None
        finally:
            self.close()
        if answer is None:
            return None
        if answer[0] == "ok":
            return [Path(p) for p in answer[1]]
        kind, message = answer[1], answer[2]
        raise (OSError if kind == "OSError" else ValueError)(message)

    def close(self) -> None:
        """End the process (at once if it is still drawing) and free its pipe."""
        self._conn.close()
        self._process.join(timeout=60.0)
        if self._process.is_alive():
            self._process.kill()
            self._process.join()


def start(rows: np.ndarray, index: dict, out_dir: str | Path, config, metrics: dict,
          note: str = "", guard=None) -> PlotProcess:
    """Fork the process that draws the run's figures into ``out_dir`` (module doc);
    ``metrics``: the run's as they are now. ``guard(write, folder)``: how the files are
    written (app/runs/headless.py: whole, or nothing left in the folder)."""
    sys.stdout.flush()  # nothing the run printed is written twice by the child
    sys.stderr.flush()
    context = multiprocessing.get_context("fork")
    ours, theirs = context.Pipe()
    process = context.Process(target=_draw, args=(theirs, rows, index, Path(out_dir), config,
                                                  metrics, note, guard), daemon=True)
    process.start()
    theirs.close()
    return PlotProcess(process, ours)


def _draw(conn, rows, index, out_dir: Path, config, metrics: dict, note: str,
          guard) -> None:
    """The process's work (module doc)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # an interrupt is the run's to handle
    from app.runs.plots import plan_figures, plot_run, render, signature

    guard = guard or (lambda write, folder: write(folder))

    early = plan_figures(rows, index, config, metrics) if len(rows) else []
    rendered = {f.name: (signature(f, note), render(f, note)) for f in early if not f.text}
    try:
        final = conn.recv()
    except EOFError:  # the run ended without its figures
        return
    try:
        paths = guard(lambda d: plot_run(rows, index, d, config, final, note,
                                                 rendered=rendered), out_dir)
        conn.send(("ok", [str(p) for p in paths]))
    except (OSError, ValueError) as err:
        message = str(err) if not isinstance(err, OSError) else (err.strerror or str(err))
        conn.send(("error", "OSError" if isinstance(err, OSError) else "ValueError",
                   message))
