"""Fidelity metrics of a run (DESIGN.md "Fidelity"), computed from its telemetry."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from app.config import EmulatorConfig
from app.runs.rendering import (
    RENDERING_FIELDS,
    contact_geometry,
    rendering_error,
    rendering_warning,
)
from app.runs.success import success_metrics
from app.sim.compensation import force_lag_s
from app.sim.loop import Emulator
from app.sim.scaling import describe as describe_scaling
from app.sim.scaling import describe_body, scaling_of


def _cols(rows: np.ndarray, index: dict, prefix: str, names) -> np.ndarray:
    return rows[:, [index[f"{prefix}_{n}"] for n in names]]


def tracking_errors(rows: np.ndarray, index: dict, sat: int, rob: int) -> dict:
    """Isochronous error between the actual mockup (robot FK) and its ODS satellite."""
    s, r = f"sat{sat}", f"rob{rob}"
    dp = np.linalg.norm(
        _cols(rows, index, r, ("x_m", "y_m", "z_m")) - _cols(rows, index, s, ("x_m", "y_m", "z_m")),
        axis=1,
    )
    dv = np.linalg.norm(
        _cols(rows, index, r, ("vx_mps", "vy_mps", "vz_mps"))
        - _cols(rows, index, s, ("vx_mps", "vy_mps", "vz_mps")),
        axis=1,
    )
    dots = np.abs(
        np.sum(
            _cols(rows, index, r, ("qw", "qx", "qy", "qz"))
            * _cols(rows, index, s, ("qw", "qx", "qy", "qz")),
            axis=1,
        )
    )
    angle = 2.0 * np.arccos(np.clip(dots, 0.0, 1.0))
    return {
        "position_error_max_m": float(dp.max()),
        "position_error_rms_m": float(np.sqrt(np.mean(dp**2))),
        "velocity_error_rms_mps": float(np.sqrt(np.mean(dv**2))),
        "attitude_error_max_rad": float(angle.max()),
    }


def contact_pair(rows: np.ndarray, index: dict, n_sat: int) -> tuple[int, int] | None:
    """The two satellites (1-based) of the run's first contact: at the first row where two
    or more satellites feel a true external force, the two that feel the largest (a hand's
    push on one satellite alone is no contact). None if no such row."""
    forces = np.stack([np.linalg.norm(
        _cols(rows, index, f"sat{s}", ("true_fx_N", "true_fy_N", "true_fz_N")), axis=1)
        for s in range(1, n_sat + 1)], axis=1)
    shared = np.nonzero(np.count_nonzero(forces, axis=1) >= 2)[0]
    if not len(shared):
        return None
    a, b = sorted(int(i) + 1 for i in np.argsort(forces[shared[0]])[-2:])
    return a, b


def collision_metrics(rows: np.ndarray, index: dict, dt_s: float, a: int = 1, b: int = 2,
                      bodies: dict[int, str] | None = None):
    """Impulses the ODS received, their balance, and the coefficient of restitution of the
    first contact between satellites a and b (1-based).

    The contact lasts from the first touch (both bodies feel a true force) until the true
    force has been zero for 50 ms; the window adds 50 ms on either side for the loop's lag
    (what the ODS receives comes filtered and delayed), and the impulses are the ODS's
    received force integrated over it. The window closes whatever the ODS keeps receiving
    (e.g. noise through a zero deadband). Restitution
    e = -(v_b - v_a)_after . n / (v_b - v_a)_before . n, with n the line of centres at
    first contact, "before" at the window's start (50 ms before the first touch: the
    undisturbed approach, before a contact gate lets noise through) and "after" 20 ms
    past the window. None, with a warning, if the run
    ended before (``contact_open_at_end``) or the satellites were not moving apart then;
    a later touch is named too (the figures cover the first contact only).

    What the bodies themselves went through (DESIGN.md "Fidelity"), from the true external
    force on each actual mockup: ``true_impulse_Ns``, ``peak_force_N``,
    ``contact_duration_s`` (while the true force acts) and ``contact_energy_J``, the energy
    the contact absorbed, −Σ dt F_b · (v_b − v_a) with the bodies' own COM velocities:
    ``bodies`` names, per satellite, the telemetry prefix of its actual body ("rob2" for a
    mockup on arm 2; default: the satellite itself, as in an ideal run).
    """
    true = {s_: _cols(rows, index, f"sat{s_}", ("true_fx_N", "true_fy_N", "true_fz_N"))
            for s_ in (a, b)}
    applied = {
        s: _cols(rows, index, f"sat{s}", ("fx_N", "fy_N", "fz_N")) for s in (a, b)
    }
    touching = (np.linalg.norm(true[a], axis=1) > 0) & (np.linalg.norm(true[b], axis=1) > 0)
    if not touching.any():
        return None
    first = int(np.argmax(touching))
    # the contact: from the first touch until the bodies have been apart for `quiet`
    quiet = int(round(0.05 / dt_s))
    last, ended = first, False
    for k in range(first, len(rows)):
        if touching[k]:
            last = k
        elif k - last > quiet:
            ended = True
            break
    # the window adds `quiet` on both sides, for the loop's lag (filtered, delayed force)
    window = slice(max(0, first - quiet), min(len(rows), last + quiet + 1))
    impulse = {s_: applied[s_][window].sum(axis=0) * dt_s for s_ in (a, b)}
    ja, jb = impulse[a], impulse[b]
    normal = _contact_normal(true[b][window].sum(axis=0) * dt_s, rows, index, a, b, first)
    biggest = max(np.linalg.norm(ja), np.linalg.norm(jb))
    balance = float(np.linalg.norm(ja + jb) / biggest) if biggest > 0 else None
    warnings = []
    restitution, before_rel = _restitution(rows, index, a, b, first, window,
                                           int(round(0.02 / dt_s)), dt_s, ended, warnings)
    if biggest == 0.0:
        warnings.append("the ODS received no force over the contact window: the satellites "
                        "never felt this contact (a deadband or a sensor that did not see it)")
    others = _other_bodies_touching(rows, index, (a, b), window)
    if others:
        warnings.append(
            f"{', '.join(others)} also felt a force during this contact: the true force "
            f"columns are each satellite's total, so the pair's impulses, balance and energy "
            f"include the third body's")
    touches = _touches(touching[first:last + 1]) + first
    if len(touches) > 1:
        gaps_ms = 1e3 * dt_s * (touches[1:, 0] - touches[:-1, 1])
        warnings.append(
            f"the bodies touched {len(touches)} times within this contact (apart for "
            f"{gaps_ms.max():.0f} ms at most, under the {1e3 * quiet * dt_s:.0f} ms that "
            f"end a contact): chatter or a re-touch; contact_duration_s spans them all, "
            f"the first touch alone lasted {1e3 * dt_s * (touches[0, 1] - touches[0, 0]):.0f} ms")
    again = np.nonzero(touching[window.stop:])[0]
    if len(again):
        warnings.append(f"the bodies touched again at t = {rows[window.stop + again[0], 0]:.3f}"
                        " s: the collision metrics cover the first contact only")
    if not ended:
        apart = ("" if touching[-1] else
                 f" (the bodies parted at t = {rows[last + 1, 0]:.3f} s, less than the "
                 f"{1e3 * quiet * dt_s:.0f} ms that end a contact before the stop)")
        warnings.append(f"the contact had not ended when the run stopped at t = "
                        f"{rows[-1, 0]:.3f} s{apart}: its impulse is incomplete, no "
                        f"restitution")
    bodies = bodies or {}
    body_v = {s_: _cols(rows, index, bodies.get(s_, f"sat{s_}"), ("vx_mps", "vy_mps", "vz_mps"))
              for s_ in (a, b)}
    touch = np.nonzero(touching[window])[0] + window.start
    # row k: the state at t_k and the force over [t_k, t_k+1): velocities at mid-cycle
    k0, k1 = window.start, min(window.stop, len(rows) - 1)
    v_rel = body_v[b] - body_v[a]
    v_mid = 0.5 * (v_rel[k0:k1] + v_rel[k0 + 1:k1 + 1])
    energy = -float(np.sum(np.einsum("ij,ij->i", true[b][k0:k1], v_mid)) * dt_s)
    if restitution is not None and restitution > 1.0:
        warnings.append(
            f"restitution {restitution:.3f} > 1: the satellites left faster than they came, "
            f"which a dissipative contact cannot do (the contact itself absorbed "
            f"{1e3 * energy:.2f} mJ): the emulation put energy into the collision")
    return {
        "pair": [f"sat{a}", f"sat{b}"],
        "impulse_Ns": {f"sat{a}": ja.tolist(), f"sat{b}": jb.tolist()},
        "impulse_balance": balance,
        "normal": normal.tolist(),
        "off_normal_ratio": {f"sat{s_}": _off_normal(impulse[s_], normal) for s_ in (a, b)},
        "true_impulse_Ns": {f"sat{s_}": (true[s_][window].sum(axis=0) * dt_s).tolist()
                            for s_ in (a, b)},
        "peak_force_N": float(np.linalg.norm(true[a][window], axis=1).max()),
        "contact_duration_s": float((touch[-1] - touch[0] + 1) * dt_s),
        "touches": len(touches),
        "dt_s": dt_s,
        "contact_energy_J": energy,
        "restitution": restitution,
        "approach_speed_mps": -before_rel,
        "contact_start_s": float(rows[first, 0]),
        "contact_end_s": float(rows[last, 0]),
        "contact_open_at_end": not ended,
        "window_s": [float(rows[window.start, 0]), float(rows[window.stop - 1, 0])],
        "warnings": warnings,
    }


def _contact_normal(true_impulse_b: np.ndarray, rows: np.ndarray, index: dict, a: int,
                    b: int, k: int) -> np.ndarray:
    """(3,) R axes: the direction of the impulse the bodies exchanged (on b), the
    contact's normal for a frictionless contact (with friction, the true impulse's own
    direction: what the ODS's should follow); without one, the line of centres at row k.
    (The line of centres is off a face's normal by the satellites' drift: 0.8 % in the
    collision scenario.)"""
    norm = float(np.linalg.norm(true_impulse_b))
    if norm > 0.0:
        return true_impulse_b / norm
    pos = {s: _cols(rows[k:k + 1], index, f"sat{s}", ("x_m", "y_m", "z_m"))[0] for s in (a, b)}
    n = pos[b] - pos[a]
    return n / np.linalg.norm(n)


def _off_normal(impulse: np.ndarray, normal: np.ndarray) -> float | None:
    """|impulse across the normal| / |impulse along it| (None without an impulse along)."""
    along = float(impulse @ normal)
    across = float(np.linalg.norm(impulse - along * normal))
    return across / abs(along) if along != 0.0 else None


def _restitution(rows: np.ndarray, index: dict, a: int, b: int, first: int, window: slice,
                 wait: int, dt_s: float, ended: bool, warnings: list[str],
                 ) -> tuple[float | None, float]:
    """(e, the relative normal velocity before the contact m/s): see collision_metrics.
    The velocities before are read at the window's start, those after `wait` rows past
    its end."""
    end = window.stop - 1
    after = end + wait
    pos = {s: _cols(rows, index, f"sat{s}", ("x_m", "y_m", "z_m")) for s in (a, b)}
    vel = {s: _cols(rows, index, f"sat{s}", ("vx_mps", "vy_mps", "vz_mps")) for s in (a, b)}
    n = pos[b][first] - pos[a][first]
    n /= np.linalg.norm(n)
    before = window.start
    before_rel = float((vel[b][before] - vel[a][before]) @ n)
    if before_rel >= 0.0:
        warnings.append(f"the satellites were not closing in before the first touch "
                        f"(relative normal velocity {1e3 * before_rel:+.1f} mm/s at t = "
                        f"{rows[before, 0]:.3f} s): no restitution")
        return None, before_rel
    if not ended:
        return None, before_rel  # collision_metrics says so
    if after >= len(rows):
        warnings.append(f"the run stopped at t = {rows[-1, 0]:.3f} s, before the velocities "
                        f"after the contact could be read (t = "
                        f"{rows[end, 0] + wait * dt_s:.3f} s, {1e3 * wait * dt_s:.0f} ms past the "
                        f"contact window): no restitution")
        return None, before_rel
    after_rel = float((vel[b][after] - vel[a][after]) @ n)
    if after_rel <= 0.0:
        warnings.append(f"the satellites were not moving apart after the contact (relative "
                        f"normal velocity {1e3 * after_rel:+.1f} mm/s at t = "
                        f"{rows[after, 0]:.3f} s): no restitution")
        return None, before_rel
    return -after_rel / before_rel, before_rel


def _other_bodies_touching(rows: np.ndarray, index: dict, pair: tuple[int, int],
                           window: slice) -> list[str]:
    """The satellites beside the pair that feel a true external force in the window."""
    names = []
    s = 1
    while f"sat{s}_true_fx_N" in index:
        if s not in pair:
            f = _cols(rows[window], index, f"sat{s}", ("true_fx_N", "true_fy_N", "true_fz_N"))
            if np.any(f != 0.0):
                names.append(f"sat{s}")
        s += 1
    return names


def _touches(touching: np.ndarray) -> np.ndarray:
    """The runs of True in a boolean array: (n, 2) [start, stop) indices."""
    edges = np.diff(np.concatenate([[0], touching.astype(np.int8), [0]]))
    return np.stack([np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0]], axis=1)


MIN_CONTACT_CYCLES = 6
"""An ideal contact shorter than this many loop cycles is sampled too coarsely (peak,
duration) and its reference is not converged (rigid at 100 Hz: e 0.57 against 0.95)."""


def compare_with_ideal(coll: dict, ideal: dict | None, deadband_N: float) -> None:
    """Add the comparison with the converged ideal run (in place): ``restitution_ideal``,
    ``restitution_error`` (e − e_ideal) / e_ideal, ``true_impulse_ratio`` |J_true| /
    |J_true,ideal| per satellite (None while either contact was still open at the end),
    and more ``warnings``. ideal: the ideal run's collision metrics; None: not compared.

    deadband_N: the F/T force deadband the contact meets (0 where the contact gate lifts
    it, or without a sensor). How far one run's restitution can be trusted is its
    interval (``restitution_sd``, ``restitution_interval_95``: app/runs/uncertainty.py).
    """
    ideal = ideal or None  # {}: the ideal run had no contact
    coll["restitution_ideal"] = None if ideal is None else ideal["restitution"]
    e, ei = coll["restitution"], coll["restitution_ideal"]
    coll["restitution_error"] = (e - ei) / ei if e is not None and ei else None
    coll["true_impulse_ratio"] = None
    warnings = list(coll.get("warnings", []))
    if ideal is not None:
        if ei is None:
            warnings.append("the ideal run gives no restitution to compare with ("
                            + "; ".join(ideal.get("warnings", [])) + ")")
        cycles = ideal["contact_duration_s"] / ideal["dt_s"]
        if cycles < MIN_CONTACT_CYCLES:
            warnings.append(
                f"the ideal contact lasts {cycles:.1f} cycles at this rate: its peak force "
                f"and duration are sampled once per cycle, and the reference is not "
                f"converged; raise loop.rate_hz")
        if not (coll.get("contact_open_at_end") or ideal.get("contact_open_at_end")):
            coll["true_impulse_ratio"] = {
                name: float(np.linalg.norm(j) / np.linalg.norm(ideal["true_impulse_Ns"][name]))
                for name, j in coll["true_impulse_Ns"].items()
                if name in ideal["true_impulse_Ns"]
            }
        if ideal["peak_force_N"] < deadband_N:
            warnings.append(
                f"the ideal contact peaks at {ideal['peak_force_N']:.1f} N, under the F/T "
                f"force deadband of {deadband_N:g} N: the sensor cannot see it whole")
    coll["warnings"] = warnings


OFF_NORMAL_QUANTILE = 2.45
"""√(−2 ln 0.05): the 95 % quantile of the magnitude of a 2-D Gaussian vector (Rayleigh) in
units of its per-axis standard deviation."""


def _off_normal_warnings(coll: dict, noise: tuple[float, float] | None) -> list[str]:
    """A satellite whose impulse across the contact's normal (the true impulse's
    direction) exceeds what the sensor noise explains: the noise's impulse over the
    contact window, σ·sqrt(T·dt) per axis, its 95 % magnitude across the normal
    (OFF_NORMAL_QUANTILE), plus 1 % (ideal and noiseless runs)."""
    out = []
    window_s = coll["window_s"][1] - coll["window_s"][0] + coll["dt_s"]
    for name, ratio in coll.get("off_normal_ratio", {}).items():
        if ratio is None:
            continue
        j = np.asarray(coll["impulse_Ns"][name])
        along = abs(float(j @ np.asarray(coll["normal"])))
        explained = 0.01
        if noise is not None and noise[0] > 0:
            explained += OFF_NORMAL_QUANTILE * noise[0] * np.sqrt(window_s * noise[1]) / along
        if ratio > explained:
            out.append(f"{name} received {100 * ratio:.0f} % of its normal impulse across "
                       f"the contact's normal, more than the sensor's noise explains"
                       f" ({100 * explained:.0f} %): the satellites leave off the "
                       f"collision's line")
    return out


def passivity_metrics(em: Emulator) -> dict | None:
    """Energy each arm's passivity controller removed (None when it is off)."""
    removed = em.coupling.dissipated_J()
    if removed is None:
        return None
    return {"dissipated_J": {
        "force": removed["force"],
        "torque": {f"sat{s + 1}": e for s, e in removed["torque"].items()}}}


