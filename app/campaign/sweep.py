"""Campaigns: a sweep spec (TOML) names a scenario, a grid and random draws over its
settings, seeds and the metrics to collect; this module validates it, expands it into runs,
runs one run, and keeps the results table (``results.csv``) that a sweep streams into and
``--resume`` reads back. Running the runs on Ray is app/campaign/sweep_ray.py.

Each run is exactly the headless run of ``orbit-emulator run`` with its settings and seed:
its configuration is resolved by :mod:`app.runs.run_config` and run by
:func:`app.runs.headless.run_scenario`. A run is identified by the hash of its resolved
configuration (which holds its seed, mode and duration).
"""

from __future__ import annotations

import csv
import difflib
import hashlib
import io
import itertools
import json
import math
import os
import resource
import socket
import time
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import tomllib
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from app.config import (
    MAX_INDEX_DIGITS,
    ConfigError,
    EmulatorConfig,
    dotted_override,
    item_index,
    merge_overrides,
    merge_overrides_all,
)
from app.config.inputs import InputFileError, read_bounded_text
from app.runs.run_config import base_config, finish_run_config
from app.scenarios import scenario_names

MAX_RUNS = 100_000
"""The most runs one spec may name (grid points × seeds or draws)."""

KEEP = ("none", "metrics", "telemetry", "all")
"""What each run leaves in DIR/runs/<run-id>/: nothing, metrics.json, + telemetry.csv,
+ the plots."""

STATUSES = ("finished", "safety_stop", "error", "lost")
"""A row's status: the run ended (finished or in a safety stop), raised (error), or its
worker died twice (lost: ``--resume`` runs it again)."""

FIXED_COLUMNS_HEAD = ("run", "run_id", "seed")
FIXED_COLUMNS_MID = ("status", "reason")
FIXED_COLUMNS_TAIL = ("wall_s", "worker", "worker_rss_peak_MiB")

TIMING_METRICS = ("realtime_factor", "cycle_time_us")
"""metrics.json's wall-clock figures: they differ from one run of a configuration to the
next; everything else in it is determined by the configuration and seed."""

METRIC_FIELDS: dict[str, tuple[str, ...]] = {
    "": ("scenario", "mode", "status", "error", "duration_s", "cycles", "rate_hz",
         "realtime_factor", "cycle_time_us", "force_scale", "torque_scale", "scaling",
         "vfdm_iterations", "seed", "satellites", "robots", "collision", "safety_stop",
         "passivity", "collision_forecast", "capture", "success", "warnings"),
    "satellites": ("id", "name", "position_error_max_m", "position_error_rms_m",
                   "velocity_error_rms_mps", "attitude_error_max_rad", "delta_v_mps",
                   "delta_v_pushed_mps"),
    "collision": ("pair", "impulse_Ns", "impulse_balance", "normal", "off_normal_ratio",
                  "true_impulse_Ns", "peak_force_N",
                  "contact_duration_s", "touches", "dt_s", "contact_energy_J", "restitution",
                  "approach_speed_mps", "contact_start_s", "contact_end_s",
                  "contact_open_at_end", "window_s", "warnings", "restitution_ideal",
                  "restitution_error", "true_impulse_ratio", "restitution_sd",
                  "restitution_interval_95", "restitution_systematic",
                  "restitution_bias_noisy", "uncertainty", "rendering_error_m",
                  "rendering_error_max_m", "contact_depth_m"),
    "robots": ("id", "name", "satellite", "position_error_max_m", "position_error_rms_m",
               "velocity_error_rms_mps", "attitude_error_max_rad", "rail_travel_m",
               "posture_deviation_max_rad"),
    "collision_forecast": ("restitution_sd", "restitution_sd_se", "restitution_mean",
                           "restitution_error_mean",
                           "peak_force_N", "noise_force_N", "peak_to_noise", "replicates",
                           "replicates_with_restitution", "restitution_noise_free",
                           "restitution_systematic", "velocity_sd_mps", "rendering_error_m",
                           "contact_depth_m", "note"),
    "cycle_time_us": ("p50", "p99"),
    "safety_stop": ("robot", "t_s", "reason"),
    "passivity": ("dissipated_J",),
    "scaling": ("law", "length", "time", "mass", "force_scale", "torque_scale", "satellites",
                "text"),
    "capture": ("captured", "t_s", "position_miss_m", "relative_speed_mps",
                "relative_angle_rad", "relative_rate_radps", "peak_contact_force_N",
                "residual_rate_radps", "residual_speed_mps"),
    "success": ("passed", "libration", "docking", "waypoints", "final_position", "recovery",
                "synchronisation"),
}
"""The fields of metrics.json (app/runs/metrics.py metrics_of) a metric path is checked against:
the top level (""), a satellite's entry, a robot's, the collision's, and the small tables; deeper
levels (e.g. ``collision.impulse_Ns.sat1``) are not checked."""


