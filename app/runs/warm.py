"""Compile the loop's numba kernels into their on-disk cache now, once, rather than on a first
run or a first `serve` (``python -m app.runs.warm``; scripts/install and the container's
build run it).

The kernels (app/sim, ``@njit(cache=True)``) compile on their first call and numba keeps
the machine code in its cache (app/runs/kernel_cache.py: where, and the stamp of what it
was compiled from). A cache whose stamp is not this tree's is deleted first
(:func:`~app.runs.kernel_cache.clear_stale`). Warming steps every shipped scenario a few
cycles, ideal and hil (fixed arms and rails; start-up, calibration, the cycle, the
uncertainty's state copy), so that each kernel is compiled with the argument types the
loop gives it; matplotlib's font cache is built too (a first run's plots would), and the
shipped collision's pre-flight reference and fidelity forecast are computed and kept
(app/runs/forecast_cache.py; unless kept already), which a first run would otherwise
spend ten seconds or more on.

When the stamp matches and every kernel module still has its index files
(:func:`~app.runs.kernel_cache.is_warm`), nothing is done and numba is not even imported
(a tenth of a second: scripts/install stays fast when nothing changed). The forecast is
computed with the kernels (a fresh install, new kernels), not after every change of the
code that would call for a new one (a developer's `scripts/serve` after an edit would
wait for it): a first run then computes it, as before.
"""

from __future__ import annotations

import argparse
import sys
import time

from app.runs.kernel_cache import STAMP_NAME, cache_folder, clear_stale, is_warm, write_stamp

WARM_CYCLES = 20
"""Cycles stepped per scenario and mode: enough for every branch of the cycle's first
calls (the first cycle, a sensor sample, the recorder)."""
KEPT_SETTINGS = ("collision",)
"""The scenarios whose pre-flight reference and forecast the warm-up computes and keeps, as
shipped: the tutorial's first run and the web app's first scenario."""


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
        write_stamp(folder)
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
