"""A run's figures drawn in a process of their own (app/runs/plot_process.py): the same
files as drawn in the run's process, with the run's final metrics; a failure to write is
reported as the run's own would be, and a process that died leaves the run to draw."""

from __future__ import annotations

import functools
import os
import signal

import pytest

from app.runs import plot_process
from app.runs.headless import run_scenario
from tests.runs.test_uncertainty import short_collision


@pytest.fixture(scope="module")
def both(tmp_path_factory):
    """The same short collision written with its plots drawn here and apart."""
    config = short_collision("uncertainty.replicates=4", "uncertainty.forecast_replicates=4")
    out = {}
    for apart in (False, True):
        folder = tmp_path_factory.mktemp(f"apart-{apart}")
        out[apart] = (folder, run_scenario(config, out_dir=folder, plots_apart=apart))
    return out


def test_the_figures_drawn_apart_are_the_bytes_drawn_in_the_runs_process(both):
    (here, run_here), (apart, run_apart) = both[False], both[True]
    names = sorted(p.name for p in here.iterdir())
    assert sorted(p.name for p in apart.iterdir()) == names
    assert {"forces.png", "contact_closeup.png", "velocity.png", "figures.json"} <= set(names)
    assert sorted(p.name for p in run_apart.files) == sorted(p.name for p in run_here.files)
    for name in names:
        if name != "metrics.json":  # (its timings differ)
            assert (apart / name).read_bytes() == (here / name).read_bytes(), name
    # the figures carrying the collision's text were drawn with the final metrics: the
    # interval the replicates added after the process had started
    assert run_apart.metrics["collision"]["restitution_interval_95"] is not None


def test_a_folder_it_cannot_write_is_an_oserror_with_nothing_left(both, tmp_path):
    em, metrics = both[True][1].emulator, both[True][1].metrics
    blocked = tmp_path / "a file"
    blocked.write_text("")
    process = plot_process.start(em.telemetry.rows(), em.telemetry.index, blocked,
                                 em.config, metrics)
    with pytest.raises(OSError):
        process.finish(metrics)
    assert blocked.read_text() == ""


def test_a_process_that_died_leaves_the_drawing_to_the_run(both, tmp_path):
    em, metrics = both[True][1].emulator, both[True][1].metrics
    process = plot_process.start(em.telemetry.rows(), em.telemetry.index, tmp_path,
                                 em.config, metrics)
    os.kill(process._process.pid, signal.SIGKILL)
    process._process.join()
    assert process.finish(metrics) is None
    assert not any(tmp_path.iterdir())


def test_a_fork_refused_leaves_every_file_drawn_in_the_runs_process(both, monkeypatch,
                                                                    tmp_path):
    def refused():
        raise BlockingIOError(11, "Resource temporarily unavailable")

    monkeypatch.setattr(os, "fork", refused)
    config = short_collision("uncertainty.replicates=4", "uncertainty.forecast_replicates=4")
    run = run_scenario(config, out_dir=tmp_path, plots_apart=True)
    here = both[False][0]
    names = sorted(p.name for p in here.iterdir())
    assert sorted(p.name for p in tmp_path.iterdir()) == names
    assert {"metrics.json", "telemetry.csv", "forces.png", "figures.json"} <= set(names)
    assert run.unwritten is None
    for name in names:
        if name.endswith(".png"):
            assert (tmp_path / name).read_bytes() == (here / name).read_bytes(), name


def test_a_process_that_hangs_is_killed_at_the_bound_and_leaves_the_drawing(
        both, monkeypatch, tmp_path):
    import time

    from app.runs import plots

    em, metrics = both[True][1].emulator, both[True][1].metrics
    monkeypatch.setattr(plots, "plot_run", lambda *a, **k: time.sleep(30))  # (the child's)
    monkeypatch.setattr(plot_process, "FINISH_TIMEOUT_S", 1.0)
    process = plot_process.start(em.telemetry.rows(), em.telemetry.index, tmp_path,
                                 em.config, metrics)
    t0 = time.monotonic()
    assert process.finish(metrics) is None
    assert time.monotonic() - t0 < 3.0
    assert not process._process.is_alive()
    assert process._process.exitcode == -signal.SIGKILL
    assert not any(tmp_path.iterdir())


