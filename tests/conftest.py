"""The whole suite shares one forecast cache (app/runs/forecast_cache.py), new for each
session: a forecast is computed once per setting within the suite, never read from a
cache an earlier session (or the user's own runs) left."""

from __future__ import annotations

import os
import shutil
import tempfile

_CACHE: list[str] = []


def pytest_configure(config):
    _CACHE.append(tempfile.mkdtemp(prefix="orbit-emulator-cache-"))
    os.environ["ORBIT_EMULATOR_CACHE"] = _CACHE[0]  # (the CLI and servers it starts too)


def pytest_unconfigure(config):
    if _CACHE:
        shutil.rmtree(_CACHE.pop(), ignore_errors=True)
