"""Compile the loop's numba kernels into their on-disk cache now, once, rather than on a first
run or a first `serve` (``python -m app.runs.warm``; scripts/install and the container's
build run it).

The kernels (app/sim, ``@njit(cache=True)``) compile on their first call and numba keeps
the machine code in its cache: ``app/sim/__pycache__``, or under ``NUMBA_CACHE_DIR``,
keyed on the CPU and on the source file that defines the kernel, that file alone: a kernel
that calls into another module (the fused command, sensor and tail paths) would be loaded
as compiled against that module's old code once it changed. So a cache whose stamp (below)
is not this tree's is deleted before the warm-up (:func:`clear_stale`), and before any
kernel loads in any process (:func:`forget_stale`, at app's import). Warming steps
every shipped scenario a few cycles, ideal and hil (fixed arms and rails; start-up,
calibration, the cycle, the uncertainty's state copy), so that each kernel is compiled
with the argument types the loop gives it; matplotlib's font cache is built too (a first
run's plots would), and the shipped collision's pre-flight reference and fidelity forecast
are computed and kept (app/runs/forecast_cache.py; unless kept already), which a first run
would otherwise spend ten seconds or more on.

A stamp beside the cache (``orbit-emulator-warm.json``) records what was warmed: the
Python, numba's version, the CPU name numba targets and each kernel source file's SHA-256.
When it matches and every kernel module still has its index files,
nothing is done and numba is not even imported (a tenth of a second: scripts/install
stays fast when nothing changed). The forecast is computed with the kernels (a fresh
install, new kernels), not after every change of the code that would call for a new one
(a developer's `scripts/serve` after an edit would wait for it): a first run then
computes it, as before.
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

SIM_DIR = Path(os.path.abspath(__file__)).parents[1] / "sim"
"""app/sim as numba names it (os.path.abspath, symbolic links kept: its cache locator's
rule, so that the folder below is the one numba writes)."""
STAMP_NAME = "orbit-emulator-warm.json"
WARM_CYCLES = 20
"""Cycles stepped per scenario and mode: enough for every branch of the cycle's first
calls (the first cycle, a sensor sample, the recorder)."""
KEPT_SETTINGS = ("collision",)
"""The scenarios whose pre-flight reference and forecast the warm-up computes and keeps, as
shipped: the tutorial's first run and the web app's first scenario."""


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


def clear_stale(folder: Path | None = None) -> int:
    """Delete app/sim's compiled kernels from the cache unless its stamp is this tree's
    (an older tree's, or none: compiled from other sources, numba would load a kernel
    against the old code of the modules it calls); the number of files deleted."""
    folder = folder or cache_folder()
    try:
        if json.loads((folder / STAMP_NAME).read_text()) == stamp():
            return 0
    except (OSError, ValueError):
        pass
    deleted = 0
    for source in kernel_sources():
        for path in folder.glob(f"{source.stem}.*.nb[ic]"):
            try:
                path.unlink()
                deleted += 1
            except OSError:  # (gone already: another process cleared it)
                pass
    return deleted


def forget_stale(folder: Path | None = None) -> int:
    """Before any kernel loads (app/__init__.py runs it at the package's import): a cache
    whose stamp is not this tree's, or that has compiled files and no stamp, loses app/sim's
    compiled files (:func:`clear_stale`) and is stamped as this tree's, empty, so that no
    process loads a kernel compiled against other sources (an update or an edit run
    without ``scripts/install``); the kernels compile again on first use, or in the next
    warm-up (:func:`is_warm` wants their index files too). The number of files deleted;
    nothing where the stamp matches (a few ms: the sources' hashes) or where the cache
    cannot be written."""
    folder = folder or cache_folder()
    current = stamp()
    try:
        if json.loads((folder / STAMP_NAME).read_text()) == current:
            return 0
    except (OSError, ValueError):
        pass
    try:
        deleted = clear_stale(folder)
        if folder.is_dir():
            (folder / STAMP_NAME).write_text(json.dumps(current, indent=1) + "\n")
    except OSError:  # (a read-only install: numba keeps its kernels elsewhere)
        return 0
    if deleted:
        print(f"orbit-emulator: {deleted} compiled kernel files of other sources deleted "
              f"from {folder}; the kernels compile again on first use (`bash "
              f"scripts/install` compiles them now)", file=sys.stderr)
    return deleted


def forecasts_kept() -> bool:
    """Whether the pre-flight reference and forecast of each of :data:`KEPT_SETTINGS` is
    kept for this code (or nothing is kept: ``ORBIT_EMULATOR_CACHE=off``)."""
    from app.runs.forecast_cache import NOT_KEPT, cache_dir, cached_reference
    from app.scenarios import load_scenario

    if cache_dir() is None:
        return True
    for name in KEPT_SETTINGS:
        config = load_scenario(name)
        if cached_reference(config, config.loop.duration_s) is NOT_KEPT:
            return False
    return True


def keep_forecasts() -> float:
    """Compute and keep the pre-flight reference and forecast of each of
    :data:`KEPT_SETTINGS` (app/runs/forecast_cache.py); the seconds it took."""
    from app.runs.headless import checked_reference, headless_config
    from app.runs.replicate_pool import cores
    from app.scenarios import load_scenario

    t0 = time.perf_counter()
    for name in KEPT_SETTINGS:
        config = load_scenario(name)
        duration_s = config.loop.duration_s
        checked_reference(headless_config(config, duration_s), duration_s,
                          processes=cores())
    return time.perf_counter() - t0


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
    warm_already = is_warm(folder)
    if args.check:
        return 0 if warm_already else 1
    if warm_already and not args.force:
        return 0
    deleted = clear_stale(folder)
    if deleted:
        print(f"warm: {deleted} compiled files of other sources deleted", file=sys.stderr)
    print(f"warm: compiling the loop's numba kernels into {folder} (once; up to a minute)",
          file=sys.stderr, flush=True)
    seconds = warm()
    try:
        folder.mkdir(parents=True, exist_ok=True)
        (folder / STAMP_NAME).write_text(json.dumps(stamp(), indent=1) + "\n")
        print(f"warm: compiled in {seconds:.1f} s", file=sys.stderr)
    except OSError as err:  # (numba then keeps them in its user-wide cache)
        print(f"warm: compiled in {seconds:.1f} s; the stamp {folder / STAMP_NAME} was not "
              f"written ({err.strerror or err}): the next install warms up again",
              file=sys.stderr)
    try:
        if not forecasts_kept():
            print(f"warm: the fidelity forecast of {', '.join(KEPT_SETTINGS)} (seconds)",
                  file=sys.stderr, flush=True)
            print(f"warm: kept in {keep_forecasts():.1f} s", file=sys.stderr)
    except Exception as err:  # noqa: BLE001 - the kernels are warm all the same
        print(f"warm: warning: the fidelity forecast of {', '.join(KEPT_SETTINGS)} was not "
              f"kept ({type(err).__name__}: {err}); a first run computes it",
              file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
