"""A 64-run collision sweep on Ray against the same runs one after the other in one process.

    .venv/bin/python -m benchmarks.sweep_scaling            # 64 runs (16 settings x 4 seeds)
    .venv/bin/python -m benchmarks.sweep_scaling --quick    # 8 runs (2 settings x 4 seeds)

The sweep: ``orbit-emulator sweep`` of the spec below as a command (its whole wall time:
Python start, Ray start on this machine with one worker per core, the runs, Ray's
shutdown; ``--keep metrics``). The baseline: the same runs (the same resolved
configurations, from the same plan) in this one process, each as ``orbit-emulator run``
computes it: ``run_scenario``, every hil collision with its own ideal reference run, no
files written (imports and numba's cache loading before the clock starts). The sweep
runs the ideal reference once per setting (16), the baseline once per run (64): that is
part of what the sweep gains, by design.

Checked: every row's kept metrics.json equals the baseline's metrics of that run except
the wall-clock figures (realtime_factor, cycle_time_us). Printed: the uptime before, both
times, their ratio against the target (<= 0.6), and each worker's peak resident memory;
and, to tell the parallel speed-up from the ideal runs saved, an estimate of a sequential
baseline that shares the ideal as the sweep does (the ideal runs timed apart, once per
setting, subtracted for the runs that repeat them).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from app.campaign.sweep import TIMING_METRICS, load_spec, plan_sweep, read_results

SPEC = """
scenario = "collision"
mode = "hil"
duration_s = 3.5          # the satellites touch at 3.1 s
seeds = [0, 1, 2, 3]
metrics = ["collision.restitution", "collision.restitution_error",
           "satellites.0.position_error_max_m", "realtime_factor"]

[grid]
"materials.sponge.stiffness_Npm" = {stiffness}
"servo.delay_cycles" = {delays}
"""
TARGET_RATIO = 0.6


def uptime() -> str:
    return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()


def sweep_command(spec: Path, out: Path) -> float:
    """The sweep as a command; its wall time (s)."""
    exe = Path(sys.prefix) / "bin" / "orbit-emulator"
    t0 = time.perf_counter()
    proc = subprocess.run([str(exe), "sweep", str(spec), "--out", str(out), "--quiet"],
                          capture_output=True, text=True)
    wall_s = time.perf_counter() - t0
    if proc.returncode != 0:
        sys.exit(f"the sweep failed:\n{proc.stderr[-3000:]}")
    print(proc.stdout.strip())
    return wall_s


def sequential(plan) -> tuple[float, dict[str, dict]]:
    """The same runs one after the other here: (wall time, run_id → metrics)."""
    from app.runs.headless import run_scenario

    runs = list(plan.runs())
    run_scenario(runs[0].config, duration_s=0.1)  # imports and kernels before the clock
    out = {}
    t0 = time.perf_counter()
    for run in runs:
        result = run_scenario(run.config, mode=run.config.loop.mode,
                              duration_s=run.config.loop.duration_s)
        out[run.run_id] = result.metrics
    return time.perf_counter() - t0, out


def ideal_times(plan) -> tuple[float, int]:
    """The ideal reference runs alone, once per setting, timed apart: (their total time,
    how many runs share them), to estimate a sequential baseline that shares them too."""
    from app.runs.headless import headless_config, ideal_collision

    first = {}
    for run in plan.runs():
        first.setdefault(run.ideal_id, run.config)
    t0 = time.perf_counter()
    for config in first.values():
        ideal_collision(headless_config(config, config.loop.duration_s),
                        config.loop.duration_s)
    return time.perf_counter() - t0, plan.count // len(first)


def deterministic(metrics: dict) -> dict:
    return {k: v for k, v in metrics.items() if k not in TIMING_METRICS}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="8 runs instead of 64")
    args = parser.parse_args()
    stiffness, delays = ([500, 8000], [1]) if args.quick else ([500, 1000, 2000, 8000],
                                                               [1, 2, 3, 4])
    with tempfile.TemporaryDirectory() as tmp:
        spec = Path(tmp) / "scaling.toml"
        spec.write_text(SPEC.format(stiffness=stiffness, delays=delays))
        plan = plan_sweep(load_spec(spec), tmp, str(spec))
        print(f"uptime before: {uptime()}")
        print(f"{plan.count} runs: collision, hil, 3.5 s each; sponge stiffness {stiffness} "
              f"N/m x servo delay {delays} cycles x seeds 0-3\n")
        sweep_s = sweep_command(spec, Path(tmp) / "out")
        seq_s, seq = sequential(plan)
        _, rows = read_results(Path(tmp) / "out" / "results.csv")
        summary = json.loads((Path(tmp) / "out" / "summary.json").read_text())
        equal = 0
        for row in rows:
            kept = json.loads((Path(tmp) / "out" / "runs" / row["run_id"] /
                               "metrics.json").read_text())
            equal += deterministic(kept) == deterministic(seq[row["run_id"]])
        workers: dict[str, list[float]] = {}
        for row in rows:
            workers.setdefault(row["worker"], []).append(float(row["worker_rss_peak_MiB"]))
        ideal_s, per = ideal_times(plan)
        shared_s = seq_s - (per - 1) * ideal_s  # each setting's ideal once instead of `per`
        ratio = sweep_s / seq_s
        print(f"\n| | wall time | runs/min |\n|---|---|---|\n"
              f"| sweep on Ray ({summary['workers']} workers, {summary['ideal_runs']} ideal "
              f"runs; whole command) | {sweep_s:.1f} s | {60 * plan.count / sweep_s:.1f} |\n"
              f"| sequential, one process ({plan.count} ideal runs; run_scenario as `run`, no "
              f"files) | {seq_s:.1f} s | {60 * plan.count / seq_s:.1f} |\n"
              f"| sequential with the ideal shared as the sweep does (estimate: less "
              f"{plan.count - plan.count // per} ideal runs, {ideal_s / (plan.count // per):.2f} "
              f"s each timed apart) | {shared_s:.1f} s | {60 * plan.count / shared_s:.1f} |")
        print(f"\nratio sweep / sequential: {ratio:.2f} (target <= {TARGET_RATIO}: "
              f"{'met' if ratio <= TARGET_RATIO else 'MISSED'}); against the estimate with the "
              f"ideal shared: {sweep_s / shared_s:.2f}")
        print(f"rows equal to the sequential run's metrics (all but {', '.join(TIMING_METRICS)}): "
              f"{equal}/{len(rows)}")
        print("peak RSS per worker: " + ", ".join(
            f"{w.split(':')[-1]}: {max(v):.0f} MiB after {len(v)} runs"
            for w, v in sorted(workers.items())))
        print(f"uptime after: {uptime()}")


if __name__ == "__main__":
    main()
