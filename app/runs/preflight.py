"""Pre-flight: before the arms move, an ideal run predicts where each mockup will go, and a
run whose course leaves an arm's reach, its safety volume or its speed is refused.

The prediction is the scenario's ideal run (no arms: the ODS with exact contact, the
scripted pulses, the satellites' own actuation), over the run's duration. Each carried
satellite's predicted mockup centre (its COM, the arm's TCP) must stay

* inside the robot's safety box ([[robots]] safety_box_min_m / _max_m, in W);
* within :data:`app.sim.ur10e.HOLD_RADIUS_M` of the arm's shoulder (its reach; on a rail,
  of the segment the shoulder sweeps over the carriage's travel);
* with the arm's wrist (the origin of joint 5, from the mockup's pose and its mounting)
  at least :data:`MIN_WRIST_RADIUS_M` from the axis of its base joint (on a rail, for some
  carriage position that also keeps the reach): a UR's wrist cannot come within d4 of
  that axis (the shoulder singularity), and the arm, dragged near it, stops on its
  tracking error;
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

__all__ = ["DRIFT_SIGMAS", "INNER_RADIUS_M", "MAX_TCP_RATE_RADPS", "MAX_TCP_SPEED_MPS",
           "MIN_WRIST_RADIUS_M", "PredictionFailed", "PreflightRefused", "Violation",
           "check_course", "check_drift", "predict", "preflight", "wrist_axis_distance"]

INNER_RADIUS_M = DH_D_M[3]
"""The reach's inner limit: the UR10e's wrist point (the flange less d6 along the flange's
axis, where joints 5 and 6 meet) is never nearer than the shoulder offset d4 = 0.174 m to
the base joint's axis: the base joint's angle has no solution inside that cylinder, and on
its wall it is singular (the arm's shoulder singularity; the UR manuals ask to keep the
tool out of the cylinder above and below the base)."""

MAX_TCP_SPEED_MPS = 1.0
"""The UR10e's TCP speed limit (data sheet: 1 m/s)."""
MAX_TCP_RATE_RADPS = 3.0
"""Just under the wrist joints' 3.14 rad/s (data sheet): a faster spin cannot be followed."""
MIN_WRIST_RADIUS_M = INNER_RADIUS_M + 0.02
"""The least distance of the wrist from the base joint's axis a course may take it to:
d4 (:data:`INNER_RADIUS_M`) and 20 mm, within which joint 1 turns at
v / sqrt(r² − d4²) (1 rad/s for 0.08 m/s at 20 mm)."""
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
                 drift: dict[int, tuple] | None = None) -> list[Violation]:
    """Each robot's first violation of each limit along the predicted telemetry ``rows``
    (an ideal run's; columns ``index``), earliest first. ``drift``: per satellite
    (1-based), how far (m, per row) and how much faster (m/s) it may be from its
    predicted course, and its velocity's spread per axis of R with the time since the
    contact per row (:func:`check_drift`); each limit is then checked at its worst (on a
    rail, the carriage carries the drift along the rail within its travel)."""
    T_W_R = make_transform(quat_to_matrix(config.lab.r_attitude_wxyz), config.lab.r_origin_m)
    found = []
    for k, robot in enumerate(config.robots):
        s = config.satellite_index(robot.satellite) + 1
        found += _robot_violations(k, robot, s, rows, index, T_W_R,
                                   (drift or {}).get(s, (np.zeros(len(rows)), 0.0, None,
                                                          None)))
    return sorted(found, key=lambda v: v.t_s)


