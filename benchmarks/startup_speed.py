"""Start-up and output benchmark: where the wall time of a whole `orbit-emulator run` goes.

    .venv/bin/python -m benchmarks.startup_speed                         # per-stage breakdown
    .venv/bin/python -m benchmarks.startup_speed --plots-here            # ... plots not apart
    .venv/bin/python -m benchmarks.startup_speed --against /tmp/old      # both trees' wall time

The breakdown runs the command in this process (``app.cli.main``), with timers wrapped
around the functions each stage calls (the run itself unchanged): the imports, the
pre-flight's ideal run, the fidelity forecast (read from its cache or computed),
calibration and lag identification, the loop, the uncertainty replicates, the metrics,
the plots and the other files. What no timer covers is "rest". Run it in a fresh process
each time (the imports are timed once).

``--against TREE`` times the whole command (a fresh ``python -m app.cli run ...`` per
run, the same environment but ``PYTHONPATH``) of this tree and of TREE in turn,
``--rounds`` times. Each tree has its own forecast cache folder (``ORBIT_EMULATOR_CACHE``),
warmed by one run before the rounds, so that both read a kept forecast, as a user's second
run of a setting does; ``--cold-forecast`` empties it before every run instead (a first
run of a setting). The numba kernels' cache is each tree's own (``app/sim/__pycache__``)
and is warm after the warm-up run.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve()
ROOT = HERE.parents[1]


# --- per-stage breakdown (in this process) -----------------------------------------------


def _wrap(owner, name: str, stage, acc: dict, stack: list) -> None:
    """Replace ``owner.name`` with a timed call adding its exclusive time to acc[stage]
    (time spent in another timed stage inside it is that stage's); ``stage``: a name, or a
    function of the call's first argument that gives it."""
    fn = getattr(owner, name)

    def timed(*args, **kwargs):
        t0 = time.perf_counter()
        stack.append(0.0)
        try:
            return fn(*args, **kwargs)
        finally:
            inner = stack.pop()
            spent = time.perf_counter() - t0
            key = stage(args[0]) if callable(stage) else stage
            acc[key] = acc.get(key, 0.0) + spent - inner
            if stack:
                stack[-1] += spent

    setattr(owner, name, timed)


STAGES = ("imports", "pre-flight (ideal run + prediction)", "emulator build, kernels loaded "
          "(ideal)", "loop (ideal)", "forecast", "drift check",
          "emulator build, kernels loaded (hil)", "start posture + move", "lag identification",
          "calibration (rest + run-up)", "loop (hil)", "ideal reference (metrics)",
          "uncertainty replicates", "metrics", "plots", "plots: process started",
          "plots: waiting for the process", "telemetry.csv + metrics.json",
          "rest")


def breakdown(argv: list[str], plots_here: bool = False) -> dict[str, float]:
    """Seconds per stage of ``orbit-emulator run`` with ``argv`` (run here); ``plots_here``:
    the plots drawn in this process even where the tree would draw them apart."""
    t_start = time.perf_counter()
    import tqdm  # noqa: F401 - what `run` imports first

    import app.cli as cli
    import app.runs.headless as headless
    import app.sim.loop as loop
    acc: dict[str, float] = {"imports": time.perf_counter() - t_start}
    stack: list[float] = []
    w = lambda owner, name, stage: _wrap(owner, name, stage, acc, stack)  # noqa: E731
    w(headless, "preflight", "pre-flight (ideal run + prediction)")
    w(headless, "cached_forecast", "forecast")
    w(headless, "check_drift", "drift check")
    by_mode = lambda what: lambda em: f"{what} ({getattr(em, 'mode', '?')})"  # noqa: E731
    w(loop.Emulator, "__init__", by_mode("emulator build, kernels loaded"))
    w(loop.Emulator, "_start_posture", "start posture + move")
    w(loop.Emulator, "prepare", "calibration (rest + run-up)")
    w(loop, "lag_model", "lag identification")
    w(loop.Emulator, "run", by_mode("loop"))
    w(headless, "ideal_collision", "ideal reference (metrics)")
    w(headless, "spread_of_run", "uncertainty replicates")
    w(headless, "compute_metrics", "metrics")
    w(headless, "plot_run", "plots")
    if hasattr(headless, "plot_process"):  # drawn in a process of their own
        w(headless.plot_process, "start", "plots: process started")
        w(headless.plot_process.PlotProcess, "finish", "plots: waiting for the process")
    w(headless, "_write_csv", "telemetry.csv + metrics.json")
    w(headless, "_write_json", "telemetry.csv + metrics.json")
    if plots_here and hasattr(headless, "plot_process"):
        whole = headless.run_scenario
        headless.run_scenario = lambda *a, **k: whole(*a, **{**k, "plots_apart": False})
    status = cli.main(["run", *argv])
    total = time.perf_counter() - t_start
    acc["rest"] = total - sum(acc.values())
    acc["total"] = total
    acc["exit status"] = status
    return acc


def print_breakdown(argv: list[str], plots_here: bool = False) -> None:
    import io
    from contextlib import redirect_stdout

    with redirect_stdout(io.StringIO()):
        acc = breakdown(argv, plots_here)
    total = acc["total"]
    print(f"\n## `orbit-emulator run {' '.join(argv)}`: per stage "
          f"(exit status {acc['exit status']}{', plots here' if plots_here else ''}; "
          f"load {os.getloadavg()[0]:.2f})\n")
    print("| stage | s | share |")
    print("|---|---:|---:|")
    for stage in STAGES:
        if stage in acc:
            print(f"| {stage} | {acc[stage]:.3f} | {acc[stage] / total:.0%} |")
    print(f"| **total (in process)** | **{total:.3f}** | |")


# --- whole command, both trees alternating ------------------------------------------------


def whole_run(tree: Path, argv: list[str], cache: Path, out: Path) -> float:
    """Wall seconds of ``python -m app.cli run ARGV --out OUT`` in ``tree`` with its
    forecast cache in ``cache``."""
    env = dict(os.environ, PYTHONPATH=str(tree), ORBIT_EMULATOR_CACHE=str(cache))
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "app.cli", "run", *argv, "--quiet",
                           "--out", str(out)], cwd=tree, env=env, capture_output=True,
                          text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{tree}: exit {proc.returncode}: {proc.stderr[-2000:]}")
    return wall


