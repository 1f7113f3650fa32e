"""Writing what a run recorded: telemetry CSV, metrics JSON and the summary table."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from app.runs.rendering import unrendered_share


def write_telemetry_csv(path: str | Path, columns: list[str], rows: np.ndarray) -> None:
    """CSV with a header line; floats in %.12g so equal runs give equal bytes."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(telemetry_csv_text(columns, rows))


def telemetry_csv_text(columns: list[str], rows: np.ndarray) -> str:
    """The telemetry CSV as a string (what :func:`write_telemetry_csv` writes)."""
    fmt = csv_row_format(len(columns))
    return ",".join(columns) + "\n" + "".join(fmt % row for row in map(tuple, rows.tolist()))


def csv_row_format(n_columns: int) -> str:
    """The %-format of one CSV row: %.12g floats, so that equal runs give equal bytes."""
    return ",".join(["%.12g"] * n_columns) + "\n"


def write_json(path: str | Path, data: dict) -> None:
    """``data`` as JSON (:func:`json_safe`: a non-finite number is null)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(json_safe(data), indent=2, allow_nan=False) + "\n")


def json_safe(value):
    """A nested value as JSON can hold it: NumPy scalars and arrays as Python numbers and
    lists, and non-finite floats (NaN, ±Infinity: JSON has none) as None."""
    if isinstance(value, (np.ndarray, np.generic)):
        value = value.tolist()
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    return value


def run_summary(metrics: dict) -> str:
    """The table a headless run prints: timing, tracking errors per satellite, events."""
    rtf, ct = metrics["realtime_factor"], metrics["cycle_time_us"]

    def num(v, spec):
        return "-" if v is None else format(v, spec)

    lines = [
        f"scenario {metrics['scenario']}  mode {metrics['mode']}  status {metrics['status']}",
        f"simulated {metrics['duration_s']:.2f} s in {metrics['cycles']} cycles, "
        f"real-time factor {num(rtf, '.2f')}, cycle p50 {num(ct['p50'], '.0f')} us / p99 "
        f"{num(ct['p99'], '.0f')} us",
        metrics["scaling"]["text"] if "scaling" in metrics else
        f"force scale {metrics['force_scale']:g}, torque scale {metrics['torque_scale']:g}",
        "",
        f"{'sat':>3} {'name':12s} {'pos err max':>12} {'pos err rms':>12} {'vel err rms':>12} "
        f"{'att err max':>12} {'net dv':>12} {'pushes |dv|':>12}",
    ]

    def cell(v, scale, unit):
        text = "-" if v is None else f"{v * scale:.3f} {unit}"
        return f"{text:>12}"

    for s in metrics["satellites"]:
        lines.append(
            f"{s['id']:>3} {s['name']:12s} {cell(s['position_error_max_m'], 1e3, 'mm')} "
            f"{cell(s['position_error_rms_m'], 1e3, 'mm')} "
            f"{cell(s['velocity_error_rms_mps'], 1e3, 'mm/s')} "
            f"{cell(s['attitude_error_max_rad'], 1e3, 'mrad')} "
            f"{cell(s['delta_v_mps'], 1.0, 'm/s')} "
            f"{cell(s.get('delta_v_pushed_mps'), 1.0, 'm/s')}"
        )
    lines.append("net dv: |v_end - v_start|; pushes |dv|: the sum of |dv| over the cycles "
                 "a force reached the ODS")
    coll = metrics.get("collision")
    if coll:
        e, ei = coll["restitution"], coll["restitution_ideal"]
        err, ratio = coll.get("restitution_error"), coll.get("true_impulse_ratio")
        true_j = ", ".join(f"{name} {np.linalg.norm(j):.4f}"
                           for name, j in coll["true_impulse_Ns"].items())
        latched = (metrics.get("capture") or {}).get("captured")
        rebound = "latched: no rebound, no restitution" if latched and e is None else (
            f"restitution {'-' if e is None else f'{e:.3f}'} (ideal "
            f"{'-' if ei is None else f'{ei:.3f}'}, error "
            f"{'-' if err is None else f'{100 * err:+.1f} %'})")
        lines += [
            "",
            f"{'contact' if latched else 'collision'} at {coll['contact_start_s']:.3f} s: "
            f"{rebound}; the ODS's impulse balance {num(coll['impulse_balance'], '.3f')}",
            f"what the mockups went through: impulse {true_j} N s"
            + ("" if not ratio else " (x ideal: " + ", ".join(
                f"{name} {r:.2f}" for name, r in ratio.items()) + ")")
            + f", peak force {coll['peak_force_N']:.1f} N, contact "
            f"{1e3 * coll['contact_duration_s']:.0f} ms, energy absorbed "
            f"{1e3 * coll['contact_energy_J']:.2f} mJ",
            *([rendering_text(coll)] if coll.get("rendering_error_m") is not None else []),
            *([interval_text(coll)] if interval_text(coll) else []),
            *([forecast_text(metrics["collision_forecast"])]
              if metrics.get("collision_forecast") else []),
            *(f"WARNING: {w}" for w in coll.get("warnings", [])),
        ]
    success = metrics.get("success")
    if success:
        judged = [k for k, v in success.items() if isinstance(v, dict) and "passed" in v]
        lines += ["", "success: " + ("passed" if success["passed"] else "NOT MET")
                  + f" ({len(judged)} {'criterion' if len(judged) == 1 else 'criteria'} "
                  + "judged: " + ", ".join(
                      f"{k} {'passed' if success[k]['passed'] else 'NOT MET'}"
                      for k in judged) + ")"]
        touch = success.get("no_contact")
        if touch:
            lines.append("  no contact between the satellites (required: none)"
                         if not touch["touched"] else
                         f"  {' and '.join(touch['pair'])} touched at {touch['at_s']:.2f} s (lab) "
                         f"(peak {touch['peak_force_N']:.1f} N): a contact this scenario "
                         f"must not have")
        lib = success.get("libration")
        if lib:
            period = "-" if lib["period_s"] is None else f"{lib['period_s']:.1f} s"
            error = "-" if lib["period_error"] is None else f"{100 * lib['period_error']:+.3f} %"
            lines.append(
                f"  libration of {lib['satellite']} ({lib['amplitude_deg']:.1f} deg, "
                f"{lib['periods_seen']:g} periods seen): period {period} (orbit time), "
                f"theory {lib['period_theory_s']:.1f} s, error {error} (limit "
                f"{100 * lib['limit']:g} %)")
        lines += docking_success_lines(success)
        lines += gnc_success_lines(success)
    cap = metrics.get("capture")
    if cap:
        lines.append("")
        if cap["captured"]:
            lines.append(
                f"captured at {cap['t_s']:.3f} s (miss {1e3 * cap['position_miss_m']:.1f} mm, "
                f"{1e3 * cap['relative_speed_mps']:.1f} mm/s, "
                f"{1e3 * cap['relative_angle_rad']:.1f} mrad); peak contact force "
                f"{cap.get('peak_contact_force_N', 0.0):.1f} N; residual rate "
                f"{1e3 * cap.get('residual_rate_radps', 0.0):.2f} mrad/s, speed "
                f"{1e3 * cap.get('residual_speed_mps', 0.0):.1f} mm/s")
        else:
            lines.append("NOT captured (peak contact force "
                         f"{cap.get('peak_contact_force_N', 0.0):.1f} N)")
    pc = metrics.get("passivity")
    if pc:
        d = pc["dissipated_J"]
        lines.append(f"passivity layer removed {d['force'] * 1e3:.2f} mJ (force ports), "
                     f"{sum(d['torque'].values()) * 1e3:.3f} mJ (torque ports)")
    lines += [f"WARNING: {w}" for w in metrics.get("warnings", [])]
    stop = metrics.get("safety_stop")
    if stop:
        lines.append(
            f"SAFETY STOP: robot {stop['robot']} at t = {stop['t_s']:.3f} s: {stop['reason']}"
        )
    return "\n".join(lines)


def docking_success_lines(success: dict) -> list[str]:
    """The summary's lines for the docking criteria (app/runs/success.py docking)."""
    dock = success.get("docking")
    if not dock:
        return []
    lines = []
    if dock["required"] is not None:
        lines.append(f"  captured: {'yes' if dock['captured'] else 'no'} (required: "
                     f"{'yes' if dock['required'] else 'no'})")
    if dock["residual_rate_max_radps"] is not None:
        rate = dock["residual_rate_radps"]
        lines.append("  residual rate of the compound "
                     + ("-" if rate is None else f"{1e3 * rate:.2f} mrad/s")
                     + f" (limit {1e3 * dock['residual_rate_max_radps']:g} mrad/s)")
    return lines


