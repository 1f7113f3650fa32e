"""Downloads in bounded memory (app/backend/downloads.py, app/backend/ring.py): the
`serve` process's resident memory while it serves a big run's CSV, zip and bag, and after
(measured from /proc/PID/status, sampled every 10 ms), and /api/health meanwhile."""

from __future__ import annotations

import io
import os
import subprocess
import sys
import time
import zipfile
from pathlib import Path

from benchmarks.download_memory import Serve, fill, measure_downloads

MiB_ABOVE_IDLE_PEAK = 200
MiB_ABOVE_IDLE_AFTER = 50


def test_downloads_of_a_big_run_stream_in_bounded_memory():
    """An ideal collision at 5 kHz for 12 s (about 55,000 rows, a 25 MB CSV): each
    download keeps the web process under idle + 200 MiB, and it comes back within 50 MiB
    of idle once done (the CSV is read and formatted 2,048 rows at a time; the zip and the
    bag are built by a worker process of their own); health answers within 1 s meanwhile."""
    with Serve() as serve:
        state = fill(serve, 12.0, 200_000)
        rows = serve.client.get("/api/metrics").json()["cycles"]
        assert rows > 20_000, state["loop"]  # a big run even on a loaded machine
        csv = serve.client.get("/api/telemetry").content
        lines = csv.count(b"\n")
        assert lines - 1 >= rows  # every row (a stopped run: the ring's whole content)
        with zipfile.ZipFile(io.BytesIO(serve.client.get("/api/run.zip").content)) as zf:
            assert zf.read("telemetry.csv") == csv  # the zip's CSV is the same bytes
        del csv
        figures = measure_downloads(serve)
    idle = figures["idle_MiB"]
    for path in ("/api/telemetry", "/api/run.zip", "/api/bag?rate_hz=1000"):
        f = figures[path]
        assert f["bytes"] > 1_000_000, (path, f)
        assert f["peak_MiB"] - idle < MiB_ABOVE_IDLE_PEAK, (path, figures)
        assert f["health_max_s"] < 1.0, (path, figures)
    assert figures["after_reset_MiB"] - idle < MiB_ABOVE_IDLE_AFTER, figures


def test_a_download_worker_that_dies_is_an_error_and_the_next_download_gets_a_new_one():
    import os

    import pytest

    from app.backend.downloads import DownloadWorker

    worker = DownloadWorker()
    try:
        with pytest.raises(RuntimeError, match="the download's worker process died before "
                                               "it finished; try again"):
            worker.run(os._exit, 9)  # as a worker killed for its memory would
        assert worker.run(len, [1, 2, 3]) == 3
    finally:
        worker.shutdown()


def _children(pid: int) -> list[int]:
    out = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = open(f"/proc/{entry}/stat").read()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
                out.append(int(entry))
    return out


def _alive(pid: int) -> bool:
    try:
        return open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def test_the_download_worker_exits_with_the_web_process():
    """kill -9 of the process that owns the download worker (the web process) once left
    the worker behind, and through it the run's shared memory: it now exits within a
    few seconds, and so does what it kept alive."""
    code = ("import os, time\n"
            "from app.backend.downloads import DownloadWorker\n"
            "w = DownloadWorker()\n"
            "print(w.run(os.getpid), flush=True)\n"
            "time.sleep(60)\n")
    parent = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True,
                              cwd=Path(__file__).resolve().parents[1])
    try:
        assert int(parent.stdout.readline()) != parent.pid  # the task ran in a worker
        time.sleep(1.0)  # (the pool starts the next worker)
        children = _children(parent.pid)
        assert children, "no process of the pool to watch"
    finally:
        parent.kill()
        parent.wait()
    deadline = time.monotonic() + 10.0
    while any(_alive(c) for c in children) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not [c for c in children if _alive(c)], children