class SpecError(ValueError):
    """A sweep spec the sweep refuses; the message names the field."""


# --- the spec --------------------------------------------------------------------------------


class _SpecModel(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


Pair = tuple[float, float]


class Distribution(_SpecModel):
    """How a ``[random]`` setting is drawn: exactly one of ``uniform = [lo, hi]``,
    ``loguniform = [lo, hi]`` (0 < lo), ``normal = [mean, sd]`` or ``choice = [a, b, ...]``."""

    uniform: Pair | None = None
    loguniform: Pair | None = None
    normal: Pair | None = None
    choice: Annotated[list[Any], Field(min_length=1)] | None = None

    @model_validator(mode="after")
    def _one_kind(self) -> Distribution:
        given = [k for k in ("uniform", "loguniform", "normal", "choice")
                 if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError("give exactly one of uniform = [lo, hi], loguniform = [lo, hi], "
                             "normal = [mean, sd] or choice = [values]"
                             + (f" (got {', '.join(given)})" if given else ""))
        pair = self.uniform or self.loguniform or self.normal
        if pair is not None and not all(math.isfinite(v) for v in pair):
            raise ValueError(f"{given[0]}: the numbers must be finite")
        if self.uniform and not self.uniform[0] <= self.uniform[1]:
            raise ValueError("uniform: lo must not exceed hi")
        if self.loguniform and not 0 < self.loguniform[0] <= self.loguniform[1]:
            raise ValueError("loguniform: needs 0 < lo <= hi")
        if self.normal and self.normal[1] < 0:
            raise ValueError("normal: the standard deviation must not be negative")
        return self

    def draw(self, rng: np.random.Generator):
        """One value."""
        if self.uniform:
            return float(rng.uniform(*self.uniform))
        if self.loguniform:
            lo, hi = self.loguniform
            return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))
        if self.normal:
            return float(rng.normal(*self.normal))
        return self.choice[int(rng.integers(len(self.choice)))]

    def probes(self) -> list:
        """Values to try on the configuration before anything runs: the bounds, the
        mean, every choice."""
        if self.choice is not None:
            return list(self.choice)
        return list(self.uniform or self.loguniform or self.normal[:1])


class SweepSpec(_SpecModel):
    """A sweep spec (the manual's tutorial "A campaign on Ray"). Setting keys are the
    dotted keys of ``run --set``, quoted in TOML:
    ``"materials.sponge.stiffness_Npm" = [500, 2000]``."""

    scenario: str | None = None
    """A built-in scenario, or"""
    config: str | None = None
    """a scenario file (relative to the spec's own folder)."""
    description: str = ""
    mode: Literal["hil", "ideal"] | None = None
    duration_s: Annotated[float, Field(gt=0.0, allow_inf_nan=False)] | None = None
    """Seconds of scenario time (``run --duration``); default: the scenario's."""
    seeds: Annotated[list[Annotated[int, Field(ge=0)]], Field(min_length=1)] | None = None
    draws: Annotated[int, Field(ge=1)] | None = None
    """Runs per grid point with seeds 0 … draws − 1 (``[random]`` is drawn per seed)."""
    metrics: Annotated[list[str], Field(min_length=1)]
    """Dotted paths into metrics.json, e.g. ``collision.restitution``."""
    set: dict[str, Any] = {}
    """Settings for every run (``run --set``)."""
    grid: dict[str, Any] = {}
    """Every combination: a key and its list of values, or a table of keys whose lists go
    together (a linked axis: their i-th values make one point)."""
    random: dict[str, Distribution] = {}

    @model_validator(mode="after")
    def _one_of_each(self) -> SweepSpec:
        if (self.scenario is None) == (self.config is None):
            raise ValueError('give one of scenario = "NAME" or config = "FILE.toml"')
        if (self.seeds is None) == (self.draws is None):
            raise ValueError("give one of seeds = [0, 1, ...] or draws = N")
        if self.seeds is not None and len(set(self.seeds)) != len(self.seeds):
            twice = sorted({s for s in self.seeds if self.seeds.count(s) > 1})
            raise ValueError(f"seeds: given twice: {twice} (a run is its configuration and "
                             f"seed: the same seed is the same run)")
        return self

    def seed_list(self) -> list[int]:
        return list(self.seeds) if self.seeds is not None else list(range(self.draws))


