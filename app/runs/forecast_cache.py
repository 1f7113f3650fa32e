"""The fidelity forecasts already computed, kept on disk and computed once per setting.

A forecast (:func:`app.runs.uncertainty.forecast`) takes seconds: a noise-free hil twin
to the contact, then hundreds of replicates of the contact window. It depends on the
configuration but not on the run's seed (its draws are the configuration's own), so every
seed of a setting, every run of a campaign and every web run of the same scenario shares
one. A forecast is found again under a key made of

- the configuration with its seed and its telemetry capacity set aside (neither changes
  the forecast; a test checks it for the seed),
- the ideal run's collision figures it starts from,
- a fingerprint of the code (every ``.py`` file of ``app/``, and the Python, NumPy and
  numba versions): a change of the code is a new key, so a forecast is never one an older
  chain computed.

The folder is ``$ORBIT_EMULATOR_CACHE/forecasts`` (default: ``$XDG_CACHE_HOME`` or
``~/.cache``, then ``orbit-emulator``); ``ORBIT_EMULATOR_CACHE=off`` computes every
forecast anew. A file that cannot be read, or is not a forecast's (not a regular file, too
large, not JSON, not of a forecast's shape), is computed anew and written over; one that
cannot be written is not kept: the cache never stops a run. Only a file and a folder
this user owns and no one else may write are read (a kept pre-flight reference lets a run
skip the pre-flight); within them a forecast of the right shape is trusted as the
installation is.

Beside the forecasts (``.../references``), the pre-flight's outcome is kept the same way
(:func:`cached_reference`): the ideal run's collision reference with its forecast, for a
setting whose pre-flight passed, under a key of the configuration less its seed and
telemetry capacity, the run's duration and the code's fingerprint. The pre-flight's ideal
run has no sensor, so no seed (a test checks it); a refused setting is not kept (it is
checked anew, and refused with its message, every time).
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import os
import stat
import sys
import tempfile
from pathlib import Path

from app.config import EmulatorConfig

CACHE_ENV = "ORBIT_EMULATOR_CACHE"
MAX_FILE_BYTES = 1 << 20
"""A kept forecast is a few hundred bytes; a larger file is not one."""
NOT_KEPT = object()
"""What a look-up returns when nothing usable is kept for its key."""
IDEAL_KEYS = ("pair", "window_s", "contact_duration_s", "restitution", "peak_force_N")
"""The ideal run's figures a forecast reads."""


def cache_dir(kind: str = "forecasts") -> Path | None:
    """Where forecasts (``kind`` "references": pre-flight references) are kept; None when
    ``ORBIT_EMULATOR_CACHE=off``."""
    root = os.environ.get(CACHE_ENV, "")
    if root.lower() == "off":
        return None
    if not root:
        root = os.path.join(os.environ.get("XDG_CACHE_HOME")
                            or os.path.join(os.path.expanduser("~"), ".cache"),
                            "orbit-emulator")
    return Path(root) / kind


@functools.lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """SHA-256 of the Python, NumPy and numba versions and every ``.py`` file of ``app/``
    (its path and its bytes), in path order."""
    import numba
    import numpy

    app_dir = Path(__file__).resolve().parents[1]
    digest = hashlib.sha256()
    digest.update(f"{sys.version}\0{numpy.__version__}\0{numba.__version__}\0".encode())
    for path in sorted(app_dir.rglob("*.py")):
        digest.update(str(path.relative_to(app_dir)).encode() + b"\0")
        digest.update(path.read_bytes() + b"\0")
    return digest.hexdigest()


def _setting(config: EmulatorConfig) -> dict:
    """The configuration as a key sees it: its seed and telemetry capacity set aside."""
    loop = config.loop.model_copy(update={"seed": 0, "telemetry_capacity": 0})
    return config.model_copy(update={"loop": loop}).model_dump(mode="json")


