"""The telemetry rings fit where they live (app/backend/ring.py): `serve` with a 64 MiB
/dev/shm, Docker's default, refuses a start whose ring does not fit with a 422 naming
loop.telemetry_capacity and the space, instead of dying of SIGBUS mid-run."""

from __future__ import annotations

import shutil
import subprocess
import time

import pytest

from benchmarks.download_memory import Serve


def _private_shm_allowed() -> bool:
    if shutil.which("unshare") is None:
        return False
    probe = subprocess.run(["unshare", "-m", "sh", "-c",
                            "mount -t tmpfs -o size=64m tmpfs /dev/shm"],
                           capture_output=True, timeout=10)
    return probe.returncode == 0


needs_private_shm = pytest.mark.skipif(
    not _private_shm_allowed(),
    reason="a private /dev/shm needs a mount namespace (unshare -m) and mount: root, or a "
           "container allowed CAP_SYS_ADMIN")

SMALL_SHM = ("unshare", "-m", "sh", "-c",
             'mount -t tmpfs -o size=64m tmpfs /dev/shm && exec "$0" "$@"')
"""`serve` as in a container run with Docker's default 64 MiB /dev/shm."""


@needs_private_shm
def test_a_start_whose_ring_does_not_fit_in_dev_shm_is_refused_with_a_422():
    with Serve(argv_prefix=SMALL_SHM) as serve:
        health = serve.client.get("/api/health").json()
        assert health["status"] == "ok"
        # a collision with both arms: 140000 rows of 113 values, 120.7 MiB
        r = serve.client.post("/api/scenarios/collision/start", json={})
        assert r.status_code == 422, r.text
        detail = r.json()["detail"]
        assert detail.startswith(
            "loop.telemetry_capacity: 140000 rows of 113 values need 120.7 MiB of shared "
            "memory in /dev/shm, which has ")
        assert detail.endswith("free of 64.0 MiB: ask for at most " + detail.split(
            "ask for at most ")[1].split()[0] + " rows, or give /dev/shm more room (docker "
            "run --shm-size=1g)")
        fits = int(detail.split("ask for at most ")[1].split()[0])
        assert 70_000 < fits < (64 << 20) // 904  # 64 MiB less the snapshot block, 904 B a row
        state = serve.client.get("/api/state").json()
        assert state["status"] == "idle" and state["generation"] == 0  # nothing changed
        # the rows it says fit are taken
        body = {"mode": "hil", "loop": {"telemetry_capacity": fits}}
        r = serve.client.post("/api/scenarios/collision/start", json=body)
        assert r.status_code == 200 and r.json()["status"] == "running", r.text
        serve.client.post("/api/stop")
        # in this /dev/shm a run fills its ring, wraps and goes on (5 kHz, 10,000 rows)
        body = {"mode": "ideal", "loop": {"rate_hz": 5000.0, "duration_s": 1e4,
                                          "telemetry_capacity": 10_000}}
        r = serve.client.post("/api/scenarios/collision/start", json=body)
        assert r.status_code == 200, r.text
        time.sleep(3.0)
        state = serve.client.get("/api/state").json()
        assert state["status"] == "running" and state["loop"]["cycles"] > 10_000  # wrapped
        assert serve.client.get("/api/health").json()["status"] in ("ok", "degraded")
        serve.client.post("/api/stop")
