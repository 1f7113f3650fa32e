"""The runs store (app/runs/store.py): ids, retention, files, a telemetry.csv appended to
as a run goes, and runs a stopped server left."""

from __future__ import annotations

import datetime as dt
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from app.runs.store import (
    BadRunName,
    RunNotFound,
    RunStore,
    TelemetryAppender,
    check_file_name,
    check_run_id,
    read_telemetry,
    read_telemetry_every,
    telemetry_span,
)


def _at(second: int) -> dt.datetime:
    return dt.datetime(2026, 11, 26, 5, 0, second, 123000, tzinfo=dt.timezone.utc)


def _new(store: RunStore, second: int, scenario: str = "collision") -> str:
    return store.create(scenario, "hil", {"loop": {}}, 7, started=_at(second))


def test_a_run_is_named_by_its_start_time_and_scenario(tmp_path):
    store = RunStore(tmp_path)
    run_id = _new(store, 5)
    assert run_id == "20261126T050005123Z-collision"
    assert _new(store, 5) == "20261126T050005123Z-collision-2"  # the same millisecond
    record = store.run(run_id)
    assert (record["scenario"], record["mode"], record["seed"], record["status"]) == (
        "collision", "hil", 7, "running")
    assert record["started_at"] == "2026-11-26T05:00:05.123+00:00"
    assert record["config"] == {"scenario": "collision", "mode": "hil", "config": {"loop": {}}}
    assert record["files"] == ["config.json", "run.json"] and record["metrics"] is None


def test_retention_deletes_the_oldest_first_and_never_the_run_being_recorded(tmp_path):
    store = RunStore(tmp_path, keep_runs=3)
    ids = [_new(store, s) for s in range(5)]
    assert store.ids() == ids[2:]  # the oldest two went as the fourth and fifth came
    assert [r["id"] for r in store.runs()] == ids[:1:-1]  # newest first
    assert not (tmp_path / ids[0]).exists()
    assert store.prune(keep={ids[2]}) == []
    store.keep_runs = 1
    assert store.prune(keep={ids[2]}) == ids[3:]  # ids[2] is kept: it is recording
    assert store.ids() == [ids[2]]


def test_the_size_cap_deletes_the_oldest_until_the_runs_fit(tmp_path):
    store = RunStore(tmp_path, keep_runs=100, max_bytes=1)
    first = _new(store, 1)
    (tmp_path / first / "telemetry.csv").write_text("x" * 5000)
    second = _new(store, 2)  # over the cap: the oldest goes, never the new one
    assert store.ids() == [second]
    assert "at most" in store.retention() and "oldest first" in store.retention()
    with pytest.raises(ValueError, match="keep_runs: must be at least 1, got 0"):
        RunStore(tmp_path, keep_runs=0)


@pytest.mark.parametrize("bad", ["..", "../etc", "x", "20261126T050005123Z-Coll",
                                 "20261126T050005123Z-collision/..", "", "20261126T0500Z-a"])
def test_a_bad_run_id_is_refused_by_name(bad):
    with pytest.raises(BadRunName, match="not a run's id"):
        check_run_id(bad)


@pytest.mark.parametrize("bad", ["..", "../run.json", ".hidden", "a/b", "a..b", "", "x" * 200])
def test_a_bad_file_name_is_refused_by_name(bad):
    with pytest.raises(BadRunName, match="not a file of a run"):
        check_file_name(bad)


def test_files_are_only_the_regular_files_of_the_run_s_folder(tmp_path):
    store = RunStore(tmp_path / "runs")
    run_id = _new(store, 1)
    folder = store.folder(run_id)
    (tmp_path / "secret.txt").write_text("no")
    os.symlink(tmp_path / "secret.txt", folder / "link.txt")
    (folder / "bag").mkdir()
    assert store.file(run_id, "run.json") == folder / "run.json"
    for name in ("link.txt", "bag", "nope.png"):
        with pytest.raises(RunNotFound, match=f"run '{run_id}' has no file '{name}'"):
            store.file(run_id, name)
    with pytest.raises(RunNotFound, match="no run '20261126T050009123Z-collision' in"):
        store.run("20261126T050009123Z-collision")
    store.delete(run_id)
    assert store.ids() == []


def test_the_appended_telemetry_reads_back_as_written_and_a_cut_line_is_left_out(tmp_path):
    rows = np.random.default_rng(1).normal(size=(50, 3))
    out = TelemetryAppender(tmp_path / "telemetry.csv", ["t_s", "a", "b"])
    out.append(rows[:20])
    out.append(rows[20:])
    out.close()
    columns, back = read_telemetry(tmp_path / "telemetry.csv")
    assert columns == ["t_s", "a", "b"]
    np.testing.assert_allclose(back, rows, rtol=1e-11)  # %.12g
    with open(tmp_path / "telemetry.csv", "a") as f:
        f.write("1.5,2")  # a kill in the middle of a line
    assert len(read_telemetry(tmp_path / "telemetry.csv")[1]) == 50


def test_the_telemetry_read_every_kth_row_and_its_span(tmp_path):
    """What a kept run's bag and an overlay read: every k-th row from the first among the
    first n, and the time step and span, without the cut last line."""
    rows = np.column_stack([0.002 * np.arange(101), np.arange(101.0) ** 2])
    out = TelemetryAppender(tmp_path / "telemetry.csv", ["t_s", "a"])
    out.append(rows)
    out.close()
    with open(tmp_path / "telemetry.csv", "a") as f:
        f.write("0.204,1")  # cut short by a kill
    columns, n, dt_s, span_s = telemetry_span(tmp_path / "telemetry.csv")
    assert (columns, n) == (["t_s", "a"], 101)
    assert dt_s == pytest.approx(0.002) and span_s == pytest.approx(0.2)
    columns, kept = read_telemetry_every(tmp_path / "telemetry.csv", 7)
    np.testing.assert_allclose(kept, rows[::7], rtol=1e-11)
    kept = read_telemetry_every(tmp_path / "telemetry.csv", 3, max_rows=10)[1]
    np.testing.assert_allclose(kept, rows[:10:3], rtol=1e-11)


def test_the_runs_list_says_which_runs_have_a_replay(tmp_path):
    store = RunStore(tmp_path)
    with_replay, without = _new(store, 1), _new(store, 2)
    (tmp_path / with_replay / "replay.html").write_text("<html></html>")
    listed = {r["id"]: r["replay"] for r in store.runs()}
    assert listed == {with_replay: True, without: False}
    assert "replay.html" in store.run(with_replay)["files"]


def test_a_run_left_running_by_a_server_that_is_gone_is_found_interrupted(tmp_path):
    store = RunStore(tmp_path)
    mine, theirs = _new(store, 1), _new(store, 2)
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    store.update(theirs, server_pid=int(gone.stdout))  # a process that has exited
    assert store.recover() == [theirs]
    assert store.run(theirs)["status"] == "interrupted"
    assert "stopped before the run ended" in store.run(theirs)["reason"]
    assert store.run(mine)["status"] == "running"  # this process records it still
    finished = store.finish(mine, {"duration_s": 1.5, "satellites": []}, "finished", "done")
    assert finished["status"] == "finished" and finished["duration_s"] == 1.5
    assert json.loads((tmp_path / mine / "metrics.json").read_text())["duration_s"] == 1.5