@dataclass(frozen=True)
class RunFacts:
    """What the metrics need of a run beyond its telemetry and configuration: what the loop
    knows (a headless Emulator, or the loop process's published state)."""

    mode: str
    status: str
    cycles: int
    wall_s: float
    cycle_time_us: dict
    """{"p50", "p99"} (µs; None without cycles)."""
    safety_stop: dict | None
    passivity: dict | None
    arm_of: dict[int, int]
    """Satellite (0-based) → the arm (0-based) that carries it."""
    capture: dict | None = None
    """The docking capture (Emulator.capture_event), if one happened."""
    error: str | None = None
    """Why the run failed (status "error"); None otherwise."""


def run_facts(em: Emulator, wall_s: float, error: str | None = None) -> RunFacts:
    """The facts of an Emulator that ran (its cycle times over the whole run); error: why
    it failed, if it did."""
    ct = np.array(em.cycle_time_ns, dtype=float) / 1e3
    return RunFacts(
        mode=em.mode, status=em.status, cycles=em.cycles, wall_s=wall_s,
        cycle_time_us={"p50": float(np.percentile(ct, 50)) if len(ct) else None,
                       "p99": float(np.percentile(ct, 99)) if len(ct) else None},
        safety_stop=em.safety_stop, passivity=passivity_metrics(em),
        arm_of={arm.satellite: arm.index for arm in em.arms}, capture=em.capture_event,
        error=error)


