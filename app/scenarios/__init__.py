"""Built-in scenarios: the TOML files beside this module (paper, Section 4)."""

from __future__ import annotations

from pathlib import Path

from app.config import ConfigError, EmulatorConfig, load_config, read_scenario_file

_DIR = Path(__file__).parent


def scenario_names() -> list[str]:
    return sorted(p.stem for p in _DIR.glob("*.toml"))


def scenario_path(name: str) -> Path:
    path = _DIR / f"{name}.toml"
    if name not in scenario_names():
        raise ConfigError(f"unknown scenario {name!r}; choose one of {scenario_names()}")
    return path


def load_scenario(name: str) -> EmulatorConfig:
    """The validated configuration of a built-in scenario."""
    return load_config(scenario_path(name))


def scenario_descriptions() -> dict[str, str]:
    """Name -> one-line description of every built-in scenario."""
    out = {}
    for name in scenario_names():
        data = read_scenario_file(scenario_path(name))
        out[name] = data.get("description", "")
    return out
