"""Headless runs: a scenario end to end, writing telemetry.csv, metrics.json and plots."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from app.bag import replace_bag_dir, write_bag
from app.config import EmulatorConfig, merge_overrides
from app.metrics import collision_metrics, compute_metrics, contact_pair
from app.plots import plot_run
from app.preflight import preflight
from app.report import write_json, write_telemetry_csv
from app.sim.loop import Emulator
from app.uncertainty import forecast, snapshot_time_s, spread_of_run


@dataclass
class RunResult:
    emulator: Emulator
    metrics: dict
    files: list[Path]


class RunFailed(RuntimeError):
    """A headless run raised after its start-up: what it recorded up to then is written,
    its metrics.json with status "error" and the reason (``result``)."""

    def __init__(self, reason: str, result: RunResult) -> None:
        super().__init__(reason)
        self.result = result


def ideal_collision(config: EmulatorConfig, duration_s: float) -> dict:
    """The collision metrics of the same scenario run in ideal mode (the reference); {}
    when the ideal run has no contact."""
    em = Emulator(config, mode="ideal")
    em.run(duration_s)
    return collision_of(em)


def collision_of(em: Emulator) -> dict:
    """The collision metrics of an ideal run that ran; {} without contact."""
    rows, index = em.telemetry.rows(), em.telemetry.index
    pair = contact_pair(rows, index, em.n_sat) if em.n_sat >= 2 and len(rows) else None
    return {} if pair is None else collision_metrics(rows, index, em.dt_s, *pair) or {}


def checked_reference(config: EmulatorConfig, duration_s: float,
                      with_ideal: bool = True) -> dict | None:
    """Before a hil run: its pre-flight (app/preflight.py; raises PreflightRefused naming
    the robot, the time and the limit), and from the same ideal run the collision
    reference a run with two or more satellites is compared with (None when it needs
    none). Nothing of the run itself has started."""
    prediction = preflight(config, duration_s)
    if not with_ideal or len(config.satellites) < 2:
        return None
    if prediction is None:  # no robots: no pre-flight, but a reference still
        return ideal_collision(config, duration_s)
    reference = collision_of(prediction)  # at the run's rate (two satellites)
    if reference:  # the fidelity forecast (app/uncertainty.py), in metrics.json
        reference["forecast"] = forecast(config, reference)
    return reference


def run_scenario(
    config: EmulatorConfig,
    mode: str | None = None,
    duration_s: float | None = None,
    out_dir: str | Path | None = None,
    progress=None,
    with_ideal: bool = True,
    bag: bool = False,
    bag_rate_hz: float | None = None,
    ideal: dict | None = None,
    preflight_done: bool = False,
) -> RunResult:
    """Run a scenario headless; with out_dir, write its telemetry, metrics and plots (and
    with ``bag`` a ROS 2 bag, ``out_dir/bag``: :func:`app.bag.write_bag`).

    The telemetry buffer is sized to hold the whole run, so nothing recorded is dropped;
    on a safety stop the run ends there and everything up to it is written. A hil run
    with two or more satellites is compared with its ideal run unless ``with_ideal`` is
    False; ``ideal``: that run's :func:`ideal_collision`, if already computed (it does not
    depend on the seed), else it is computed here. A hil run is refused before it starts
    when its pre-flight fails (PreflightRefused), unless ``preflight_done`` (the caller
    ran :func:`checked_reference`). A run that raises once started ends there: RunFailed,
    after its files are written (status "error"); one its start-up refuses (e.g. a start
    pose not found) raises as it is.
    """
    duration_s = duration_s or config.loop.duration_s
    config = headless_config(config, duration_s)
    hil = (mode or config.loop.mode) == "hil"
    if hil and not preflight_done:
        reference = checked_reference(config, duration_s, with_ideal)
        ideal = reference if ideal is None else ideal
    em = Emulator(config, mode=mode)
    if em.mode == "hil":  # the uncertainty's snapshot, before the predicted contact
        em.snapshot_at_s = snapshot_time_s(config, ideal)
    t0 = time.perf_counter()
    failure = None
    try:
        failure = _run(em, duration_s, progress)
    finally:
        wall_s = time.perf_counter() - t0
        if with_ideal and em.mode == "hil" and len(config.satellites) >= 2:
            if ideal is None:
                ideal = ideal_collision(config, duration_s)
        else:
            ideal = None
        error = None if failure is None else f"{type(failure).__name__}: {failure}"
        metrics = compute_metrics(em, wall_s, ideal_collision=ideal, error=error)
        if failure is None:
            _add_uncertainty(em, metrics)
        files = []
        if out_dir is not None:
            files = write_run_files(em, metrics, out_dir, bag=bag, bag_rate_hz=bag_rate_hz)
    if failure is not None:
        raise RunFailed(error, RunResult(em, metrics, files)) from failure
    return RunResult(em, metrics, files)


def _add_uncertainty(em: Emulator, metrics: dict) -> None:
    """The restitution's interval from the replicates of the contact window
    (app/uncertainty.py); if they fail, the run's record is written all the same, with a
    warning and no interval."""
    coll = metrics.get("collision")
    if coll is None or em.snapshot is None:
        return
    try:
        spread_of_run(em, coll)
    except Exception as err:  # noqa: BLE001 - the run's record matters more
        coll["restitution_sd"] = coll["restitution_interval_95"] = coll["uncertainty"] = None
        coll["warnings"].append(f"the restitution's interval failed: {type(err).__name__}: "
                                f"{err}")


def _run(em: Emulator, duration_s: float, progress) -> Exception | None:
    """Run ``em``: what it raised once started (its status then "error"), else None. What
    its start-up raises (nothing ran) is raised as it is."""
    try:
        em.run(duration_s, progress=progress)
    except Exception as err:
        if em.status != "running":
            raise
        em.status = "error"
        return err
    return None


def headless_config(config: EmulatorConfig, duration_s: float) -> EmulatorConfig:
    """The configuration with its telemetry sized to hold a whole headless run of
    duration_s (and no more: a sweep's worker runs many)."""
    cycles = max(int(round(duration_s * config.loop.rate_hz)) + 2, TELEMETRY_MIN_ROWS)
    if cycles > config.loop.telemetry_capacity:  # validated: the 1 GiB bound
        return merge_overrides(config, {"loop": {"telemetry_capacity": cycles}})
    if cycles < config.loop.telemetry_capacity:  # smaller is always valid
        return config.model_copy(update={
            "loop": config.loop.model_copy(update={"telemetry_capacity": cycles})})
    return config


TELEMETRY_MIN_ROWS = 100
"""The least telemetry capacity a configuration takes ([loop] telemetry_capacity)."""


def write_run_files(em: Emulator, metrics: dict, out_dir: str | Path, telemetry: bool = True,
                    plots: bool = True, bag: bool = False,
                    bag_rate_hz: float | None = None) -> list[Path]:
    """Write what a headless run leaves in ``out_dir``: metrics.json, and as asked
    telemetry.csv, the plots and the ROS 2 bag; the paths written."""
    out = Path(out_dir)
    rows = em.telemetry.rows()
    files = []
    if telemetry:
        write_telemetry_csv(out / "telemetry.csv", em.columns, rows)
        files.append(out / "telemetry.csv")
    write_json(out / "metrics.json", metrics)
    files.append(out / "metrics.json")
    if plots:
        files += plot_run(rows, em.telemetry.index, out, em.n_sat, len(em.arms),
                          metrics.get("collision"), note=metrics["scaling"]["text"])
    if bag:
        files.append(write_bag(replace_bag_dir(out / "bag"), em.config, rows,
                               em.telemetry.index, bag_rate_hz))
    return files
