"""Pre-flight: before the arms move, an ideal run predicts where each mockup will go, and a
run whose course leaves an arm's reach, its safety volume or its speed is refused.

The prediction is the scenario's ideal run (no arms: the ODS with exact contact, the
scripted pulses, the satellites' own actuation), over the run's duration. Each carried
satellite's predicted mockup centre (its COM, the arm's TCP) must stay

* inside the robot's safety box ([[robots]] safety_box_min_m / _max_m, in W);
* within :data:`app.sim.ur10e.HOLD_RADIUS_M` of the arm's shoulder (its reach; on a rail,
  of the segment the shoulder sweeps over the carriage's travel);
* with the arm's wrist (the origin of joint 5, from the mockup's pose and its mounting)
  at least :data:`MIN_WRIST_RADIUS_M` from the axis of joint 1 (no rail): a UR's wrist
  cannot come within d4 of that axis (the shoulder singularity), and the arm, dragged
  there, stops on its tracking error;
* below :data:`MAX_TCP_SPEED_MPS` and :data:`MAX_TCP_RATE_RADPS` (what the arm can follow).

After a contact, the sensor's noise makes the hil satellites leave at a velocity the
ideal run does not have: with the pre-flight's forecast (app/runs/uncertainty.py), its
replicates' spread of the velocities after the contact, :func:`check_drift` checks the
same limits with each position widened, from the contact's end, by
:data:`DRIFT_SIGMAS` standard deviations of that velocity times the time since.

What an operator will do cannot be predicted: the web app's hand can still push a
satellite out, and the panel's course warning and the arm's own stops are there for that.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.config import ConfigError, EmulatorConfig, merge_overrides
from app.runs.metrics import contact_pair
from app.sim.loop import Emulator
from app.sim.rotations import make_transform, quat_to_matrix
from app.sim.ur10e import (
    DH_D_M,
    HOLD_RADIUS_M,
    SHOULDER_B_M,
    T_F_C_from_config,
    T_W_B_from_config,
)

__all__ = ["DRIFT_SIGMAS", "MAX_TCP_RATE_RADPS", "MAX_TCP_SPEED_MPS", "MIN_WRIST_RADIUS_M",
           "PredictionFailed", "PreflightRefused", "Violation", "check_course", "check_drift",
           "predict", "preflight", "wrist_radius_m"]

MAX_TCP_SPEED_MPS = 1.0
"""The UR10e's TCP speed limit (data sheet: 1 m/s)."""
MAX_TCP_RATE_RADPS = 3.0
"""Just under the wrist joints' 3.14 rad/s (data sheet): a faster spin cannot be followed."""
MIN_WRIST_RADIUS_M = DH_D_M[3] + 0.02
"""The least distance of the wrist (joint 5's origin) from joint 1's axis: d4 (0.174 m,
where the UR's shoulder is singular and its wrist can come no closer) and 20 mm, within
which joint 1 turns at v / sqrt(r² − d4²) (1 rad/s for 0.08 m/s at 20 mm)."""
DRIFT_SIGMAS = 3.0
"""How many standard deviations of the forecast's post-contact velocity the drift check
allows for (a hil run's satellites leave a contact at a velocity the noise scatters)."""
MIN_TELEMETRY_ROWS = 100
"""The least telemetry capacity a configuration takes ([loop] telemetry_capacity)."""
COARSE_RATE_HZ = 100.0
"""The prediction's rate where no contact can happen (one satellite) and every scripted
pulse starts and ends on its grid (so that it applies the same impulse): 5x fewer cycles."""


class PreflightRefused(ValueError):
    """The predicted course leaves what an arm can do; the message names each robot, the
    time and the limit."""


class PredictionFailed(PreflightRefused):
    """The prediction itself (the ideal run) raised: with no course to check, the run is
    refused all the same; the message gives the reason."""