def sensing_limits(em: Emulator) -> float:
    """The F/T force deadband a contact of a run meets, for compare_with_ideal: 0 where
    the contact gate lifts it, or without arms (an ideal run has no sensor)."""
    return _contact_deadband(em.config, bool(em.arms))


def _sensor_noise(cfg: EmulatorConfig, with_arms: bool) -> tuple[float, float] | None:
    """(σ per sample, N; the time between samples, s) of the F/T noise a contact meets;
    None without arms (an ideal run has no sensor)."""
    if not with_arms:
        return None
    # a sensor slower than the loop repeats each sample: its noise adds up per sample
    sample_hz = min(cfg.loop.rate_hz, cfg.sensor.sample_rate_hz or math.inf)
    return cfg.sensor.noise_force_N, 1.0 / sample_hz


def _contact_deadband(cfg: EmulatorConfig, with_arms: bool) -> float:
    if not with_arms or cfg.wrench.contact_gate:
        return 0.0
    return cfg.wrench.deadband_force_N


def compute_metrics(em: Emulator, wall_s: float, ideal_collision: dict | None = None,
                    error: str | None = None) -> dict:
    """The metrics.json of a run (the emulator after it ran; wall_s its wall-clock time;
    error: why it failed, if it did)."""
    return metrics_of(em.config, em.telemetry.rows(), em.telemetry.index,
                      run_facts(em, wall_s, error), ideal_collision)


