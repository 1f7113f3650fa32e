"""Did a scenario do what it is for? Its ``[success]`` criteria, measured on its telemetry.

Each criterion a scenario names is computed here and reported in metrics.json as
``success``: the figures, the limit, and ``passed``. Pure: telemetry rows and the config in,
a dict out.
"""

from __future__ import annotations

import math

import numpy as np

from app.config import EmulatorConfig
from app.sim.gnc import moving_point
from app.sim.orbital import orbit_rate
from app.sim.rotations import quat_mul, quat_to_matrix
from app.sim.scaling import ods_inertia_kgm2, scaling_of

__all__ = ["docking", "final_position", "no_contact", "gnc_satellite", "libration",
           "libration_period_theory_s", "pitch_rad", "recovery", "reference_track",
           "success_metrics", "synchronisation", "waypoints_flown"]


def success_metrics(config: EmulatorConfig, rows: np.ndarray, index: dict,
                    capture: dict | None = None, collision: dict | None = None,
                    ) -> dict | None:
    """The ``success`` block of metrics.json (None when the scenario names no criterion);
    ``capture``: the run's capture metrics, if it has a [capture]; ``collision``: its
    first contact's metrics (app/runs/metrics.py), None if the satellites never touched."""
    crit = config.success
    checks = {}
    if crit.no_contact:
        checks["no_contact"] = no_contact(config, collision)
    if crit.libration_period_error_max is not None:
        lib = libration(config, rows, index, satellite=0)
        lib["limit"] = crit.libration_period_error_max
        lib["passed"] = lib["period_error"] is not None and \
            abs(lib["period_error"]) <= crit.libration_period_error_max
        checks["libration"] = lib
    if crit.captured is not None or crit.residual_rate_max_radps is not None:
        checks["docking"] = docking(config, capture, crit)
    if crit.needs_gnc:
        checks.update(gnc_checks(config, rows, index))
    if not checks:
        return None
    return {"passed": all(c["passed"] for c in checks.values()), **checks}


def no_contact(config: EmulatorConfig, collision: dict | None) -> dict:
    """The satellites never touched; if they did, which pair (by name), when (lab s) and
    how hard (N, in the lab)."""
    if collision is None:
        return {"touched": False, "passed": True}
    names = [config.satellites[int(label.removeprefix("sat")) - 1].name
             for label in collision["pair"]]
    return {"touched": True, "pair": names, "at_s": collision["contact_start_s"],
            "peak_force_N": collision["peak_force_N"], "passed": False}


def docking(config: EmulatorConfig, capture: dict | None, crit) -> dict:
    """Captured as required, and the compound's residual rate within its limit."""
    capture = capture or {"captured": False}
    out = {"captured": capture["captured"], "required": crit.captured,
           "residual_rate_radps": capture.get("residual_rate_radps"),
           "residual_rate_max_radps": crit.residual_rate_max_radps}
    ok = crit.captured is None or capture["captured"] == crit.captured
    if crit.residual_rate_max_radps is not None:
        rate = capture.get("residual_rate_radps")
        ok = ok and rate is not None and rate <= crit.residual_rate_max_radps
    out["passed"] = bool(ok)
    return out


def gnc_checks(config: EmulatorConfig, rows: np.ndarray, index: dict) -> dict:
    """The GNC criteria the scenario names, about its first satellite with a GNC."""
    crit, sat = config.success, gnc_satellite(config)
    flown = waypoints_flown(config, rows, index, sat)
    checks = {}
    if crit.waypoints_reached:
        checks["waypoints"] = flown
    if crit.final_position_error_max_m is not None:
        checks["final_position"] = final_position(config, rows, index, sat,
                                                  crit.final_position_error_max_m)
    if crit.recovery_time_max_s is not None:
        checks["recovery"] = recovery(config, rows, index, sat, flown["reached_rows"],
                                      crit.recovery_time_max_s)
    if crit.needs_sync:
        checks["synchronisation"] = synchronisation(config, rows, index, sat,
                                                    flown["reached_rows"])
    flown.pop("reached_rows")
    return checks


def pitch_rad(q_wxyz: np.ndarray) -> np.ndarray:
    """The rotation about R's z (the orbit normal) of attitudes q_R_B (rows wxyz): the
    angle of the body's x axis from R's x (radial) in R's x-y plane."""
    w, x, y, z = q_wxyz.T
    r00 = 1.0 - 2.0 * (y * y + z * z)
    r10 = 2.0 * (x * y + w * z)
    return np.arctan2(r10, r00)


def _agm(a: float, b: float) -> float:
    while abs(a - b) > 1e-15 * a:
        a, b = 0.5 * (a + b), math.sqrt(a * b)
    return a


