"""Headless runs: a scenario end to end, writing telemetry.csv, metrics.json and plots."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from app.bag import replace_bag_dir, write_bag
from app.config import EmulatorConfig, merge_overrides
from app.metrics import collision_metrics, compute_metrics, contact_pair
from app.plots import plot_run
from app.report import write_json, write_telemetry_csv
from app.sim.loop import Emulator


@dataclass
class RunResult:
    emulator: Emulator
    metrics: dict
    files: list[Path]


def ideal_collision(config: EmulatorConfig, duration_s: float) -> dict:
    """The collision metrics of the same scenario run in ideal mode (the reference); {}
    when the ideal run has no contact."""
    em = Emulator(config, mode="ideal")
    em.run(duration_s)
    rows, index = em.telemetry.rows(), em.telemetry.index
    pair = contact_pair(rows, index, em.n_sat) if em.n_sat >= 2 and len(rows) else None
    return {} if pair is None else collision_metrics(rows, index, em.dt_s, *pair) or {}


def run_scenario(
    config: EmulatorConfig,
    mode: str | None = None,
    duration_s: float | None = None,
    out_dir: str | Path | None = None,
    progress=None,
    with_ideal: bool = True,
    bag: bool = False,
    bag_rate_hz: float | None = None,
) -> RunResult:
    """Run a scenario headless; with out_dir, write its telemetry, metrics and plots (and
    with ``bag`` a ROS 2 bag, ``out_dir/bag``: :func:`app.bag.write_bag`).

    The telemetry buffer is sized to hold the whole run, so nothing recorded is dropped;
    on a safety stop the run ends there and everything up to it is written. A hil run
    with two or more satellites is compared with its ideal run unless ``with_ideal`` is
    False.
    """
    duration_s = duration_s or config.loop.duration_s
    cycles = int(round(duration_s * config.loop.rate_hz)) + 2
    if cycles > config.loop.telemetry_capacity:
        config = merge_overrides(config, {"loop": {"telemetry_capacity": cycles}})
    em = Emulator(config, mode=mode)
    t0 = time.perf_counter()
    try:
        em.run(duration_s, progress=progress)
    finally:
        wall_s = time.perf_counter() - t0
        ideal = None
        if with_ideal and em.mode == "hil" and len(config.satellites) >= 2:
            ideal = ideal_collision(config, duration_s)
        metrics = compute_metrics(em, wall_s, ideal_collision=ideal)
        files = []
        if out_dir is not None:
            out = Path(out_dir)
            write_telemetry_csv(out / "telemetry.csv", em.columns, em.telemetry.rows())
            write_json(out / "metrics.json", metrics)
            files = [out / "telemetry.csv", out / "metrics.json"]
            files += plot_run(
                em.telemetry.rows(), em.telemetry.index, out, em.n_sat, len(em.arms),
                metrics.get("collision"), note=metrics["scaling"]["text"],
            )
            if bag:
                files.append(write_bag(replace_bag_dir(out / "bag"), em.config,
                                       em.telemetry.rows(), em.telemetry.index, bag_rate_hz))
    return RunResult(em, metrics, files)