def gnc_success_lines(success: dict) -> list[str]:
    """The summary's lines for the GNC criteria (app/runs/success.py), orbit units."""
    lines = []
    wp = success.get("waypoints")
    if wp:
        at = ", ".join(f"{t:.1f}" for t in wp["reached_at_s"]) or "-"
        lines.append(f"  waypoints of {wp['satellite']}: {wp['reached']} of {wp['count']} "
                     f"reached in order (required: all), at {at} s (orbit time)")
        for leg in wp.get("transfers", []):
            lines.append(f"  CW transfer to waypoint {leg['waypoint']}: due at "
                         f"{leg['due_s']:.1f} s, arrived {leg['miss_m']:.3f} m from it")
    fp = success.get("final_position")
    if fp:
        err = "-" if fp["error_m"] is None else f"{fp['error_m']:.3f} m"
        lines.append(f"  final position of {fp['satellite']}: {err} from its last waypoint "
                     f"(limit {fp['limit_m']:g} m)")
    rec = success.get("recovery")
    if rec:
        if rec["pulse_end_s"] is None:
            lines.append(f"  recovery of {rec['satellite']}: no scripted push on it")
        elif rec["waypoint"] is None:
            lines.append(f"  recovery of {rec['satellite']}: the run ended before its push "
                         f"did ({rec['pulse_end_s']:.1f} s, orbit time)")
        else:
            back = "not back" if rec["recovery_time_s"] is None else \
                f"back in {rec['recovery_time_s']:.1f} s"
            lines.append(
                f"  recovery of {rec['satellite']} from the push ending at "
                f"{rec['pulse_end_s']:.1f} s: {rec['excursion_max_m']:.3f} m off waypoint "
                f"{rec['waypoint']}, {back} (limit {rec['limit_s']:g} s, orbit time)")
    sync = success.get("synchronisation")
    if sync:
        if sync["at_s"] is None:
            lines.append(f"  synchronisation of {sync['satellite']} with {sync['target']}: "
                         f"its capture point (waypoint {sync['waypoint']}) not reached"
                         + sync_limits_text(sync))
        else:
            lines.append(
                f"  synchronisation of {sync['satellite']} with {sync['target']} at its "
                f"capture point ({sync['at_s']:.1f} s, over the {sync['hold_s']:.1f} s hold): "
                f"position {1e3 * sync['position_error_max_m']:.1f} mm, attitude "
                f"{math.degrees(sync['attitude_error_max_rad']):.2f} deg, rate "
                f"{math.degrees(sync['rate_error_max_radps']):.3f} deg/s at most"
                + sync_limits_text(sync))
    return lines


