"""A live server for tests and demos: uvicorn + viser on ephemeral loopback ports (the
viewer reached through the app at /viewer/).

    with LiveServer() as live:
        httpx.get(live.url + "/api/health")

Runs the real app (lifespan included) in a background thread of this process; the
emulator loop runs in its own process as always.
"""

from __future__ import annotations

import socket
import tempfile
import threading
import time

import httpx
import uvicorn

from app.backend.server import create_app


def free_port(host: str = "127.0.0.1") -> int:
    with socket.socket() as sock:
        sock.bind((host, 0))
        return sock.getsockname()[1]


class LiveServer:
    def __init__(self, host: str = "127.0.0.1", default_scenario: str | None = None,
                 startup_timeout_s: float = 90.0, token: str | None = None,
                 runs_dir=None, keep_runs: int = 100) -> None:
        self.host = host
        self.port = free_port(host)
        self.token = token
        # the runs it records: in a temporary folder unless one is given, and there
        # without their plots (each run's figures cost seconds of the suite's CPU)
        self._runs_tmp = None if runs_dir is not None else tempfile.TemporaryDirectory(
            prefix="orbit-emulator-runs-")
        self.runs_dir = runs_dir if runs_dir is not None else self._runs_tmp.name
        self.app = create_app(viser_port=0, host=host, default_scenario=default_scenario,
                              token=token, runs_dir=self.runs_dir, keep_runs=keep_runs,
                              run_plots=runs_dir is not None)
        self.url = f"http://{host}:{self.port}"
        self._server = uvicorn.Server(
            uvicorn.Config(self.app, host=host, port=self.port, log_level="warning",
                           lifespan="on")
        )
        self._thread: threading.Thread | None = None
        self.startup_timeout_s = startup_timeout_s
        self.client: httpx.Client | None = None
        self.viser_port: int | None = None

    def __enter__(self) -> LiveServer:
        self._thread = threading.Thread(target=self._server.run, name="uvicorn", daemon=True)
        self._thread.start()
        deadline = time.monotonic() + self.startup_timeout_s
        self.client = httpx.Client(  # with the token, if any, on every request
            base_url=self.url, timeout=60.0,
            headers={"Authorization": f"Bearer {self.token}"} if self.token else None)
        while True:
            if not self._thread.is_alive():
                raise RuntimeError("the server thread exited during start-up")
            try:
                health = self.client.get("/api/health").json()
                break
            except httpx.HTTPError:
                if time.monotonic() > deadline:
                    raise TimeoutError("the server did not start in time") from None
                time.sleep(0.1)
        assert health["viewer"] == "/viewer/"
        self.viser_port = self.app.state.viser_port  # viser's own port: not for clients
        return self

    def __exit__(self, *exc) -> None:
        if self.client is not None:
            self.client.close()
        self._server.should_exit = True
        if self._thread is not None:
            self._thread.join(20.0)
        if self._runs_tmp is not None:
            self._runs_tmp.cleanup()

    # --- helpers -----------------------------------------------------------------------

    def state(self) -> dict:
        return self.client.get("/api/state").json()

    def wait_for_scene(self, timeout_s: float = 30.0) -> None:
        """Until the 3D scene shows the current run (gizmos exist, arms are posed)."""
        deadline = time.monotonic() + timeout_s
        while True:
            gen = self.state()["generation"]
            if self.client.get("/api/health").json()["scene_generation"] == gen:
                return
            if time.monotonic() > deadline:
                raise TimeoutError("the scene did not catch up")
            time.sleep(0.05)

    def wait_for(self, predicate, timeout_s: float = 30.0, poll_s: float = 0.02) -> dict:
        deadline = time.monotonic() + timeout_s
        while True:
            s = self.state()
            if predicate(s):
                return s
            if time.monotonic() > deadline:
                raise TimeoutError(f"condition not met; last state status {s['status']!r}, "
                                   f"t_s {s['t_s']:.3f}")
            time.sleep(poll_s)