@dataclass(frozen=True)
class Violation:
    """The first moment a robot's satellite breaks one limit on its predicted course."""

    robot: int  # 1-based
    robot_name: str
    satellite: str
    t_s: float
    limit: str

    def __str__(self) -> str:
        return (f"robot {self.robot} ({self.robot_name}): satellite {self.satellite!r} "
                f"{self.limit} at t = {self.t_s:.2f} s")


def predict(config: EmulatorConfig, duration_s: float) -> Emulator:
    """The ideal run of ``config`` over ``duration_s`` (its telemetry: the course). With
    one satellite (no contact) and pulses on its grid at a coarser rate, for speed (a
    pulse between its samples would be missed)."""
    coarse = (len(config.satellites) == 1 and config.loop.rate_hz > COARSE_RATE_HZ
              and all(_on_grid(t, COARSE_RATE_HZ) for p in config.pulses
                      for t in (p.start_s, p.end_s)))
    predicted = None
    for rate in ([COARSE_RATE_HZ] if coarse else []) + [config.loop.rate_hz]:
        loop = {"rate_hz": rate,
                "telemetry_capacity": max(int(duration_s * rate) + 3, MIN_TELEMETRY_ROWS)}
        try:
            predicted = merge_overrides(config, {"loop": loop})
            break
        except ConfigError:  # too coarse for this configuration (e.g. its time scale)
            continue
    if predicted is None:
        predicted = merge_overrides(config, {"loop": loop})  # (raises, naming the field)
    em = Emulator(predicted, mode="ideal")
    em.run(duration_s)
    return em


def _on_grid(t_s: float, rate_hz: float) -> bool:
    """Whether t_s is a whole number of cycles at rate_hz (to a millionth of a cycle)."""
    cycles = t_s * rate_hz
    return abs(cycles - round(cycles)) < 1e-6


def check_course(config: EmulatorConfig, rows: np.ndarray, index: dict,
                 drift: dict[int, tuple[np.ndarray, float]] | None = None) -> list[Violation]:
    """Each robot's first violation of each limit along the predicted telemetry ``rows``
    (an ideal run's; columns ``index``), earliest first. ``drift``: per satellite
    (1-based), how far (m, per row) and how much faster (m/s) it may be from its
    predicted course (:func:`check_drift`); each limit is then checked at its worst."""
    T_W_R = make_transform(quat_to_matrix(config.lab.r_attitude_wxyz), config.lab.r_origin_m)
    found = []
    for k, robot in enumerate(config.robots):
        s = config.satellite_index(robot.satellite) + 1
        found += _robot_violations(k, robot, s, rows, index, T_W_R,
                                   (drift or {}).get(s, (np.zeros(len(rows)), 0.0)))
    return sorted(found, key=lambda v: v.t_s)


def wrist_radius_m(robot, s: int, rows: np.ndarray, index: dict,
                   T_W_R: np.ndarray) -> np.ndarray:
    """Per row, the distance of robot's wrist (joint 5's origin: the flange less d6 along
    its axis) from joint 1's axis, with the mockup of satellite s (1-based) at its
    predicted pose (T_W_R · T_R_C) and the flange at T_W_C · T_F_C⁻¹."""
    T_B_R = np.linalg.inv(T_W_B_from_config(robot)) @ T_W_R
    T_C_F = np.linalg.inv(T_F_C_from_config(robot))
    p_R = rows[:, [index[f"sat{s}_{a}_m"] for a in "xyz"]]
    R_R_C = _quat_matrices(rows[:, [index[f"sat{s}_q{a}"] for a in "wxyz"]])
    R_B_C = np.einsum("ij,njk->nik", T_B_R[:3, :3], R_R_C)
    p_B_C = p_R @ T_B_R[:3, :3].T + T_B_R[:3, 3]
    p_B_F = p_B_C + R_B_C @ T_C_F[:3, 3]
    z_B_F = R_B_C @ T_C_F[:3, 2]
    wrist = p_B_F - DH_D_M[5] * z_B_F
    return np.hypot(wrist[:, 0], wrist[:, 1])


