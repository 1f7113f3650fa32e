"""Compile the loop's numba kernels into their on-disk cache now, once, rather than on a first
run or a first `serve` (``python -m app.runs.warm``; scripts/install and the container's
build run it).

The kernels (app/sim, ``@njit(cache=True)``) compile on their first call and numba keeps
the machine code in its cache: ``app/sim/__pycache__``, or under ``NUMBA_CACHE_DIR``,
keyed on each source file's contents and on the CPU. Warming steps every shipped
scenario a few cycles, ideal and hil (fixed arms and rails; start-up, calibration, the
cycle, the uncertainty's state copy), so that each kernel is compiled with the argument
types the loop gives it; matplotlib's font cache is built too (a first run's plots would).

A stamp beside the cache (``orbit-emulator-warm.json``) records what was warmed: the
Python, numba's version, the CPU name numba targets and each kernel source file's SHA-256
(numba's own key). When it matches and every kernel module still has its index files,
nothing is done and numba is not even imported (a tenth of a second: scripts/install
stays fast when nothing changed).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import time
from importlib import metadata
from pathlib import Path

SIM_DIR = Path(__file__).resolve().parents[1] / "sim"
STAMP_NAME = "orbit-emulator-warm.json"
WARM_CYCLES = 20
"""Cycles stepped per scenario and mode: enough for every branch of the cycle's first
calls (the first cycle, a sensor sample, the recorder)."""


def kernel_sources() -> list[Path]:
    """The app/sim files that define numba kernels."""
    return sorted(p for p in SIM_DIR.glob("*.py") if "@njit" in p.read_text())


def cache_folder() -> Path:
    """Where numba keeps app/sim's compiled kernels (its own rule: NUMBA_CACHE_DIR holds
    a tree named after the sources' folder; else their ``__pycache__``)."""
    root = os.environ.get("NUMBA_CACHE_DIR")
    if not root:
        return SIM_DIR / "__pycache__"
    # numba's UserProvidedCacheLocator: the folder's name and the SHA-1 of its path
    return Path(root) / f"{SIM_DIR.name}_{hashlib.sha1(str(SIM_DIR).encode()).hexdigest()}"


def stamp() -> dict:
    """What a warm cache was compiled from (module doc)."""
    return {"python": sys.version, "numba": metadata.version("numba"),
            "cpu": os.environ.get("NUMBA_CPU_NAME", ""),
            "sources": {p.name: hashlib.sha256(p.read_bytes()).hexdigest()
                        for p in kernel_sources()}}


def is_warm(folder: Path | None = None) -> bool:
    """Whether the stamp in the cache matches this tree and every kernel module has its
    index files there."""
    folder = folder or cache_folder()
    try:
        kept = json.loads((folder / STAMP_NAME).read_text())
    except (OSError, ValueError):
        return False
    if kept != stamp():
        return False
    return all(any(folder.glob(f"{p.stem}.*.nbi")) for p in kernel_sources())


def warm() -> float:
    """Step every shipped scenario ideal and hil (module doc); the seconds it took."""
    import numpy as np

    from app.runs.headless import headless_config
    from app.scenarios import load_scenario, scenario_names
    from app.sim.loop import Emulator

    t0 = time.perf_counter()
    for name in scenario_names():
        config = headless_config(load_scenario(name), WARM_CYCLES / 50.0)
        for mode in ("ideal", "hil") if config.robots else ("ideal",):
            em = Emulator(config, mode=mode)
            em.prepare(settle_s=0.02)
            for _ in range(WARM_CYCLES):
                if em.status != "running":
                    break
                em.step()
            em.copy_state().step()  # the uncertainty's replicates
            em.record_final()
            np.asarray(em.telemetry.rows())
    import matplotlib.font_manager  # noqa: F401 - builds matplotlib's font cache, once
    return time.perf_counter() - t0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m app.runs.warm", description=__doc__.split(
        "\n\n")[0])
    ap.add_argument("--force", action="store_true", help="warm even if the stamp matches")
    ap.add_argument("--check", action="store_true",
                    help="only say whether the cache is warm (exit status 0) or not (1)")
    args = ap.parse_args(argv)
    folder = cache_folder()
    if args.check:
        return 0 if is_warm(folder) else 1
    if not args.force and is_warm(folder):
        return 0
    print(f"warm: compiling the loop's numba kernels into {folder} (once; up to a minute)",
          file=sys.stderr, flush=True)
    seconds = warm()
    folder.mkdir(parents=True, exist_ok=True)
    (folder / STAMP_NAME).write_text(json.dumps(stamp(), indent=1) + "\n")
    print(f"warm: done in {seconds:.1f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
