"""The web process's memory while it serves a big run's downloads (docs/reliability-io.md).

Starts `orbit-emulator serve` on a free loopback port, runs an ideal two-satellite run at
5 kHz with a large telemetry ring for SECONDS, stops it, then downloads its CSV, zip and
bag while sampling the serve process's resident memory (VmRSS, every 10 ms) and timing
/api/health meanwhile; then resets and reads the memory again.

    .venv/bin/python -m benchmarks.download_memory [--seconds 20] [--capacity 200000]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx

EXE = shutil.which("orbit-emulator") or f"{sys.prefix}/bin/orbit-emulator"


def rss_mib(pid: int, field: str = "VmRSS") -> float:
    """A memory field of /proc/PID/status in MiB (VmRSS, VmHWM, RssAnon, RssShmem)."""
    text = Path(f"/proc/{pid}/status").read_text()
    return int(re.search(rf"^{field}:\s+(\d+) kB", text, re.M).group(1)) / 1024


class Serve:
    """`orbit-emulator serve --port 0` in a process of its own (a new session)."""

    def __init__(self, *, argv_prefix: tuple[str, ...] = (), env: dict | None = None) -> None:
        self.proc = subprocess.Popen(
            [*argv_prefix, EXE, "serve", "--port", "0"], stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT, text=True, start_new_session=True,
            env={**os.environ, **(env or {})})
        self.lines: list[str] = []
        self.url = None
        deadline = time.monotonic() + 120
        for line in self.proc.stdout:
            self.lines.append(line)
            found = re.search(r"web app\s+(http://[\d.]+:\d+)/", line)
            if found:
                self.url = found.group(1)
                break
            if time.monotonic() > deadline:
                break
        if self.url is None:
            self.close()
            raise RuntimeError("serve did not start:\n" + "".join(self.lines))
        threading.Thread(target=self._drain, daemon=True).start()
        self.client = httpx.Client(base_url=self.url, timeout=120.0)

    def _drain(self) -> None:
        for line in self.proc.stdout:
            self.lines.append(line)

    @property
    def pid(self) -> int:
        """The web process (the serve command itself; the loop is its child)."""
        return self.proc.pid

    def close(self) -> None:
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGTERM)
            try:
                self.proc.wait(20)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(5)

    def __enter__(self) -> Serve:
        return self

    def __exit__(self, *exc) -> None:
        self.client.close()
        self.close()


BIG_RUN = {"mode": "ideal", "loop": {"rate_hz": 5000.0}}
"""An ideal collision at 5 kHz: rows ten times as fast as the 500 Hz loop writes them."""


def fill(serve: Serve, seconds: float, capacity: int) -> dict:
    """Run BIG_RUN with this ring for ``seconds`` of wall time, then stop; its state."""
    body = {**BIG_RUN, "loop": {**BIG_RUN["loop"], "telemetry_capacity": capacity,
                                "duration_s": 1e5}}
    r = serve.client.post("/api/scenarios/collision/start", json=body)
    r.raise_for_status()
    time.sleep(seconds)
    return serve.client.post("/api/stop").json()


def _sample(serve: Serve, done: threading.Event, peak: list, slowest: list) -> None:
    """VmRSS and the time /api/health takes, every 10 ms until done."""
    with httpx.Client(base_url=serve.url, timeout=30.0) as health:
        while not done.is_set():
            peak.append(rss_mib(serve.pid))
            t0 = time.perf_counter()
            health.get("/api/health")
            slowest.append(time.perf_counter() - t0)
            time.sleep(0.01)


def _download(serve: Serve, path: str) -> dict:
    """One download, streamed and counted, with the memory and health sampled meanwhile."""
    peak, slowest, done = [rss_mib(serve.pid)], [0.0], threading.Event()
    sampler = threading.Thread(target=_sample, args=(serve, done, peak, slowest))
    sampler.start()
    t0 = time.perf_counter()
    size = 0
    try:
        with serve.client.stream("GET", path) as r:
            r.raise_for_status()
            for chunk in r.iter_bytes():
                size += len(chunk)
    finally:
        done.set()
        sampler.join()
    return {"bytes": size, "wall_s": round(time.perf_counter() - t0, 2),
            "peak_MiB": round(max(peak), 1), "after_MiB": round(rss_mib(serve.pid), 1),
            "health_max_s": round(max(slowest), 3)}


def measure_downloads(serve: Serve) -> dict:
    """Each download's size, the peak VmRSS over it, the slowest /api/health meanwhile."""
    out = {"idle_MiB": rss_mib(serve.pid)}
    for path in ("/api/telemetry", "/api/run.zip", "/api/bag?rate_hz=1000"):
        out[path] = _download(serve, path)
    out["after_MiB"] = rss_mib(serve.pid)
    serve.client.post("/api/reset").raise_for_status()
    time.sleep(1.0)
    out["after_reset_MiB"] = rss_mib(serve.pid)
    out["VmHWM_MiB"] = rss_mib(serve.pid, "VmHWM")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--capacity", type=int, default=200_000)
    args = parser.parse_args()
    with Serve() as serve:
        state = fill(serve, args.seconds, args.capacity)
        result = {"cycles": state["loop"]["cycles"], "capacity": args.capacity,
                  **measure_downloads(serve)}
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