def libration_period_theory_s(orbit_rate_radps: float, inertia_kgm2, amplitude_rad: float,
                              ) -> float:
    """Pitch libration under the gravity gradient (Eq. 7 about the orbit normal):
    I_z θ̈ = -3/2 Ω² (I_y - I_x) sin 2θ, a pendulum in φ = 2θ of small-amplitude rate
    ω_p = Ω sqrt(3 (I_y - I_x) / I_z); its period at amplitude θ0 is 4 K(sin θ0) / ω_p
    (K: complete elliptic integral of the first kind, by the arithmetic-geometric mean)."""
    ix, iy, iz = inertia_kgm2
    if iy <= ix:
        return math.inf  # no restoring torque: it tumbles away
    w_p = orbit_rate_radps * math.sqrt(3.0 * (iy - ix) / iz)
    k = math.sin(abs(amplitude_rad))
    elliptic_k = math.pi / (2.0 * _agm(1.0, math.sqrt(1.0 - k * k)))
    return 4.0 * elliptic_k / w_p


def _crossings(t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Times where x crosses zero (linear interpolation)."""
    k = np.nonzero(np.signbit(x[:-1]) != np.signbit(x[1:]))[0]
    return t[k] - x[k] * (t[k + 1] - t[k]) / (x[k + 1] - x[k])


def libration(config: EmulatorConfig, rows: np.ndarray, index: dict, satellite: int) -> dict:
    """Satellite ``satellite``'s pitch libration in the ODS: its period from the zero
    crossings (two per period), in orbit seconds, against theory at the amplitude it was
    released at."""
    sc = scaling_of(config)
    pre = f"sat{satellite + 1}"
    t = rows[:, 0]
    pitch = pitch_rad(rows[:, [index[f"{pre}_q{a}"] for a in "wxyz"]])
    amplitude = float(abs(pitch[0])) if len(pitch) else 0.0
    omega_lab = sc.orbit_rate_lab(orbit_rate(config.orbit.altitude_m))
    theory_s = sc.time * libration_period_theory_s(
        omega_lab, ods_inertia_kgm2(config.satellites[satellite], sc), amplitude)
    crossings = _crossings(t, pitch)
    period_s = None
    if len(crossings) >= 3:  # at least a whole period between the first and the last
        period_s = sc.time * 2.0 * float(np.mean(np.diff(crossings)))
    error = None if period_s is None or not math.isfinite(theory_s) else \
        period_s / theory_s - 1.0
    return {"satellite": config.satellites[satellite].name,
            "amplitude_deg": math.degrees(amplitude),
            "periods_seen": max(0, (len(crossings) - 1) / 2),
            "period_s": period_s, "period_theory_s": theory_s, "period_error": error}


# --- a satellite's own GNC (app/sim/gnc.py): judged on the ODS state, in orbit units --------


def gnc_satellite(config: EmulatorConfig) -> int:
    """The first satellite with a ``[satellites.gnc]`` (0-based)."""
    return next(i for i, s in enumerate(config.satellites) if s.gnc is not None)


def orbit_track(config: EmulatorConfig, rows: np.ndarray, index: dict, satellite: int,
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(time, position in R, velocity in R) of a satellite's ODS state in orbit units:
    t = k_T t', x = k_L x', v = (k_L / k_T) v' (app/sim/scaling.py)."""
    sc, pre = scaling_of(config), f"sat{satellite + 1}"
    return (sc.time * rows[:, 0],
            sc.length * rows[:, [index[f"{pre}_{a}_m"] for a in "xyz"]],
            sc.velocity * rows[:, [index[f"{pre}_v{a}_mps"] for a in "xyz"]])


def attitude_track(config: EmulatorConfig, rows: np.ndarray, index: dict, satellite: int,
                   ) -> tuple[np.ndarray, np.ndarray]:
    """(q_R_B rows wxyz, angular velocity relative to R in body axes, orbit rad/s)."""
    pre = f"sat{satellite + 1}"
    return (rows[:, [index[f"{pre}_q{a}"] for a in "wxyz"]],
            rows[:, [index[f"{pre}_w{a}_radps"] for a in "xyz"]] / scaling_of(config).time)


def reference_track(config: EmulatorConfig, rows: np.ndarray, index: dict, satellite: int,
                    waypoint: int) -> tuple[np.ndarray, np.ndarray]:
    """(position, velocity) in R, orbit units, row by row, of what the satellite's GNC
    flies to for ``waypoint`` (app/sim/gnc.py reference): the waypoint itself, at rest,
    or, with ``relative_to``, the point of the target's body it names, moving with it."""
    gnc = config.satellites[satellite].gnc
    offset = np.asarray(gnc.waypoints[waypoint].position_m, dtype=float)
    if gnc.relative_to is None:
        return np.broadcast_to(offset, (len(rows), 3)), np.zeros((len(rows), 3))
    j = [s.name for s in config.satellites].index(gnc.relative_to)
    _, p_T, v_T = orbit_track(config, rows, index, j)
    q_T, w_T = attitude_track(config, rows, index, j)
    r, v, _ = moving_point(p_T, v_T, q_T, w_T, offset)
    return r, v


def _inside(gnc, ref: tuple[np.ndarray, np.ndarray], p: np.ndarray, v: np.ndarray,
            ) -> np.ndarray:
    """Rows within the GNC's tolerance of a waypoint's reference: |r − r_ref| <
    tolerance_m and |v − v_ref| < tolerance_mps (the guidance's own test, app/sim/gnc.py
    within_tolerance)."""
    r_ref, v_ref = ref
    return ((np.linalg.norm(p - r_ref, axis=1) < gnc.tolerance_m)
            & (np.linalg.norm(v - v_ref, axis=1) < gnc.tolerance_mps))


def _first_held(t: np.ndarray, inside: np.ndarray, start: int, hold_s: float) -> int | None:
    """The first row from ``start`` at which the satellite has been inside for hold_s
    without a break (the guidance's hold: a stretch begins at its first row inside)."""
    rows = np.flatnonzero(inside[start:]) + start
    if not len(rows):
        return None
    begins = rows[(rows == start) | ~inside[rows - 1]]
    since = begins[np.searchsorted(begins, rows, side="right") - 1]
    held = rows[t[rows] - t[since] >= hold_s]
    return int(held[0]) if len(held) else None


def waypoints_flown(config: EmulatorConfig, rows: np.ndarray, index: dict,
                    satellite: int) -> dict:
    """Which of its waypoints the satellite reached, in order, and when (orbit s): each
    the first time after the previous one it stayed within tolerance for its hold_s,
    judged on the recorded ODS state as the guidance judges it."""
    gnc = config.satellites[satellite].gnc
    t, p, v = orbit_track(config, rows, index, satellite)
    reached, start = [], 0
    for k, wp in enumerate(gnc.waypoints):
        ref = reference_track(config, rows, index, satellite, k)
        row = _first_held(t, _inside(gnc, ref, p, v), start, wp.hold_s)
        if row is None:
            break
        reached.append(row)
        start = row + 1
    return {"satellite": config.satellites[satellite].name, "count": len(gnc.waypoints),
            "reached": len(reached), "reached_at_s": [float(t[r]) for r in reached],
            "transfers": transfers(gnc, t, p, reached),
            "reached_rows": reached, "passed": len(reached) == len(gnc.waypoints)}


def transfers(gnc, t: np.ndarray, p: np.ndarray, reached: list[int]) -> list[dict]:
    """Each CW transfer leg flown (``transfer_s``): where it began (the previous waypoint
    reached, or the run's start), when it was due to arrive, and how far (orbit m) from
    its waypoint the satellite was then (before the braking and the PD's hold)."""
    out = []
    for k, wp in enumerate(gnc.waypoints):
        if wp.transfer_s is None or (k > 0 and len(reached) < k):
            continue
        start_s = float(t[reached[k - 1]]) if k > 0 else float(t[0])
        due_s = start_s + wp.transfer_s
        if not len(t) or due_s > t[-1]:
            continue
        row = int(np.argmin(np.abs(t - due_s)))
        out.append({"waypoint": k + 1, "start_s": start_s, "due_s": due_s,
                    "miss_m": float(np.linalg.norm(p[row] - np.asarray(wp.position_m)))})
    return out


def final_position(config: EmulatorConfig, rows: np.ndarray, index: dict, satellite: int,
                   limit_m: float) -> dict:
    """How far (orbit m) the satellite ends from its last waypoint."""
    _, p, _ = orbit_track(config, rows, index, satellite)
    last = len(config.satellites[satellite].gnc.waypoints) - 1
    r_ref, _ = reference_track(config, rows, index, satellite, last)
    error = float(np.linalg.norm(p[-1] - r_ref[-1])) if len(p) else None
    return {"satellite": config.satellites[satellite].name, "error_m": error,
            "limit_m": limit_m, "passed": error is not None and error <= limit_m}


def recovery(config: EmulatorConfig, rows: np.ndarray, index: dict, satellite: int,
             reached_rows: list[int], limit_s: float) -> dict:
    """The recovery from the last scripted pulse on the satellite: the waypoint it was
    flying to when the pulse began, how far the pulse put it off (orbit m), and how long
    (orbit s) from the pulse's end until it was within tolerance of that waypoint again
    (position and speed). No pulse (or none that ended within the run), or no return:
    not passed."""
    name, sc = config.satellites[satellite].name, scaling_of(config)
    out = {"satellite": name, "limit_s": limit_s, "pulse_end_s": None, "waypoint": None,
           "excursion_max_m": None, "recovery_time_s": None, "passed": False}
    pulses = [q for q in config.pulses if q.satellite == name]
    if not pulses or not len(rows):
        return out
    pulse = max(pulses, key=lambda q: q.end_s)
    gnc = config.satellites[satellite].gnc
    t, p, v = orbit_track(config, rows, index, satellite)
    t_lab = rows[:, 0]
    if t_lab[-1] < pulse.end_s:
        out["pulse_end_s"] = sc.time * pulse.end_s  # the run ended before the push did
        return out
    k = min(sum(1 for r in reached_rows if t_lab[r] < pulse.start_s), len(gnc.waypoints) - 1)
    ref = reference_track(config, rows, index, satellite, k)
    after = np.flatnonzero((t_lab >= pulse.end_s) & _inside(gnc, ref, p, v))
    end = int(after[0]) if len(after) else len(rows) - 1
    window = (t_lab >= pulse.start_s) & (np.arange(len(rows)) <= end)
    out.update(pulse_end_s=sc.time * pulse.end_s, waypoint=k + 1,
               excursion_max_m=float(np.max(np.linalg.norm(p[window] - ref[0][window], axis=1),
                                            initial=0.0)))
    if len(after):
        out["recovery_time_s"] = float(t[after[0]] - sc.time * pulse.end_s)
        out["passed"] = out["recovery_time_s"] <= limit_s
    return out


def synchronisation(config: EmulatorConfig, rows: np.ndarray, index: dict, satellite: int,
                    reached_rows: list[int]) -> dict:
    """How well a GNC flying relative to a target (``relative_to``) is synchronised with it
    at its capture point (its last waypoint): over the hold that reached it (the last
    ``hold_s`` before it counted as reached, orbit time), the largest and the final
    position error to the point that moves with the target, velocity error, attitude
    error to q_R_T ⊗ q_wp (the rotation angle between them) and rate error (relative to R,
    in R's axes). Not reached: not passed."""
    crit, gnc = config.success, config.satellites[satellite].gnc
    last = len(gnc.waypoints) - 1
    out = {"satellite": config.satellites[satellite].name, "target": gnc.relative_to,
           "waypoint": last + 1, "at_s": None,
           "position_limit_m": crit.synchronisation_position_error_max_m,
           "attitude_limit_rad": crit.synchronisation_attitude_error_max_rad,
           "passed": False}
    if len(reached_rows) < len(gnc.waypoints):
        return out
    t, p, v = orbit_track(config, rows, index, satellite)
    end = reached_rows[-1]
    hold = np.flatnonzero((t >= t[end] - gnc.waypoints[last].hold_s) & (t <= t[end]))
    r_ref, v_ref = reference_track(config, rows, index, satellite, last)
    j = [s.name for s in config.satellites].index(gnc.relative_to)
    q_T, w_T = attitude_track(config, rows[hold], index, j)
    q_B, w_B = attitude_track(config, rows[hold], index, satellite)
    q_ref = quat_mul(q_T, np.asarray(gnc.attitude_wxyz, dtype=float))
    q_e = quat_mul(q_ref * np.array([1.0, -1.0, -1.0, -1.0]), q_B)
    angle = 2.0 * np.arccos(np.clip(np.abs(q_e[:, 0]), 0.0, 1.0))
    rate = np.linalg.norm(np.einsum("kij,kj->ki", quat_to_matrix(q_B), w_B)
                          - np.einsum("kij,kj->ki", quat_to_matrix(q_T), w_T), axis=1)
    pos = np.linalg.norm(p[hold] - r_ref[hold], axis=1)
    vel = np.linalg.norm(v[hold] - v_ref[hold], axis=1)
    out.update(at_s=float(t[end]), hold_s=float(t[end] - t[hold[0]]),
               position_error_m=float(pos[-1]), position_error_max_m=float(pos.max()),
               velocity_error_mps=float(vel[-1]), velocity_error_max_mps=float(vel.max()),
               attitude_error_rad=float(angle[-1]), attitude_error_max_rad=float(angle.max()),
               rate_error_radps=float(rate[-1]), rate_error_max_radps=float(rate.max()))
    ok = True
    if crit.synchronisation_position_error_max_m is not None:
        ok = ok and out["position_error_max_m"] <= crit.synchronisation_position_error_max_m
    if crit.synchronisation_attitude_error_max_rad is not None:
        ok = ok and out["attitude_error_max_rad"] <= crit.synchronisation_attitude_error_max_rad
    out["passed"] = bool(ok)
    return out