def _robot_violations(k: int, robot, s: int, rows: np.ndarray, index: dict,
                      T_W_R: np.ndarray, drift: tuple) -> list[Violation]:
    """Robot k's (0-based) first violation of each limit, carrying satellite s (1-based),
    its course widened by ``drift`` (m per row, m/s)."""
    off_m, off_mps, sd_R, since_s = drift
    p_W = rows[:, [index[f"sat{s}_{a}_m"] for a in "xyz"]] @ T_W_R[:3, :3].T + T_W_R[:3, 3]
    speed = np.linalg.norm(rows[:, [index[f"sat{s}_v{a}_mps"] for a in "xyz"]], axis=1)
    rate = np.linalg.norm(rows[:, [index[f"sat{s}_w{a}_radps"] for a in "xyz"]], axis=1)
    T_W_B = T_W_B_from_config(robot)
    shoulder_W = T_W_B[:3, :3] @ np.asarray(SHOULDER_B_M) + T_W_B[:3, 3]
    reach, whose = _reach(p_W, shoulder_W, robot.rail), "its shoulder"
    across_m = off_m  # how far the drift takes it from where the arm holds it
    if robot.rail is not None:
        whose = "its shoulder's line along the rail"
        if sd_R is not None:  # along the rail the carriage follows, within its travel
            axis_W = np.asarray(robot.rail.axis_W)
            sd = np.asarray(sd_R, dtype=float)
            along_sd = float(np.linalg.norm((T_W_R[:3, :3].T @ axis_W) * sd))
            across_sd = float(np.sqrt(max(float(sd @ sd) - along_sd**2, 0.0)))
            along_m = DRIFT_SIGMAS * along_sd * since_s
            across_m = DRIFT_SIGMAS * across_sd * since_s
            reach = np.maximum(*(_reach(p_W + sign * along_m[:, None] * axis_W, shoulder_W,
                                        robot.rail) for sign in (1.0, -1.0)))
    quat = rows[:, [index[f"sat{s}_q{a}"] for a in "wxyz"]]
    wrist = wrist_axis_distance(robot, T_W_R, p_W, quat)
    inside = (wrist - across_m < MIN_WRIST_RADIUS_M) & (reach <= HOLD_RADIUS_M)
    lo, hi = np.asarray(robot.safety_box_min_m), np.asarray(robot.safety_box_max_m)
    pm = (lambda j: f" ± {off_m[j]:.3f}") if off_m.any() else (lambda j: "")
    pm_across = (lambda j: f" ± {across_m[j]:.3f}") if across_m.any() else (lambda j: "")
    checks = [
        (np.any((p_W - off_m[:, None] < lo) | (p_W + off_m[:, None] > hi), axis=1),
         lambda j: f"leaves the safety volume (at {_fmt(p_W[j])}{pm(j)} m in W; box "
                   f"{_fmt(lo)} to {_fmt(hi)})"),
        (reach + across_m > HOLD_RADIUS_M,
         lambda j: f"leaves the arm's reach ({reach[j]:.3f}{pm_across(j)} m from {whose}; limit "
                   f"{HOLD_RADIUS_M:g} m)"),
        (inside,
         lambda j: f"leaves the arm's reach (its wrist {_closest(wrist - across_m, inside)}"
                   f"{' wherever the carriage stands' if robot.rail else ''}; inner limit "
                   f"{MIN_WRIST_RADIUS_M:.3f} m, the shoulder singular at "
                   f"{INNER_RADIUS_M:.3f} m)"),
        (speed + off_mps > MAX_TCP_SPEED_MPS,
         lambda j: f"moves faster than the arm's TCP ({speed[j] + off_mps:.3g} m/s; limit "
                   f"{MAX_TCP_SPEED_MPS:g} m/s)"),
        (rate > MAX_TCP_RATE_RADPS,
         lambda j: f"turns faster than the arm's wrist ({rate[j]:.3g} rad/s; limit "
                   f"{MAX_TCP_RATE_RADPS:g} rad/s)"),
    ]
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


def wrist_axis_distance(robot, T_W_R: np.ndarray, p_W: np.ndarray,
                        quat_wxyz: np.ndarray) -> np.ndarray:
    """Each pose's distance of the arm's wrist point from its base joint's axis when its
    mockup (the satellite's body frame) is at ``p_W`` (n, 3) with attitude ``quat_wxyz``
    (n, 4, in R): the flange is ``T_W_C · T_F_C⁻¹``, the wrist point the flange less d6
    along its axis (:data:`INNER_RADIUS_M`). On a rail, the largest such distance over
    the carriage positions within the travel that keep the TCP within the reach (the
    distance is convex in s: the largest is at an end of that interval)."""
    T_W_B = T_W_B_from_config(robot)
    R_B_W = T_W_B[:3, :3].T
    T_F_C = T_F_C_from_config(robot)
    R_C_F = T_F_C[:3, :3].T
    p_C_F = -R_C_F @ T_F_C[:3, 3]
    q = np.asarray(quat_wxyz, dtype=float)
    R_W_C = np.einsum("ab,nbc->nac", T_W_R[:3, :3], quat_to_matrix(q))
    z_F_W = R_W_C @ R_C_F[:, 2]
    wrist_W = p_W + R_W_C @ p_C_F - DH_D_M[5] * z_F_W
    u = (wrist_W - T_W_B[:3, 3]) @ R_B_W.T  # in B0 (the carriage at 0)
    rail = robot.rail
    if rail is None:
        return np.hypot(u[:, 0], u[:, 1])
    axis_W = np.asarray(rail.axis_W)
    b = R_B_W @ axis_W
    shoulder_W = T_W_B[:3, :3] @ np.asarray(SHOULDER_B_M) + T_W_B[:3, 3]
    rel = p_W - shoulder_W
    c = rel @ axis_W
    w = np.sqrt(np.maximum(HOLD_RADIUS_M**2 - (np.einsum("na,na->n", rel, rel) - c * c), 0.0))
    lo = np.clip(c - w, *rail.travel_m)
    hi = np.clip(c + w, *rail.travel_m)
    return np.maximum(*(np.hypot(u[:, 0] - s * b[0], u[:, 1] - s * b[1]) for s in (lo, hi)))


def _fmt(v) -> str:
    return "(" + ", ".join(f"{x:.3f}" for x in v) + ")"


def _closest(distance_m: np.ndarray, inside: np.ndarray) -> str:
    """How close the course takes the wrist to the base axis; a drift's widening can take
    it past the axis (a negative distance), which is said as a crossing."""
    closest = float(np.min(distance_m[inside]))
    if closest <= 0.0:
        return "could cross its base axis"
    return f"would come within {closest:.3f} m of its base axis"


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
        drift[int(name[3:])] = (rate * since_s, rate, np.asarray(sd, dtype=float), since_s)
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
