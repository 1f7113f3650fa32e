"""What one headless run runs: a scenario (or a config file), a mode, a duration, a seed and
``--set`` overrides resolved into one EmulatorConfig.

``orbit-emulator run`` and every run of a sweep (app/campaign/sweep.py) resolve their configuration
here, so that a sweep's run is exactly the ``run`` of the same settings. The resolved
configuration carries the mode (``loop.mode``), the duration (``loop.duration_s``) and the
seed (``loop.seed``): it alone says what the run does.
"""

from __future__ import annotations

from pathlib import Path

from app.config import (
    EmulatorConfig,
    load_config,
    max_telemetry_rows,
    merge_overrides,
    merge_overrides_all,
)
from app.scenarios import load_scenario


def resolve_run_config(
    scenario: str | None = None,
    config_file: str | Path | None = None,
    *,
    mode: str | None = None,
    duration_s: float | None = None,
    seed: int | None = None,
    overrides: list[dict] = (),
    duration_name: str = "--duration",
) -> EmulatorConfig:
    """The configuration of one headless run.

    The base is ``config_file`` if given, else the built-in ``scenario``
    (:func:`base_config`); then :func:`finish_run_config`.
    """
    return finish_run_config(base_config(scenario, config_file), mode=mode,
                             duration_s=duration_s, seed=seed, overrides=overrides,
                             duration_name=duration_name)


def base_config(scenario: str | None = None,
                config_file: str | Path | None = None) -> EmulatorConfig:
    """A run's starting point: the TOML file ``config_file`` if given, else the built-in
    ``scenario``."""
    return load_config(config_file) if config_file else load_scenario(scenario)


def finish_run_config(
    config: EmulatorConfig,
    *,
    mode: str | None = None,
    duration_s: float | None = None,
    seed: int | None = None,
    overrides: list[dict] = (),
    duration_name: str = "--duration",
) -> EmulatorConfig:
    """The run's configuration from its base: the seed, then each override (a merge patch,
    :func:`app.config.merge_overrides`) in order; the mode and duration default to the
    configuration's own. A duration whose telemetry would not fit in memory is refused,
    named by ``duration_name``."""
    seeded = [{"loop": {"seed": seed}}] if seed is not None else []
    config = merge_overrides_all(config, [*seeded, *overrides])  # validated once, together
    duration_s = duration_s or config.loop.duration_s
    check_headless_duration(config, duration_s, duration_name)
    return merge_overrides(config, {"loop": {"mode": mode or config.loop.mode,
                                             "duration_s": duration_s}})


def check_headless_duration(config: EmulatorConfig, duration_s: float,
                            name: str = "--duration") -> None:
    """A headless run keeps every cycle in memory: refuse a duration beyond that."""
    cycles = duration_s * config.loop.rate_hz
    max_cycles = max_telemetry_rows(len(config.satellites), len(config.robots),
                                    len(config.rail_robots)) - 2
    if cycles > max_cycles:
        raise ValueError(
            f"{name}: {duration_s:g} s at {config.loop.rate_hz:g} Hz is {cycles:.3g} cycles; "
            f"a headless run keeps every cycle in memory, at most {max_cycles:,} "
            f"({max_cycles / config.loop.rate_hz:g} s at this rate)")
