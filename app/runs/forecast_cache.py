"""The fidelity forecasts already computed, kept on disk and computed once per setting.

A forecast (:func:`app.runs.uncertainty.forecast`) takes seconds: a noise-free hil twin
to the contact, then hundreds of replicates of the contact window. It depends on the
configuration but not on the run's seed (its draws are the configuration's own), so every
seed of a setting, every run of a campaign and every web run of the same scenario shares
one. A forecast is found again under a key made of

- the configuration with its seed and its telemetry capacity set aside (neither changes
  the forecast; a test checks it for the seed),
- the ideal run's collision figures it starts from,
- a fingerprint of the code (every ``.py`` file of ``app/``): a change of the code is a
  new key, so a forecast is never one an older chain computed.

The folder is ``$ORBIT_EMULATOR_CACHE/forecasts`` (default: ``$XDG_CACHE_HOME`` or
``~/.cache``, then ``orbit-emulator``); ``ORBIT_EMULATOR_CACHE=off`` computes every
forecast anew. A file that cannot be read or written is computed and not kept: the cache
never stops a run.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import tempfile
from pathlib import Path

from app.config import EmulatorConfig

CACHE_ENV = "ORBIT_EMULATOR_CACHE"
IDEAL_KEYS = ("pair", "window_s", "contact_duration_s", "restitution", "peak_force_N")
"""The ideal run's figures a forecast reads."""


def cache_dir() -> Path | None:
    """Where forecasts are kept; None when ``ORBIT_EMULATOR_CACHE=off``."""
    root = os.environ.get(CACHE_ENV, "")
    if root.lower() == "off":
        return None
    if not root:
        root = os.path.join(os.environ.get("XDG_CACHE_HOME")
                            or os.path.join(os.path.expanduser("~"), ".cache"),
                            "orbit-emulator")
    return Path(root) / "forecasts"


@functools.lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """SHA-256 of every ``.py`` file of ``app/`` (its path and its bytes), in path order."""
    app_dir = Path(__file__).resolve().parents[1]
    digest = hashlib.sha256()
    for path in sorted(app_dir.rglob("*.py")):
        digest.update(str(path.relative_to(app_dir)).encode() + b"\0")
        digest.update(path.read_bytes() + b"\0")
    return digest.hexdigest()


def forecast_key(config: EmulatorConfig, ideal: dict) -> str:
    """The key of the forecast of ``config`` from the ideal run ``ideal``."""
    loop = config.loop.model_copy(update={"seed": 0, "telemetry_capacity": 0})
    setting = config.model_copy(update={"loop": loop}).model_dump(mode="json")
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
    try:
        return json.loads(path.read_text())["forecast"]
    except (OSError, ValueError, KeyError, TypeError):
        pass
    result = compute(config, ideal)
    _keep(path, result)
    return result


def _keep(path: Path, result: dict | None) -> None:
    """Write ``result`` to ``path`` whole (a reader sees the old file or the new one)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile("w", dir=path.parent, suffix=".tmp",
                                         delete=False) as tmp:
            json.dump({"forecast": result}, tmp, allow_nan=True)
        os.replace(tmp.name, path)
    except OSError:
        try:
            os.unlink(tmp.name)
        except (OSError, NameError):
            pass