def _loc(parts) -> str:
    out = []
    for p in parts:
        text = str(p)
        out.append(json.dumps(text) if not text.replace("_", "").isalnum() else text)
    return ".".join(out) or "(top level)"


def _spec_error(err: ValidationError, where: str) -> SpecError:
    lines = []
    for e in err.errors():
        msg = e["msg"].removeprefix("Value error, ")
        if e["type"] == "extra_forbidden":
            msg = "unknown field"
            if len(e["loc"]) == 1:
                msg += f" (fields: {', '.join(SweepSpec.model_fields)})"
        if e["type"] == "missing":
            msg = "required"
        lines.append(f"{_loc(e['loc'])}: {msg}")
    return SpecError(f"{where}: " + "; ".join(lines))


def load_spec(path: str | Path) -> SweepSpec:
    """Read and validate a spec file's shape (its settings are checked by plan_sweep)."""
    path = Path(path)
    try:
        data = tomllib.loads(read_bounded_text(path, what="a sweep spec"))
    except FileNotFoundError:
        raise SpecError(f"sweep spec not found: {path}") from None
    except IsADirectoryError:
        raise SpecError(f"{path}: is a directory, not a sweep spec") from None
    except InputFileError as err:
        raise SpecError(str(err)) from None
    except (OSError, UnicodeDecodeError) as err:
        raise SpecError(f"{path}: cannot be read: {getattr(err, 'strerror', None) or err}"
                        ) from None
    except tomllib.TOMLDecodeError as err:
        raise SpecError(f"{path}: not valid TOML: {err}") from None
    except RecursionError:
        raise SpecError(f"{path}: not valid TOML: nested too deeply") from None
    try:
        return SweepSpec.model_validate(data)
    except ValidationError as err:
        raise _spec_error(err, str(path)) from None


# --- the plan --------------------------------------------------------------------------------


@dataclass(frozen=True)
class Run:
    """One run of a sweep: its place in the plan, its seed, the values the spec gave it
    and its resolved configuration."""

    index: int
    seed: int
    params: dict[str, Any]
    config: EmulatorConfig | None
    error: str | None = None
    """Why its configuration could not be resolved (a combination of valid values that is
    not valid together): the run becomes a row with status "error"."""
    run_id: str = ""
    ideal_id: str | None = None


