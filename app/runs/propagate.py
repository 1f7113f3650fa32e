"""Run the ODS alone over a scenario's pulses (the `propagate` command)."""

from __future__ import annotations

import numpy as np

from app.config import EmulatorConfig
from app.sim.hand import pulse_wrenches
from app.sim.orbital import OrbitalSimulator
from app.sim.telemetry import satellite_columns


def satellite_row(sim: OrbitalSimulator, force: np.ndarray, torque: np.ndarray) -> np.ndarray:
    """One telemetry row of every satellite, in the order of :func:`satellite_columns`."""
    return np.hstack(
        [sim.position_m, sim.velocity_mps, sim.attitude_wxyz, sim.omega_rel_radps, force, torque]
    ).ravel()


def propagate(config: EmulatorConfig, duration_s: float, dt_s: float):
    """Integrate the ODS; returns (columns, rows) with one row per step, t_s first.

    Row k holds the state at t_k and the wrench applied over [t_k, t_k + dt) (as given,
    before the configured force and torque scales); the last row is the final state.
    """
    if not (dt_s > 0 and np.isfinite(dt_s)):
        raise ValueError("dt must be a positive number of seconds")
    if not (duration_s > 0 and np.isfinite(duration_s)):
        raise ValueError("duration must be a positive number of seconds")
    sim = OrbitalSimulator.from_config(config)
    steps = int(round(duration_s / dt_s))
    rows = np.empty((steps + 1, 1 + 19 * len(config.satellites)))
    for k in range(steps + 1):
        t = k * dt_s
        force, torque = pulse_wrenches(config, t)
        if k == steps:
            force[:], torque[:] = 0.0, 0.0
        rows[k, 0] = t
        rows[k, 1:] = satellite_row(sim, force, torque)
        if k < steps:
            sim.step(force, torque, dt_s)
    return ["t_s", *satellite_columns(len(config.satellites))], rows