def metrics_of(config: EmulatorConfig, rows: np.ndarray, index: dict, facts: RunFacts,
               ideal_collision: dict | None = None) -> dict:
    """The metrics.json of a run from its telemetry rows (oldest first), its
    configuration and the facts the loop kept."""
    sim_s = float(rows[-1, 0]) if len(rows) else 0.0
    n_sat = len(config.satellites)
    scaling = scaling_of(config)
    sats = []
    for i, sat in enumerate(config.satellites):
        entry = {"id": i + 1, "name": sat.name}
        if i in facts.arm_of and len(rows):
            entry.update(tracking_errors(rows, index, i + 1, facts.arm_of[i] + 1))
        else:
            entry.update(
                position_error_max_m=None, position_error_rms_m=None,
                velocity_error_rms_mps=None, attitude_error_max_rad=None,
            )
        v = _cols(rows, index, f"sat{i + 1}", ("vx_mps", "vy_mps", "vz_mps"))
        entry["delta_v_mps"] = float(np.linalg.norm(v[-1] - v[0])) if len(rows) else 0.0
        entry["delta_v_pushed_mps"] = pushed_delta_v(rows, index, i + 1)
        sats.append(entry)
    metrics = {
        "scenario": config.name,
        "mode": facts.mode,
        "status": facts.status,
        "error": facts.error,
        "duration_s": sim_s,
        "cycles": facts.cycles,
        "rate_hz": config.loop.rate_hz,
        "realtime_factor": sim_s / facts.wall_s if facts.wall_s > 0 else None,
        "cycle_time_us": dict(facts.cycle_time_us),
        "force_scale": scaling.force_scale,
        "torque_scale": scaling.torque_scale,
        "scaling": describe_scaling(config),
        "vfdm_iterations": config.vfdm.iterations,
        "seed": config.loop.seed,
        "satellites": sats,
        "robots": robot_metrics(config, rows, index, facts),
        "collision": None,
        "safety_stop": facts.safety_stop,
        "passivity": facts.passivity,
    }
    pair = contact_pair(rows, index, n_sat) if n_sat >= 2 and len(rows) else None
    if pair is not None:
        bodies = {s + 1: f"rob{a + 1}" for s, a in facts.arm_of.items()}
        coll = collision_metrics(rows, index, 1.0 / config.loop.rate_hz, *pair, bodies=bodies)
        if coll is not None:
            ideal = dict(coll) if facts.mode == "ideal" else ideal_collision
            if ideal is not None and ideal.get("pair") != coll["pair"]:
                coll["warnings"].append(
                    f"the ideal run has no contact between {' and '.join(coll['pair'])}"
                    + (f" (its first contact is between {' and '.join(ideal['pair'])})"
                       if ideal else "") + ": nothing to compare this one with")
                ideal = None
            compare_with_ideal(coll, ideal, _contact_deadband(config, bool(facts.arm_of)))
            coll["warnings"] += _off_normal_warnings(
                coll, _sensor_noise(config, bool(facts.arm_of)))
            coll["restitution_sd"] = coll["restitution_interval_95"] = None  # hil: filled
            coll["restitution_systematic"] = None
            coll["restitution_bias_noisy"] = None
            coll["uncertainty"] = None  # by app/runs/uncertainty.py after the run
            if facts.arm_of:  # how far the mockups' contact was the satellites' (Eq. R1)
                coll.update(rendering_error(rows, index, coll, bodies, force_lag_s(config),
                                             contact_geometry(config)))
                coll["warnings"] += [w for w in [rendering_warning(coll)] if w]
            else:  # ideal: no mockups
                coll.update(dict.fromkeys(RENDERING_FIELDS))
            if facts.arm_of and coll["peak_force_N"] >= config.sensor.range_force_N:
                coll["warnings"].append(
                    f"the contact peaked at {coll['peak_force_N']:.0f} N, beyond the F/T "
                    f"sensor's {config.sensor.range_force_N:g} N range: its readings "
                    f"clipped, and the ODS received less than the mockups exchanged")
        metrics["collision"] = coll
    metrics["collision_forecast"] = (ideal_collision or {}).get("forecast")
    metrics["capture"] = None
    if config.capture is not None:
        metrics["capture"] = capture_metrics(config, rows, index, facts.capture)
        if facts.capture and metrics.get("collision"):  # latched: no rebound to measure
            metrics["collision"]["warnings"] = [  # no rebound to measure: not a fault
                w for w in metrics["collision"]["warnings"] if "restitution" not in w]
    metrics["success"] = success_metrics(config, rows, index, metrics.get("capture"),
                                         metrics.get("collision")) if len(rows) else None
    metrics["warnings"] = _run_warnings(metrics, ideal_collision) + noise_spin_warnings(
        config, [i for i in facts.arm_of])
    return metrics


