"""Suite-wide settings.

- One forecast cache (app/runs/forecast_cache.py) for the whole session, new for each: a
  forecast is computed once per setting within the suite, never read from a cache an
  earlier session (or the user's own runs) left.
- The tests that run in real time or measure the machine (a live server, the browser, Ray,
  the benchmarks) are marked ``serial``: ``scripts/test`` runs them alone, one at a time,
  after the others have run two at a time (pytest-xdist, one file per worker).
"""

from __future__ import annotations

import os
import shutil
import tempfile

import pytest

SERIAL_FILES = ("test_manual.py", "test_sweep_ray.py", "test_benchmarks.py")
"""Besides every tests/test_backend_*.py."""

_CACHE: list[str] = []


def pytest_configure(config):
    config.addinivalue_line("markers", "serial: runs alone (real time, a live server, the "
                                       "browser, Ray or a benchmark)")
    if os.environ.get("PYTEST_XDIST_WORKER") and os.environ.get("ORBIT_EMULATOR_CACHE"):
        return  # a worker: its controller's cache
    _CACHE.append(tempfile.mkdtemp(prefix="orbit-emulator-cache-"))
    os.environ["ORBIT_EMULATOR_CACHE"] = _CACHE[0]  # (the CLI and servers it starts too)


def pytest_unconfigure(config):
    if _CACHE:
        shutil.rmtree(_CACHE.pop(), ignore_errors=True)


@pytest.hookimpl(tryfirst=True)  # (before -m selects by it)
def pytest_collection_modifyitems(config, items):
    for item in items:
        name = item.path.name
        if name.startswith("test_backend_") or name in SERIAL_FILES:
            item.add_marker(pytest.mark.serial)
