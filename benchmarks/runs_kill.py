"""How much of a web run a SIGKILLed server loses (docs/runs.md).

Each trial starts `orbit-emulator serve` on a free port with a fresh runs directory,
starts a 60 s ideal collision, kills the server with SIGKILL at a random moment between
2 and 5 s of scenario time, and compares the last state it answered with the last row its
telemetry.csv holds. The recorder flushes every 0.25 s: the gap should stay under that.

    PYTHONPATH=. .venv/bin/python benchmarks/runs_kill.py [SEED] [TRIALS]
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx

from app.runs.store import read_telemetry
from tests.live_server import free_port
from tests.test_cli import EXE


def trial(runs: Path, rng: random.Random) -> tuple[float, float]:
    """(the scenario time of the last state seen before the kill, the last row's)."""
    port = free_port()
    proc = subprocess.Popen([EXE, "serve", "--port", str(port), "--runs-dir", str(runs)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    client = httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=60)
    try:
        while True:
            try:
                if client.get("/api/health").status_code == 200:
                    break
            except httpx.HTTPError:
                time.sleep(0.2)
        client.post("/api/scenarios/collision/start",
                    json={"mode": "ideal", "loop": {"duration_s": 60}})
        target = 2.0 + 3.0 * rng.random()
        while (state := client.get("/api/state").json())["t_s"] < target:
            time.sleep(0.05)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    finally:
        client.close()
        if proc.poll() is None:
            proc.kill()
    (run,) = runs.iterdir()
    return state["t_s"], float(read_telemetry(run / "telemetry.csv")[1][-1, 0])


def main() -> None:
    seed = int(sys.argv[1]) if len(sys.argv) > 1 else 1
    trials = int(sys.argv[2]) if len(sys.argv) > 2 else 4
    rng = random.Random(seed)
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(trials):
            seen, last = trial(Path(tmp) / f"t{k}", rng)
            print(f"trial {k}: state seen t={seen:.3f} s, last row on disk t={last:.3f} s, "
                  f"behind {seen - last:.3f} s", flush=True)


if __name__ == "__main__":
    main()
