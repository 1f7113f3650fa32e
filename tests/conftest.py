"""Suite-wide settings.

- One forecast cache (app/runs/forecast_cache.py) for the whole session (for all the
  passes of ``scripts/test``: ``ORBIT_EMULATOR_TEST_CACHE``), new for each: a forecast is
  computed once per setting within the suite, never read from a cache an earlier session
  (or the user's own runs) left.
- Three kinds of test, run by ``scripts/test`` in three passes:
  * the default: headless, at their own pace (CPU-bound): two files at a time, one per
    core (pytest-xdist);
  * ``realtime``: a live server whose loop runs in real time (REST, websocket, runs on
    disk): two files at a time too, each mostly waiting on its loop's clock, never beside
    a CPU-bound test;
  * ``alone``: what measures the machine or draws in a browser (deadline misses, health
    latency, memory, Chromium's software WebGL): one at a time.
"""

from __future__ import annotations

import os
import shutil
import tempfile

import pytest

ALONE_FILES = ("test_backend_browser.py", "test_backend_page.py",
               "test_backend_scene_rails.py", "test_backend_supervision.py",
               "test_backend_downloads.py", "test_backend_replay.py", "test_manual.py")
REALTIME_FILES = ("test_backend_rest.py", "test_backend_runs.py", "test_backend_access.py",
                  "test_backend_gizmo_ws.py", "test_backend_ring.py")
"""Every other file (tests/test_backend_openapi.py's fuzzing computes forecasts, Ray
runs a campaign) is CPU-bound: the default pass."""

_CACHE: list[str] = []


def pytest_configure(config):
    config.addinivalue_line("markers", "realtime: a live server's loop in real time, two "
                                       "files at a time, never beside a CPU-bound test")
    config.addinivalue_line("markers", "alone: measures the machine or draws in a browser: "
                                       "one at a time")
    if os.environ.get("PYTEST_XDIST_WORKER") and os.environ.get("ORBIT_EMULATOR_CACHE"):
        return  # a worker: its controller's cache
    shared = os.environ.get("ORBIT_EMULATOR_TEST_CACHE")  # scripts/test's, for its passes
    if not shared:
        _CACHE.append(tempfile.mkdtemp(prefix="orbit-emulator-cache-"))
    os.environ["ORBIT_EMULATOR_CACHE"] = shared or _CACHE[0]  # (the CLI, servers it starts)


def pytest_unconfigure(config):
    if _CACHE:
        shutil.rmtree(_CACHE.pop(), ignore_errors=True)


@pytest.hookimpl(tryfirst=True)  # (before -m selects by it)
def pytest_collection_modifyitems(config, items):
    for item in items:
        name = item.path.name
        if name in ALONE_FILES:
            item.add_marker(pytest.mark.alone)
        elif name in REALTIME_FILES:
            item.add_marker(pytest.mark.realtime)