def test_a_process_that_fails_says_so_quietly(both, monkeypatch, tmp_path, capfd):
    from app.runs import plots

    def broken(*args, **kwargs):
        raise RuntimeError("no figures today")

    em, metrics = both[True][1].emulator, both[True][1].metrics
    monkeypatch.setattr(plots, "plan_figures", broken)  # (the child's: before its answer)
    process = plot_process.start(em.telemetry.rows(), em.telemetry.index, tmp_path,
                                 em.config, metrics)
    assert process.finish(metrics) is None  # the run then draws them
    assert process._process.exitcode == 1
    assert "Traceback" not in capfd.readouterr().err


def test_closed_before_its_figures_it_is_ended_at_once(both, tmp_path):
    import time

    em, metrics = both[True][1].emulator, both[True][1].metrics
    process = plot_process.start(em.telemetry.rows(), em.telemetry.index, tmp_path,
                                 em.config, metrics)
    t0 = time.monotonic()
    process.close()  # (the run failed before its files: finish not reached)
    assert time.monotonic() - t0 < 1.0
    assert process._process.exitcode == -signal.SIGKILL
    assert not any(tmp_path.iterdir())


def test_a_run_gone_without_its_figures_ends_the_process_by_itself(both, tmp_path, capfd):
    em, metrics = both[True][1].emulator, both[True][1].metrics
    process = plot_process.start(em.telemetry.rows(), em.telemetry.index, tmp_path,
                                 em.config, metrics)
    process._conn.close()  # as if the run's process had gone
    process._process.join(timeout=60.0)
    assert process._process.exitcode == 0  # it saw the pipe's end: no copy kept open
    assert not any(tmp_path.iterdir())
    assert "Traceback" not in capfd.readouterr().err


def test_where_processes_cannot_be_forked_none_is_started(both, monkeypatch, tmp_path):
    import multiprocessing

    em, metrics = both[True][1].emulator, both[True][1].metrics
    monkeypatch.setattr(multiprocessing, "get_all_start_methods", lambda: ["spawn"])
    assert plot_process.start(em.telemetry.rows(), em.telemetry.index, tmp_path, em.config,
                              metrics) is None  # (the run draws them: run_scenario's None)
    assert not any(tmp_path.iterdir())


def test_started_before_the_loop_it_waits_for_the_telemetry(both, tmp_path):
    """Forked before the loop, the process imports matplotlib while it waits; a run that
    ends before its loop does (its start-up failed) leaves nothing drawn: finish without
    begin is None (the run draws), and the process exits by itself once the pipe is gone."""
    em = both[True][1].emulator
    process = plot_process.prestart(tmp_path, em.config, (10, 3))
    assert process.finish({}) is None
    assert process._process.exitcode is not None
    assert not any(tmp_path.iterdir())
    waiting = plot_process.prestart(tmp_path, em.config, (10, 3))
    waiting._conn.close()  # the run's process gone before its loop ended
    waiting._process.join(timeout=60.0)
    assert waiting._process.exitcode == 0
    assert not any(tmp_path.iterdir())


def test_a_stopped_process_cannot_block_the_run(both, monkeypatch, tmp_path):
    """A process that stops answering before the loop ends (SIGSTOP: stuck in an import, a
    lock) takes the telemetry all the same, far more than a pipe holds, at once; the run
    then waits for it no longer than FINISH_TIMEOUT_S and draws the figures itself."""
    import time

    import numpy as np

    em, metrics = both[True][1].emulator, both[True][1].metrics
    monkeypatch.setattr(plot_process, "FINISH_TIMEOUT_S", 1.0)
    rows = np.tile(em.telemetry.rows(), (20, 1))  # some 30 MB: a pipe holds a few hundred kB
    process = plot_process.prestart(tmp_path, em.config, rows.shape)
    os.kill(process._process.pid, signal.SIGSTOP)
    try:
        t0 = time.monotonic()
        process.begin(rows, em.telemetry.index, metrics)
        assert time.monotonic() - t0 < 1.0
        assert process.finish(metrics) is None
        assert time.monotonic() - t0 < 3.0
    finally:
        process.close()
    assert process._process.exitcode == -signal.SIGKILL
    assert not any(tmp_path.iterdir())