@dataclass
class SweepPlan:
    """A validated spec, ready to expand into runs."""

    spec: SweepSpec
    base: EmulatorConfig
    axes: list[list[dict[str, Any]]]
    """One list per grid axis: the points of the axis, each {key: value}."""
    param_keys: list[str]
    set_patches: list[dict] = field(default_factory=list)
    source: str = ""

    @property
    def count(self) -> int:
        return count_runs(self.spec)

    def columns(self) -> list[str]:
        """The results table's header."""
        return [*FIXED_COLUMNS_HEAD, *self.param_keys, *FIXED_COLUMNS_MID,
                *self.spec.metrics, *FIXED_COLUMNS_TAIL]

    def runs(self) -> Iterator[Run]:
        """Every run, grid points in the spec's order and seeds innermost, resolved one at
        a time (a plan of 100,000 runs is not held in memory)."""
        seeds = self.spec.seed_list()
        index = 0
        for point in itertools.product(*self.axes):
            fixed = {k: v for part in point for k, v in part.items()}
            for seed in seeds:
                drawn = {k: d.draw(draw_rng(seed, k)) for k, d in self.spec.random.items()}
                yield self.resolve(index, seed, {**fixed, **drawn})
                index += 1

    def resolve(self, index: int, seed: int, params: dict[str, Any]) -> Run:
        """A run's configuration: exactly what ``orbit-emulator run`` resolves for its
        scenario, mode, duration, seed and ``--set`` of the spec's settings."""
        patches = [*self.set_patches, *(dotted_override(k, v) for k, v in params.items())]
        try:
            config = finish_run_config(self.base, mode=self.spec.mode,
                                       duration_s=self.spec.duration_s, seed=seed,
                                       overrides=patches, duration_name="duration_s")
        except ValueError as err:
            return Run(index, seed, params, None, error=f"{type(err).__name__}: {err}",
                       run_id=_hash({"unresolved": params, "seed": seed}))
        return Run(index, seed, params, config, run_id=run_id(config),
                   ideal_id=ideal_id(config))


def count_runs(spec: SweepSpec) -> int:
    """Grid points × seeds (or draws), without expanding anything."""
    n = len(spec.seed_list()) if spec.seeds is not None else spec.draws
    for axis in _grid_axes(spec):
        n *= len(axis)
    return n


def draw_rng(seed: int, key: str) -> np.random.Generator:
    """The random stream of one ``[random]`` key in the run of this seed: the same seed
    draws the same value at every grid point, whatever the other keys."""
    return np.random.default_rng([seed, zlib.crc32(key.encode())])