def compare(other: Path, argv: list[str], rounds: int, cold_forecast: bool) -> None:
    trees = {"this tree": ROOT, "other": other.resolve()}
    tmp = Path(tempfile.mkdtemp(prefix="startup-speed-"))
    try:
        caches = {name: tmp / f"cache-{i}" for i, name in enumerate(trees)}
        for name, tree in trees.items():  # warm: the kernels, and the kept forecast
            whole_run(tree, argv, caches[name], tmp / f"out-{name}")
        walls: dict[str, list[float]] = {name: [] for name in trees}
        for _ in range(rounds):
            for name, tree in trees.items():
                if cold_forecast:
                    shutil.rmtree(caches[name], ignore_errors=True)
                walls[name].append(whole_run(tree, argv, caches[name],
                                             tmp / f"out-{name}"))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    kind = "empty forecast cache before each run" if cold_forecast else "kept forecast"
    print(f"\n## `orbit-emulator run {' '.join(argv)}`: whole command, {rounds} rounds "
          f"alternating ({kind}; load {os.getloadavg()[0]:.2f})\n")
    print("| round | this tree s | " + f"{other} s | ratio |")
    print("|---:|---:|---:|---:|")
    ratios = []
    for r in range(rounds):
        a, b = walls["this tree"][r], walls["other"][r]
        ratios.append(a / b)
        print(f"| {r + 1} | {a:.2f} | {b:.2f} | {a / b:.2f} |")
    print(f"\nratio median {statistics.median(ratios):.2f} (spread {min(ratios):.2f}–"
          f"{max(ratios):.2f}); medians {statistics.median(walls['this tree']):.2f} s vs "
          f"{statistics.median(walls['other']):.2f} s")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenario", nargs="?", default="collision")
    ap.add_argument("--duration", default=None, help="seconds of scenario time")
    ap.add_argument("--against", type=Path, default=None,
                    help="another checkout: the whole command's wall time of both trees")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--cold-forecast", action="store_true",
                    help="with --against: an empty forecast cache before each run")
    ap.add_argument("--plots-here", action="store_true",
                    help="breakdown: draw the plots in the run's process, not apart")
    args = ap.parse_args(argv)
    run_argv = [args.scenario] + (["--duration", args.duration] if args.duration else [])
    if args.against is not None:
        compare(args.against, run_argv, args.rounds, args.cold_forecast)
        return 0
    out = Path(tempfile.mkdtemp(prefix="startup-speed-out-"))
    try:
        print_breakdown([*run_argv, "--quiet", "--out", str(out)], args.plots_here)
    finally:
        shutil.rmtree(out, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