def forecast_key(config: EmulatorConfig, ideal: dict) -> str:
    """The key of the forecast of ``config`` from the ideal run ``ideal``."""
    setting = _setting(config)
    figures = {k: ideal.get(k) for k in IDEAL_KEYS}
    text = json.dumps({"config": setting, "ideal": figures, "code": code_fingerprint()},
                      sort_keys=True, allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()


def cached_forecast(config: EmulatorConfig, ideal: dict | None, compute) -> dict | None:
    """``compute(config, ideal)`` (the forecast), or the one kept for the same key."""
    folder = cache_dir()
    if folder is None or not ideal:
        return compute(config, ideal)
    path = folder / f"{forecast_key(config, ideal)}.json"
    kept = _read(path)
    if kept is not NOT_KEPT:
        return kept
    result = compute(config, ideal)
    _keep(path, result)
    return result


def reference_key(config: EmulatorConfig, duration_s: float) -> str:
    """The key of the pre-flight reference of ``config`` over ``duration_s``."""
    text = json.dumps({"config": _setting(config), "duration_s": float(duration_s),
                       "code": code_fingerprint()}, sort_keys=True, allow_nan=True)
    return hashlib.sha256(text.encode()).hexdigest()


def cached_reference(config: EmulatorConfig, duration_s: float):
    """The pre-flight reference kept for this setting and duration (a dict, or None: a run
    that needs none), or :data:`NOT_KEPT`. Kept by :func:`keep_reference` only once its
    pre-flight passed; like a forecast, it does not depend on the seed (a test checks it),
    and the same hardening applies to its file."""
    folder = cache_dir("references")
    if folder is None:
        return NOT_KEPT
    return _read(folder / f"{reference_key(config, duration_s)}.json", "reference",
                 _is_reference)


def keep_reference(config: EmulatorConfig, duration_s: float, reference: dict | None) -> None:
    """Keep ``reference``, the pre-flight's of a setting that passed it
    (:func:`cached_reference`)."""
    folder = cache_dir("references")
    if folder is not None:
        _keep(folder / f"{reference_key(config, duration_s)}.json", reference, "reference")


def _is_reference(kept) -> bool:
    """Whether ``kept`` has the shape of a pre-flight reference (an ideal run's collision
    metrics, app/runs/metrics.py, with its forecast) or is None (none needed)."""
    if kept is None or kept == {}:  # none needed; no contact in the ideal run
        return True
    if not isinstance(kept, dict) or not _plain(kept, 0):
        return False
    pair, window = kept.get("pair"), kept.get("window_s")
    return (isinstance(pair, list) and len(pair) == 2 and all(isinstance(p, str) for p in pair)
            and isinstance(window, list) and len(window) == 2
            and all(_number(t, None) for t in window)
            and all(kept.get(k) is None or _number(kept[k], 0.0)
                    for k in ("restitution", "peak_force_N", "contact_duration_s"))
            and isinstance(kept.get("warnings"), list)
            and (kept.get("forecast") is None or _is_forecast(kept["forecast"])))


def _plain(value, depth: int) -> bool:
    """JSON's own values, numbers finite, nested at most four deep."""
    if isinstance(value, dict):
        return depth < 4 and all(isinstance(k, str) and _plain(v, depth + 1)
                                 for k, v in value.items())
    if isinstance(value, list):
        return depth < 4 and all(_plain(v, depth + 1) for v in value)
    return value is None or isinstance(value, (str, bool)) or _number(value, None)


def _read(path: Path, field: str = "forecast", valid=None):
    """The forecast kept at ``path`` (``field``, ``valid``: another kind of file), or
    :data:`NOT_KEPT` when there is none or it is not one this code writes (not a regular
    file, over :data:`MAX_FILE_BYTES`, not JSON, or not of its shape): then it is
    computed anew and written over."""
    try:
        if not _own(os.stat(path.parent)):
            return NOT_KEPT
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOFOLLOW)
        with open(fd, "rb") as f:  # a FIFO or link swapped in is never read
            info = os.fstat(f.fileno())
            if (not stat.S_ISREG(info.st_mode) or info.st_size > MAX_FILE_BYTES
                    or not _own(info)):
                return NOT_KEPT
            kept = json.loads(f.read(MAX_FILE_BYTES + 1))[field]
    except (OSError, ValueError, KeyError, TypeError, RecursionError):
        return NOT_KEPT
    return kept if (valid or _is_forecast)(kept) else NOT_KEPT


def _own(info: os.stat_result) -> bool:
    """A file or folder only this user could have written: this user's, and not writable
    by its group or by others. A kept pre-flight reference lets a run skip the pre-flight's
    checks, so a file another user could have placed is never read."""
    return info.st_uid == os.getuid() and not info.st_mode & (stat.S_IWGRP | stat.S_IWOTH)


def _is_forecast(kept) -> bool:
    """Whether ``kept`` has a forecast's shape (app/runs/uncertainty.py :func:`forecast`):
    a dict whose numbers are finite and whose spreads are not negative, its velocity
    spread per satellite three of them."""
    if not isinstance(kept, dict) or "restitution_sd" not in kept:
        return False
    for key, value in kept.items():
        if key == "velocity_sd_mps":
            if not isinstance(value, dict) or not all(
                    isinstance(v, list) and len(v) == 3 and all(_number(x, 0.0) for x in v)
                    for v in value.values()):
                return False
        elif key == "note":
            if not isinstance(value, str):
                return False
        elif value is not None and not _number(value, 0.0 if key.endswith(("_sd", "_se"))
                                               else None):
            return False
    return True


def _number(x, least: float | None) -> bool:
    return (isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
            and (least is None or x >= least))


def _keep(path: Path, result: dict | None, field: str = "forecast") -> None:
    """Write ``result`` to ``path`` whole (a reader sees the old file or the new one)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile("w", dir=path.parent, suffix=".tmp",
                                         delete=False) as tmp:
            json.dump({field: result}, tmp, allow_nan=True)
        os.replace(tmp.name, path)
    except (OSError, TypeError, ValueError):  # not writable, or not JSON: not kept
        try:
            os.unlink(tmp.name)
        except (OSError, NameError):
            pass