def sync_limits_text(sync: dict) -> str:
    """The synchronisation's limits, as the summary shows them: " (limits 10 mm, 1.00
    deg)"; "" without any."""
    limits = []
    if sync.get("position_limit_m") is not None:
        limits.append(f"{1e3 * sync['position_limit_m']:g} mm")
    if sync.get("attitude_limit_rad") is not None:
        limits.append(f"{math.degrees(sync['attitude_limit_rad']):.2f} deg")
    return f" (limits {', '.join(limits)})" if limits else ""


def _chain_text(coll: dict) -> str:
    """Which estimate of the chain's systematic error widened the interval, and by how
    much (app.runs.uncertainty.widening: on each side, the one reaching furthest toward
    the ideal); the other, for comparison. "" with neither."""
    known = [(d, name) for d, name in ((coll.get("restitution_systematic"), "noise-free twin"),
                                       (coll.get("restitution_bias_noisy"),
                                        "noisy replicates' mean")) if d is not None]
    if not known:
        return ""
    from app.runs.uncertainty import widening  # (the loop's imports: only where it is used)

    low, high = widening(known)
    used = [e for e in (low, high) if e is not None]
    if not used:
        return ", no systematic error from the chain (" + ", ".join(n for _, n in known) + ")"
    rest = [(d, n) for d, n in known if (d, n) not in used]
    return (", widened by the chain's systematic error" + ("s " if len(used) > 1 else " ")
            + " and ".join(f"{d:+.3f} ({n})" for d, n in used)
            + "".join(f"; the {n}'s {d:+.3f}" for d, n in rest))