def _hash(data) -> str:
    text = data if isinstance(data, str) else json.dumps(data, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def run_id(config: EmulatorConfig) -> str:
    """A run's identity: the hash of its resolved configuration (seed, mode and duration
    included)."""
    return _hash(config.model_dump_json())


def ideal_id(config: EmulatorConfig) -> str | None:
    """The identity of the ideal reference a hil run with two or more satellites is
    compared with: its configuration without the seed (which drives the sensor noise only,
    app/sim/loop.py: an ideal run has no sensor). None: no ideal run needed."""
    if config.loop.mode != "hil" or len(config.satellites) < 2:
        return None
    return _hash(config.model_copy(
        update={"loop": config.loop.model_copy(update={"seed": 0})}).model_dump_json())


def _grid_axes(spec: SweepSpec) -> list[list[dict[str, Any]]]:
    """The grid's axes (checked shapes): a plain key is an axis of its values, a table is
    one axis whose keys' lists go together."""
    axes = []
    for name, values in spec.grid.items():
        if isinstance(values, list):
            _check_values(f"grid.{_loc([name])}", values)
            axes.append([{name: v} for v in values])
        elif isinstance(values, dict):
            if not values:
                raise SpecError(f"grid.{_loc([name])}: an empty table")
            lengths = {}
            for key, vals in values.items():
                where = f"grid.{_loc([name, key])}"
                if not isinstance(vals, list):
                    raise SpecError(f"{where}: a linked axis holds a list of values per key "
                                    f"(a dotted key is quoted: \"a.b.c\" = [...])")
                _check_values(where, vals)
                lengths[key] = len(vals)
            if len(set(lengths.values())) > 1:
                raise SpecError(f"grid.{_loc([name])}: the lists of a linked axis must have "
                                f"one length, got " + ", ".join(
                                    f"{k}: {n}" for k, n in lengths.items()))
            n = next(iter(lengths.values()))
            axes.append([{k: values[k][i] for k in values} for i in range(n)])
        else:
            raise SpecError(f"grid.{_loc([name])}: expected a list of values, got "
                            f"{values!r}")
    return axes


def _grid_wheres(spec: SweepSpec) -> dict[str, str]:
    """Each swept grid key → where it is in the spec, for messages."""
    out = {}
    for name, values in spec.grid.items():
        for key in values if isinstance(values, dict) else [name]:
            out[key] = "grid." + _loc([name, key] if isinstance(values, dict) else [name])
    return out


def _check_values(where: str, values: list) -> None:
    if not values:
        raise SpecError(f"{where}: an empty list of values")
    seen = set()
    for v in values:  # (linear: a spec may list 100,000 values)
        mark = json.dumps(v, sort_keys=True, default=str)
        if mark in seen:
            raise SpecError(f"{where}: the value {v!r} is given twice")
        seen.add(mark)


def plan_sweep(spec: SweepSpec, spec_dir: str | Path = ".", source: str = "") -> SweepPlan:
    """Check everything a spec names before anything runs: its size, every setting key and
    value (tried on the scenario), every metric path. Raises SpecError naming the field."""
    prefix = f"{source}: " if source else ""
    try:
        return _plan(spec, Path(spec_dir), source)
    except SpecError as err:
        raise SpecError(prefix + str(err)) from None


def _plan(spec: SweepSpec, spec_dir: Path, source: str) -> SweepPlan:
    axes = _grid_axes(spec)
    n = count_runs(spec)
    if n > MAX_RUNS:
        sizes = " × ".join(str(len(a)) for a in axes)
        raise SpecError(f"the spec names {n:,} runs ({sizes + ' grid points × ' if sizes else ''}"
                        f"{len(spec.seed_list()) if spec.seeds else spec.draws} seeds); at "
                        f"most {MAX_RUNS:,}")
    base = _base(spec, spec_dir)
    set_patches = []
    for key, value in spec.set.items():
        _check_exists(base, key, value, f"set.{_loc([key])}")
        set_patches.append(dotted_override(key, value))
    if set_patches:  # together: settings that must change together may be set apart
        try:
            base = merge_overrides_all(base, set_patches)
        except ConfigError as err:
            for key, value in spec.set.items():  # one that is wrong on its own: name it
                _check_value(base, key, value, f"set.{_loc([key])}")
            raise SpecError(f"set (together): {err}") from None
    param_keys: list[str] = []
    wheres = _grid_wheres(spec)
    for axis in axes:
        for key in axis[0]:
            _check_exists(base, key, axis[0][key], wheres[key])
        for point in axis:  # a linked axis's keys go together
            try:
                merge_overrides_all(base, [dotted_override(k, v) for k, v in point.items()])
            except ConfigError as err:
                where = " & ".join(f"{wheres[k]} = {_show(v)}" for k, v in point.items())
                raise SpecError(f"{where}: {err}") from None
        for key in axis[0]:
            if key in spec.set:
                raise SpecError(f"{wheres[key]}: also in [set]; give it in one place")
            _add_key(param_keys, key, wheres[key])
    for key, dist in spec.random.items():
        where = f"random.{_loc([key])}"
        probes = dist.probes()
        _check_key(base, key, probes[0], where)
        for value in probes[1:]:
            _check_value(base, key, value, where)
        _add_key(param_keys, key, where)
    _check_metrics(spec.metrics, base, param_keys)
    plan = SweepPlan(spec, _base(spec, spec_dir), axes, param_keys, set_patches, source)
    _check_duration(plan)
    return plan


def _base(spec: SweepSpec, spec_dir: Path) -> EmulatorConfig:
    if spec.scenario is not None and spec.scenario not in scenario_names():
        raise SpecError(f"scenario: unknown scenario {spec.scenario!r}; choose one of "
                        f"{', '.join(scenario_names())}, or config = \"FILE.toml\"")
    try:
        return base_config(spec.scenario, spec_dir / spec.config if spec.config else None)
    except ConfigError as err:
        raise SpecError(f"{'config' if spec.config else 'scenario'}: {err}") from None


def _check_duration(plan: SweepPlan) -> None:
    try:
        finish_run_config(plan.base, mode=plan.spec.mode, duration_s=plan.spec.duration_s,
                          overrides=plan.set_patches, duration_name="duration_s")
    except ValueError as err:
        raise SpecError(str(err)) from None


def _add_key(keys: list[str], key: str, where: str) -> None:
    if key in keys:
        raise SpecError(f"{where}: the key is swept twice (grid and random, or two axes)")
    if key in (*FIXED_COLUMNS_HEAD, *FIXED_COLUMNS_MID, *FIXED_COLUMNS_TAIL):
        raise SpecError(f"{where}: not a setting")
    keys.append(key)


def _check_exists(base: EmulatorConfig, key: str, sample, where: str) -> None:
    """The key names a setting of the scenario, or one the configuration takes (a table
    the base leaves out, tried with a sample value)."""
    missing = _missing_part(base.model_dump(mode="json"), key)
    if missing is None:
        return
    try:
        merge_overrides(base, dotted_override(key, sample))
    except ConfigError:
        raise SpecError(f"{where}: unknown key ({missing})") from None


def _check_key(base: EmulatorConfig, key: str, sample, where: str) -> None:
    """The key names a setting of the scenario (or the config takes it), and the sample
    value is valid there."""
    missing = _missing_part(base.model_dump(mode="json"), key)
    try:
        merge_overrides(base, dotted_override(key, sample))
    except ConfigError as err:
        if missing is not None:
            raise SpecError(f"{where}: unknown key ({missing})") from None
        raise SpecError(f"{where} = {_show(sample)}: {err}") from None


def _check_value(base: EmulatorConfig, key: str, value, where: str) -> None:
    try:
        merge_overrides(base, dotted_override(key, value))
    except ConfigError as err:
        raise SpecError(f"{where} = {_show(value)}: {err}") from None


def _missing_part(tree, key: str) -> str | None:
    """Why ``key`` names nothing in the configuration ``tree``, or None if it does."""
    node, done = tree, []
    for part in key.split("."):
        part = part.strip()
        here = ".".join(done) or "the configuration"
        if isinstance(node, dict):
            if part not in node:
                close = difflib.get_close_matches(part, list(node), n=1)
                hint = f"; did you mean {'.'.join([*done, close[0]])!r}?" if close else ""
                return f"{here} has no {part!r}{hint}"
            node = node[part]
        elif isinstance(node, list):
            i = item_index(part)
            if i is None or i >= len(node):
                shown = part if len(part) <= 20 else f"{part[:12]}... ({len(part)} characters)"
                rule = "" if i is not None else f" (1 to {MAX_INDEX_DIGITS} ASCII digits)"
                return f"{here} is a list of {len(node)}: {shown!r} is not an index of it{rule}"
            node = node[i]
        else:
            return f"{here} is a value, not a table"
        done.append(part)
    return None


def _show(value) -> str:
    return json.dumps(value) if isinstance(value, (list, dict, str)) else repr(value)


def _check_metrics(metrics: list[str], base: EmulatorConfig, param_keys: list[str]) -> None:
    for i, path in enumerate(metrics):
        where = f"metrics.{i} ({path!r})"
        if path in metrics[:i]:
            raise SpecError(f"{where}: given twice")
        if path in (*FIXED_COLUMNS_HEAD, *FIXED_COLUMNS_MID, *FIXED_COLUMNS_TAIL, *param_keys):
            raise SpecError(f"{where}: already a column of the table")
        parts = path.split(".")
        if parts[0] not in METRIC_FIELDS[""]:
            raise SpecError(f"{where}: metrics.json has no {parts[0]!r} (it has: "
                            f"{', '.join(METRIC_FIELDS[''])})")
        if parts[0] in ("satellites", "robots"):
            n = len(getattr(base, parts[0]))
            index = item_index(parts[1]) if len(parts) >= 2 else None
            if index is None or index >= n:
                raise SpecError(f"{where}: {parts[0]}.N with N in 0..{n - 1} (the scenario "
                                f"has {n})")
            parts = [parts[0], *parts[2:]]
        if len(parts) > 1 and parts[0] in METRIC_FIELDS and parts[1] not in \
                METRIC_FIELDS[parts[0]]:
            raise SpecError(f"{where}: {parts[0]} has no {parts[1]!r} (it has: "
                            f"{', '.join(METRIC_FIELDS[parts[0]])})")


# --- one run -------------------------------------------------------------------------------


def compute_ideal(config: EmulatorConfig) -> tuple[str, dict | str]:
    """The ideal reference of a hil run's configuration, after its pre-flight, from one
    ideal run: ("ok", its collision metrics), ("refused", the pre-flight's reason) or
    ("error", why it raised)."""
    from app.runs.headless import checked_reference, headless_config
    from app.runs.preflight import PreflightRefused

    duration_s = config.loop.duration_s
    try:
        return "ok", checked_reference(headless_config(config, duration_s), duration_s) or {}
    except PreflightRefused as err:
        return "refused", str(err)
    except Exception as err:  # noqa: BLE001 - a run's failure is a row, not a crash
        return "error", f"{type(err).__name__}: {err}"


def execute_run(config: EmulatorConfig, ideal: tuple[str, dict | str] | None, keep: str,
                run_dir: str | None) -> dict:
    """One run, as ``orbit-emulator run`` runs it (with its ideal reference given, if it
    needs one, after the pre-flight that came with it): the outcome {status, reason,
    metrics, wall_s, worker, worker_rss_peak_MiB}. A configuration the pre-flight refused
    is the outcome "refused" and nothing runs; whatever the run raises is caught: an
    outcome with status "error" (with the metrics of what it recorded, if it had started).
    With ``keep`` telemetry or all, it writes telemetry.csv (and the plots) into run_dir;
    metrics.json is the caller's to write."""
    from app.runs.headless import RunFailed, run_scenario, write_run_files
    from app.runs.preflight import PreflightRefused

    t0 = time.perf_counter()
    status, reason, metrics = "error", "", None
    if ideal is not None and ideal[0] == "refused":
        status, reason = "refused", ideal[1]
    else:
        try:
            result = run_scenario(
                config, mode=config.loop.mode, duration_s=config.loop.duration_s,
                ideal=ideal[1] if ideal is not None and ideal[0] == "ok" else None,
                with_ideal=ideal is not None, preflight_done=ideal is not None)
            if ideal is not None and ideal[0] == "error":
                reason = f"the ideal reference run: {ideal[1]}"
            else:
                metrics = result.metrics
                status, reason = _status_of(metrics)
                if keep in ("telemetry", "all") and run_dir is not None:
                    write_run_files(result.emulator, metrics, run_dir, plots=keep == "all")
        except PreflightRefused as err:  # a run with no shared reference checks itself
            status, reason = "refused", str(err)
        except RunFailed as err:  # it raised once started: what it recorded is kept
            reason, metrics = str(err), err.result.metrics
        except Exception as err:  # noqa: BLE001 - a run's failure is a row, not a crash
            reason = f"{type(err).__name__}: {err}"
    return {"status": status, "reason": reason, "metrics": metrics,
            "wall_s": time.perf_counter() - t0, "worker": f"{socket.gethostname()}:{os.getpid()}",
            "worker_rss_peak_MiB": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def _status_of(metrics: dict) -> tuple[str, str]:
    stop = metrics.get("safety_stop")
    if metrics["status"] == "safety_stop" and stop:
        return "safety_stop", (f"robot {stop['robot']} at t = {stop['t_s']:.3f} s: "
                               f"{stop['reason']}")
    return metrics["status"], ""


def lost_outcome(err: BaseException) -> dict:
    """The outcome of a run whose worker died twice (Ray retried it once)."""
    text = str(err).strip().splitlines()
    return {"status": "lost", "reason": f"{type(err).__name__}: "
            f"{text[0] if text else 'the worker died'} (retried once)",
            "metrics": None, "wall_s": None, "worker": None, "worker_rss_peak_MiB": None}


def unresolved_outcome(run: Run) -> dict:
    return {"status": "error", "reason": run.error, "metrics": None, "wall_s": 0.0,
            "worker": None, "worker_rss_peak_MiB": None}


# --- the results table ----------------------------------------------------------------------


def metric_value(metrics: dict | None, path: str):
    """The value at a dotted path of metrics.json (a number picks a list item); None where
    the run has none (e.g. collision.* of a run without contact)."""
    node = metrics
    for part in path.split("."):
        if isinstance(node, dict):
            node = node.get(part)
        elif isinstance(node, list) and item_index(part) is not None \
                and item_index(part) < len(node):
            node = node[item_index(part)]
        else:
            return None
    return node


def cell(value) -> str:
    """A value as the table writes it: numbers exactly (repr), None empty, lists and tables
    as JSON."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return value
    return json.dumps(value, separators=(",", ":"))


def row_of(plan: SweepPlan, run: Run, outcome: dict) -> dict[str, str]:
    """The table row of a run and its outcome."""
    row = {"run": cell(run.index), "run_id": run.run_id, "seed": cell(run.seed)}
    row.update({k: cell(run.params.get(k)) for k in plan.param_keys})
    row["status"], row["reason"] = outcome["status"], " ".join(outcome["reason"].split())
    row.update({m: cell(metric_value(outcome["metrics"], m)) for m in plan.spec.metrics})
    row["wall_s"] = "" if outcome["wall_s"] is None else f"{outcome['wall_s']:.3f}"
    row["worker"] = outcome["worker"] or ""
    rss = outcome["worker_rss_peak_MiB"]
    row["worker_rss_peak_MiB"] = "" if rss is None else f"{rss:.1f}"
    return row


class ResultsTable:
    """``results.csv``: one row per run, appended and flushed as each run ends.

    A new sweep refuses an existing table (``--resume`` continues it instead); resuming
    checks that the table has this spec's columns and forgets its ``lost`` rows (runs whose
    worker died), which run again."""

    def __init__(self, path: Path, columns: list[str], resume: bool) -> None:
        self.path, self.columns = path, columns
        self.done: dict[str, str] = {}
        """run_id → status of the rows already in the table."""
        if path.exists() and not resume:
            raise SpecError(f"--out: {path} exists: --resume continues that sweep (the runs "
                            f"in it are not run again), or choose another --out")
        if path.exists():
            self._read_for_resume()
        self._file = self._writer = None  # opened by the first row

    def _open(self) -> None:
        fresh = not self.path.exists()
        self._file = open(self.path, "a", newline="")  # noqa: SIM115 - closed by close()
        self._writer = csv.DictWriter(self._file, fieldnames=self.columns)
        if fresh:
            self._writer.writeheader()

    def _read_for_resume(self) -> None:
        text = self.path.read_text()
        if text and not text.endswith("\n"):  # a row cut short by a hard kill
            text = text[: text.rfind("\n") + 1]
        rows = list(csv.DictReader(io.StringIO(text)))
        header = next(csv.reader(io.StringIO(text)), [])
        if header != self.columns:
            raise SpecError(f"--resume: {self.path} has the columns {', '.join(header)}; "
                            f"this spec's are {', '.join(self.columns)}: another spec's "
                            f"table (choose another --out)")
        kept = [r for r in rows if r["status"] != "lost"]
        if len(kept) != len(rows) or not self.path.read_text().endswith("\n"):
            tmp = self.path.with_suffix(".csv.tmp")
            with open(tmp, "w", newline="") as f:
                writer = csv.DictWriter(f, fieldnames=self.columns)
                writer.writeheader()
                writer.writerows(kept)
            os.replace(tmp, self.path)
        self.done = {r["run_id"]: r["status"] for r in kept}

    def append(self, row: dict[str, str]) -> None:
        if self._file is None:
            self._open()
        self._writer.writerow(row)
        self._file.flush()
        self.done[row["run_id"]] = row["status"]

    def close(self) -> None:
        if self._file is not None:
            self._file.close()


def read_results(path: str | Path) -> tuple[list[str], list[dict[str, str]]]:
    """A results table: (columns, rows)."""
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        return list(reader.fieldnames or []), list(reader)


def status_counts(statuses) -> dict[str, int]:
    counts = dict.fromkeys(STATUSES, 0)
    for s in statuses:
        counts[s] = counts.get(s, 0) + 1
    return counts