def _quat_matrices(q: np.ndarray) -> np.ndarray:
    """(n, 4) unit quaternions (w, x, y, z) → (n, 3, 3) rotation matrices."""
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], axis=1)


def _robot_violations(k: int, robot, s: int, rows: np.ndarray, index: dict,
                      T_W_R: np.ndarray, drift: tuple[np.ndarray, float]) -> list[Violation]:
    """Robot k's (0-based) first violation of each limit, carrying satellite s (1-based),
    its course widened by ``drift`` (m per row, m/s)."""
    off_m, off_mps = drift
    p_W = rows[:, [index[f"sat{s}_{a}_m"] for a in "xyz"]] @ T_W_R[:3, :3].T + T_W_R[:3, 3]
    speed = np.linalg.norm(rows[:, [index[f"sat{s}_v{a}_mps"] for a in "xyz"]], axis=1)
    rate = np.linalg.norm(rows[:, [index[f"sat{s}_w{a}_radps"] for a in "xyz"]], axis=1)
    T_W_B = T_W_B_from_config(robot)
    shoulder_W = T_W_B[:3, :3] @ np.asarray(SHOULDER_B_M) + T_W_B[:3, 3]
    reach, whose = _reach(p_W, shoulder_W, robot.rail), "its shoulder"
    if robot.rail is not None:
        whose = "its shoulder's line along the rail"
    lo, hi = np.asarray(robot.safety_box_min_m), np.asarray(robot.safety_box_max_m)
    pm = (lambda j: f" ± {off_m[j]:.3f}") if off_m.any() else (lambda j: "")
    checks = [
        (np.any((p_W - off_m[:, None] < lo) | (p_W + off_m[:, None] > hi), axis=1),
         lambda j: f"leaves the safety volume (at {_fmt(p_W[j])}{pm(j)} m in W; box "
                   f"{_fmt(lo)} to {_fmt(hi)})"),
        (reach + off_m > HOLD_RADIUS_M,
         lambda j: f"leaves the arm's reach ({reach[j]:.3f}{pm(j)} m from {whose}; limit "
                   f"{HOLD_RADIUS_M:g} m)"),
        (speed + off_mps > MAX_TCP_SPEED_MPS,
         lambda j: f"moves faster than the arm's TCP ({speed[j] + off_mps:.3g} m/s; limit "
                   f"{MAX_TCP_SPEED_MPS:g} m/s)"),
        (rate > MAX_TCP_RATE_RADPS,
         lambda j: f"turns faster than the arm's wrist ({rate[j]:.3g} rad/s; limit "
                   f"{MAX_TCP_RATE_RADPS:g} rad/s)"),
    ]
    if robot.rail is None:  # (on a rail, the carriage moves the axis along)
        wrist = wrist_radius_m(robot, s, rows, index, T_W_R)
        checks.append((wrist - off_m < MIN_WRIST_RADIUS_M,
                       lambda j: f"takes the arm's wrist to {wrist[j]:.3f}{pm(j)} m from its "
                                 f"base axis (limit {MIN_WRIST_RADIUS_M:.3f} m: the shoulder "
                                 f"is singular at {DH_D_M[3]:g} m)"))
    found = []
    for bad, describe in checks:
        if bad.any():
            j = int(np.argmax(bad))
            found.append(Violation(k + 1, robot.name, robot.satellite, float(rows[j, 0]),
                                   describe(j)))
    return found


def _reach(p_W: np.ndarray, shoulder_W: np.ndarray, rail) -> np.ndarray:
    """Each point's distance from the shoulder, or with a rail from the segment the shoulder
    sweeps over the carriage's travel (base_position_m is the base at s = 0)."""
    if rail is None:
        return np.linalg.norm(p_W - shoulder_W, axis=1)
    axis = np.asarray(rail.axis_W)
    s = np.clip((p_W - shoulder_W) @ axis, *rail.travel_m)
    return np.linalg.norm(p_W - shoulder_W - s[:, None] * axis, axis=1)