def robot_metrics(config: EmulatorConfig, rows: np.ndarray, index: dict,
                  facts: RunFacts) -> list[dict]:
    """Per robot of a hil run (none in an ideal run): its satellite's tracking figures and,
    on a rail, ``rail_travel_m`` (the carriage's largest minus smallest position) and
    ``posture_deviation_max_rad`` (the largest departure of any arm joint from the posture
    the null-space term holds: ``posture_rad``, or without it the joints of the first
    row, the start posture); both None without a rail."""
    if not facts.arm_of or not len(rows):
        return []
    out = []
    for k, robot in enumerate(config.robots):
        entry = {"id": k + 1, "name": robot.name, "satellite": robot.satellite,
                 **tracking_errors(rows, index, config.satellite_index(robot.satellite) + 1,
                                   k + 1),
                 "rail_travel_m": None, "posture_deviation_max_rad": None}
        if robot.rail is not None and f"rob{k + 1}_rail_s_m" in index:
            s = rows[:, index[f"rob{k + 1}_rail_s_m"]]
            q = _cols(rows, index, f"rob{k + 1}", [f"q{j}_rad" for j in range(1, 7)])
            posture = q[0] if robot.rail.posture_rad is None else np.array(
                robot.rail.posture_rad)
            entry["rail_travel_m"] = float(s.max() - s.min())
            entry["posture_deviation_max_rad"] = float(np.abs(q - posture).max())
        out.append(entry)
    return out