def rendering_text(coll: dict) -> str:
    """How far the mockups' contact was the satellites' (app/runs/rendering.py, Eq. R1)."""
    err, depth = coll["rendering_error_m"], coll["contact_depth_m"]
    share = f" ({100 * err / depth:.1f} %)" if depth else ""
    return (f"the mockups rendered the contact to {1e6 * err:.1f} µm rms (at most "
            f"{1e6 * coll['rendering_error_max_m']:.1f} µm) of overlap against the "
            f"satellites' {1e6 * depth:.0f} µm contact depth{share}")


def interval_text(coll: dict) -> str | None:
    """The restitution's 95 % interval as a line (app/runs/uncertainty.py); None without one."""
    interval, sd = coll.get("restitution_interval_95"), coll.get("restitution_sd")
    if interval is None:
        return None
    how = coll.get("uncertainty") or {}
    ideal = coll.get("restitution_ideal")
    holds = "" if ideal is None else (
        f"; holds the ideal {ideal:.3f}" if interval[0] <= ideal <= interval[1]
        else f"; does NOT hold the ideal {ideal:.3f}")
    chain = _chain_text(coll)
    return (f"restitution 95 % interval [{interval[0]:.3f}, {interval[1]:.3f}] (sd "
            f"{sd:.3f}, {how.get('replicates', '?')} replicates of the contact with the "
            f"noise measured at calibration{chain}{holds})")


def forecast_text(forecast: dict) -> str:
    """The pre-flight's fidelity forecast as a line (app/runs/uncertainty.py)."""
    sd = forecast.get("restitution_sd")
    ratio = forecast.get("peak_to_noise")
    return ("forecast before the run: restitution sd "
            + ("-" if sd is None else f"{sd:.3f}")
            + f" (contact peak {forecast['peak_force_N']:.2f} N against the sensor's "
            f"{forecast['noise_force_N']:.3g} N noise per sample"
            + ("" if ratio is None else f": ratio {ratio:.2g}") + ")"
            + ("" if forecast.get("restitution_error_mean") is None else
               "; the chain's predicted mean error "
               f"{100 * forecast['restitution_error_mean']:+.0f} %")
            + _unrendered(forecast))


def _unrendered(forecast: dict) -> str:
    """What the forecast line adds when the noise-free twin's arms did not render the
    contact (app/runs/rendering.py); "" otherwise."""
    share = unrendered_share(forecast)
    return ("" if share is None else
            f"; the mockups will not render this contact (the noise-free twin's rendering "
            f"error is {100 * share:.0f} % of the contact depth)")