def _fmt(v) -> str:
    return "(" + ", ".join(f"{x:.3f}" for x in v) + ")"


def preflight(config: EmulatorConfig, duration_s: float) -> Emulator | None:
    """Refuse (PreflightRefused) a hil run of ``config`` whose predicted course breaks a
    limit, or whose prediction raises (PredictionFailed); else the prediction (its ideal
    run; None with no robots: nothing to check)."""
    if not config.robots:
        return None
    try:
        em = predict(config, duration_s)
    except Exception as err:  # noqa: BLE001 - whatever it is, the arms must not move
        reason = str(err) if isinstance(err, ValueError) else f"{type(err).__name__}: {err}"
        raise PredictionFailed(f"pre-flight: the ideal run failed: {reason}") from err
    rows, index = em.telemetry.rows(), em.telemetry.index
    violations = check_course(config, rows, index)
    if violations:
        raise PreflightRefused(
            "pre-flight: the ideal run predicts that "
            + "; ".join(str(v) for v in violations)
            + _contact_note(config, rows, index, violations[0].t_s)
            + ". The arms have not moved; change the scenario (or run it --mode ideal)")
    return em


def check_drift(config: EmulatorConfig, prediction: Emulator, reference: dict) -> None:
    """Refuse (PreflightRefused) a hil run whose predicted course, widened after the
    contact by the noise's drift, breaks a limit. The drift of each satellite of the
    pair: ``DRIFT_SIGMAS`` × the forecast's post-contact velocity spread (the norm of its
    per-axis standard deviations, ``collision_forecast.velocity_sd_mps``) × the time since
    the ideal contact's end; nothing without a forecast of it."""
    fc = reference.get("forecast") or {}
    spread = fc.get("velocity_sd_mps")
    if not spread:
        return
    rows, index = prediction.telemetry.rows(), prediction.telemetry.index
    since_s = np.clip(rows[:, 0] - reference["contact_end_s"], 0.0, None)
    drift, rates = {}, []
    for name, sd in spread.items():
        rate = DRIFT_SIGMAS * float(np.linalg.norm(sd))
        drift[int(name[3:])] = (rate * since_s, rate)
        rates.append(rate)
    found = check_course(config, rows, index, drift)
    if found:
        last_ok = max(0.0, np.floor(10.0 * found[0].t_s - 1e-9) / 10.0)
        raise PreflightRefused(
            f"pre-flight: after the contact (t = {reference['contact_end_s']:.2f} s) the "
            f"sensor's noise scatters the satellites' velocities (the forecast: "
            f"{DRIFT_SIGMAS:g} sd = {max(rates):.3g} m/s); with that drift, "
            + "; ".join(str(v) for v in found)
            + f". The arms have not moved; shorten the run (loop.duration_s = {last_ok:g} "
              f"keeps it within every limit) or change the scenario")


def _contact_note(config: EmulatorConfig, rows: np.ndarray, index: dict,
                  first_violation_s: float) -> str:
    """Where the predicted course has two satellites touch before its first violation,
    which may be what threw them off: which, when and how hard ('' if none touch
    before it)."""
    pair = contact_pair(rows, index, len(config.satellites)) if len(rows) else None
    if pair is None:
        return ""
    force = np.stack([np.linalg.norm(rows[:, [index[f"sat{s}_true_f{a}_N"] for a in "xyz"]],
                                     axis=1) for s in pair], axis=1).min(axis=1)
    first = int(np.argmax(force > 0.0))
    if rows[first, 0] > first_violation_s:
        return ""
    a, b = (config.satellites[s - 1].name for s in pair)
    return (f"; and before any of that, at t = {rows[first, 0]:.2f} s, the mockups of "
            f"{a!r} and {b!r} touch (up to {force.max():.3g} N)")