def pushed_delta_v(rows: np.ndarray, index: dict, sat: int) -> float:
    """The sum of |Δv| over the cycles in which satellite ``sat`` received a force (the
    pushes and contacts the ODS integrated; lab m/s): Σ |v_{k+1} − v_k| where F_k ≠ 0.
    Beside the net change |v_end − v_0|, which opposite pushes cancel."""
    if len(rows) < 2:
        return 0.0
    v = _cols(rows, index, f"sat{sat}", ("vx_mps", "vy_mps", "vz_mps"))
    f = _cols(rows[:-1], index, f"sat{sat}", ("fx_N", "fy_N", "fz_N"))
    pushed = np.any(f != 0.0, axis=1)
    return float(np.linalg.norm(np.diff(v, axis=0)[pushed], axis=1).sum())


def capture_metrics(config: EmulatorConfig, rows: np.ndarray, index: dict,
                    event: dict | None) -> dict:
    """Docking: captured or not (and the relative state at capture), the peak contact
    force before it, and the compound's residual rates at the end (lab units)."""
    cap = config.capture
    c, t = config.satellite_index(cap.chaser) + 1, config.satellite_index(cap.target) + 1
    out = {"captured": event is not None, **(event or {})}
    if not len(rows):
        return out
    before = rows[:, 0] <= (event["t_s"] if event else np.inf)
    true = [_cols(rows, index, f"sat{s}", ("true_fx_N", "true_fy_N", "true_fz_N"))
            for s in (c, t)]
    out["peak_contact_force_N"] = float(max(np.linalg.norm(f[before], axis=1).max()
                                            for f in true))
    if event:
        w = _cols(rows[-1:], index, f"sat{c}", ("wx_radps", "wy_radps", "wz_radps"))[0]
        m = np.array([config.satellites[s - 1].mass_kg for s in (c, t)])
        v = sum(m[k] * _cols(rows[-1:], index, f"sat{s}", ("vx_mps", "vy_mps", "vz_mps"))[0]
                for k, s in enumerate((c, t))) / m.sum()
        out["residual_rate_radps"] = float(np.linalg.norm(w))
        out["residual_speed_mps"] = float(np.linalg.norm(v))
    return out