def test_more_telemetry_than_it_was_started_for_is_an_oserror(both, tmp_path):
    em, metrics = both[True][1].emulator, both[True][1].metrics
    rows = em.telemetry.rows()
    process = plot_process.prestart(tmp_path, em.config, (len(rows) - 1, rows.shape[1]))
    try:
        with pytest.raises(OSError, match="the plot process was started for at most"):
            process.begin(rows, em.telemetry.index, metrics)
    finally:
        process.close()
    assert not any(tmp_path.iterdir())


def _planned(both, **changes):
    """The short collision's figures planned, its collision metrics changed as given."""
    import copy

    from app.runs.plots import plan_figures

    run = both[True][1]
    metrics = copy.deepcopy(run.metrics)
    metrics["collision"].update(changes)
    return plan_figures(run.emulator.telemetry.rows(), run.emulator.telemetry.index,
                        run.emulator.config, metrics)


def test_what_is_drawn_early_and_late_on_two_cores_is_the_bytes_drawn_here(both):
    """Before the final metrics, every figure is drawn on two cores, a figure with text
    but its text; after them, what they changed (the interval's line in the text): each
    PNG the same as drawn here, under its final signature."""
    from app.runs.plots import render, signature

    early = _planned(both, restitution_interval_95=None)
    final = _planned(both)
    assert [f.text for f in early] != [f.text for f in final]  # (the interval's line)
    here, there = plot_process._shares({f.name: (len(f.panels), None) for f in early})
    assert here and there and len(here) + len(there) == len(early)
    done = plot_process._early(early, "a note")
    assert {kind for kind, _ in done} == {"png", "panels"}
    rendered = plot_process._final(final, {f.name: f for f in early}, done, "a note")
    assert sorted(rendered) == sorted(f.name for f in final)
    for figure in final:
        assert rendered[figure.name] == (signature(figure, "a note"),
                                         render(figure, "a note")), figure.name


@pytest.mark.parametrize("child", ["fails", "hangs", "no fork"])
def test_what_the_child_does_not_deliver_is_drawn_here(both, monkeypatch, child):
    import time

    from app.runs.plots import render

    if child == "fails":
        monkeypatch.setattr(plot_process, "_do_share", lambda *a: os._exit(1))
    elif child == "hangs":
        monkeypatch.setattr(plot_process, "_do_share", lambda *a: time.sleep(30))
        monkeypatch.setattr(plot_process, "CHILD_TIMEOUT_S", 0.5)
    else:
        def refused():
            raise BlockingIOError(11, "Resource temporarily unavailable")

        monkeypatch.setattr(os, "fork", refused)
    figures = _planned(both)
    t0 = time.monotonic()
    done = plot_process._side_by_side({f.name: (len(f.panels), functools.partial(
        render, f, "")) for f in figures})
    assert time.monotonic() - t0 < 10.0
    for figure in figures:
        assert done[figure.name] == render(figure, ""), (child, figure.name)


def test_the_final_metrics_sent_early_are_those_drawn_and_a_process_gone_is_seen(both,
                                                                                 tmp_path):
    """The run sends its final metrics before it writes its record (send) and waits for
    the figures after it (finish): the figures are those of the metrics sent; sent to a
    process that has died, nothing raises and finish leaves the drawing to the run."""
    (here, _), run = both[False], both[True][1]
    em, metrics = run.emulator, run.metrics
    process = plot_process.start(em.telemetry.rows(), em.telemetry.index, tmp_path / "a",
                                 em.config, metrics, note=metrics["scaling"]["text"])
    process.send(metrics)
    process.send({})  # (once only)
    paths = process.finish({})
    assert {p.name for p in paths} >= {"forces.png", "figures.json"}
    for p in paths:
        assert p.read_bytes() == (here / p.name).read_bytes(), p.name
    gone = plot_process.start(em.telemetry.rows(), em.telemetry.index, tmp_path / "b",
                              em.config, metrics)
    os.kill(gone._process.pid, signal.SIGKILL)
    gone._process.join()
    gone.send(metrics)
    assert gone.finish(metrics) is None
    assert not (tmp_path / "b").exists() or not any((tmp_path / "b").iterdir())