NOISE_SPIN_MAX_RADPS = 0.1
"""The largest rate (lab rad/s) one F/T sample at the torque deadband may give a carried
satellite in one cycle before the run is warned about it."""


def noise_spin_warnings(config: EmulatorConfig, carried: list[int]) -> list[str]:
    """Carried satellites whose inertia in lab units (I / (k_M k_L²) under similarity,
    I / torque_scale under the paper's law) is so small that a single F/T sample just
    over the torque deadband, acting for one cycle, would turn them faster than
    NOISE_SPIN_MAX_RADPS: the sensor's noise can spin them, which the ideal run never
    shows (the rendezvous at k_M = 500 did so: a tracking stop after 1.8 s)."""
    sc, out = scaling_of(config), []
    dt_s = 1.0 / config.loop.rate_hz
    for i in carried:
        sat = config.satellites[i]
        inertia = describe_body(sat, config, sc)["lab_equivalent_inertia_kgm2"]
        if not inertia:
            continue
        kick = config.wrench.deadband_torque_Nm * dt_s / min(inertia)
        if kick > NOISE_SPIN_MAX_RADPS:
            out.append(
                f"satellite {sat.name!r}: its inertia in lab units ({min(inertia):.3g} kg m2) "
                f"is so small that one F/T sample at the torque deadband "
                f"({config.wrench.deadband_torque_Nm:g} N m) for one cycle would turn it at "
                f"{kick:.3g} rad/s: the sensor's noise can spin it (lower scaling.mass or "
                f"scaling.length, or raise its inertia)")
    return out


def _run_warnings(metrics: dict, ideal_collision: dict | None) -> list[str]:
    """What a reader of the run's metrics must not miss beyond the collision's own
    warnings: a collision the ideal run has and this run does not."""
    if metrics["collision"] is not None or not ideal_collision:
        return []
    a, b = ideal_collision["pair"]
    text = (f"in the ideal run {a} and {b} collide at t = "
            f"{ideal_collision['contact_start_s']:.3f} s; this run had no contact")
    stop = metrics["safety_stop"]
    if stop:
        text += f": it ended in a safety stop at t = {stop['t_s']:.3f} s"
    elif metrics["duration_s"] < ideal_collision["contact_start_s"]:
        text += f": it ended at t = {metrics['duration_s']:.3f} s"
    return [text]
