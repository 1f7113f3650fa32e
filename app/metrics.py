"""Fidelity metrics of a run (DESIGN.md "Fidelity"), computed from its telemetry."""

from __future__ import annotations

import numpy as np

from app.sim.loop import Emulator


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


def collision_metrics(rows: np.ndarray, index: dict, dt_s: float, a: int = 1, b: int = 2):
    """Impulses the ODS received, their balance, and the coefficient of restitution.

    The contact window runs from the first touch until neither the true contact force nor
    the force the ODS receives (filtered, delayed) has acted for 50 ms; impulses are the
    ODS's received force integrated over it. Restitution
    e = -(v_b - v_a)_after . n / (v_b - v_a)_before . n, with n the line of centres at
    first contact. None if no impact, or if the run ended before the satellites separated.
    """
    true_a = _cols(rows, index, f"sat{a}", ("true_fx_N", "true_fy_N", "true_fz_N"))
    applied = {
        s: _cols(rows, index, f"sat{s}", ("fx_N", "fy_N", "fz_N")) for s in (a, b)
    }
    touching = np.nonzero(np.linalg.norm(true_a, axis=1) > 0)[0]
    if len(touching) == 0:
        return None
    first = int(touching[0])
    acting = np.linalg.norm(true_a, axis=1) > 0
    for s_ in (a, b):
        acting |= np.linalg.norm(applied[s_], axis=1) > 0
    # the contact window: from first touch until nothing acts for `quiet` seconds
    quiet = int(round(0.05 / dt_s))
    last = first
    k = first
    while k < len(rows) and k - last <= quiet:
        if acting[k]:
            last = k
        k += 1
    window = slice(max(0, first - quiet), last + 1)
    impulse = {s_: applied[s_][window].sum(axis=0) * dt_s for s_ in (a, b)}
    ja, jb = impulse[a], impulse[b]
    biggest = max(np.linalg.norm(ja), np.linalg.norm(jb))
    balance = float(np.linalg.norm(ja + jb) / biggest) if biggest > 0 else None
    after = last + int(round(0.02 / dt_s))
    pos = {s: _cols(rows, index, f"sat{s}", ("x_m", "y_m", "z_m")) for s in (a, b)}
    vel = {s: _cols(rows, index, f"sat{s}", ("vx_mps", "vy_mps", "vz_mps")) for s in (a, b)}
    n = pos[b][first] - pos[a][first]
    n /= np.linalg.norm(n)
    before_rel = float((vel[b][first] - vel[a][first]) @ n)
    restitution = None
    if after < len(rows) and before_rel < 0:
        restitution = float(-((vel[b][after] - vel[a][after]) @ n) / before_rel)
    return {
        "impulse_Ns": {f"sat{a}": ja.tolist(), f"sat{b}": jb.tolist()},
        "impulse_balance": balance,
        "restitution": restitution,
        "contact_start_s": float(rows[first, 0]),
        "contact_end_s": float(rows[last, 0]),
    }


def passivity_metrics(em: Emulator) -> dict | None:
    """Energy each arm's passivity controller removed (None when it is off)."""
    removed = em.coupling.dissipated_J()
    if removed is None:
        return None
    return {"dissipated_J": {f"sat{s + 1}": ports for s, ports in removed.items()}}


def compute_metrics(em: Emulator, wall_s: float, restitution_ideal: float | None = None) -> dict:
    """The metrics.json of a run (the emulator after it ran; wall_s its wall-clock time)."""
    rows = em.telemetry.rows()
    index = em.telemetry.index
    sim_s = float(rows[-1, 0]) if len(rows) else 0.0
    ct = np.array(em.cycle_time_ns, dtype=float) / 1e3
    sats = []
    arm_of = {arm.satellite: arm.index for arm in em.arms}
    for i, sat in enumerate(em.config.satellites):
        entry = {"id": i + 1, "name": sat.name}
        if i in arm_of and len(rows):
            entry.update(tracking_errors(rows, index, i + 1, arm_of[i] + 1))
        else:
            entry.update(
                position_error_max_m=None, position_error_rms_m=None,
                velocity_error_rms_mps=None, attitude_error_max_rad=None,
            )
        v = _cols(rows, index, f"sat{i + 1}", ("vx_mps", "vy_mps", "vz_mps"))
        entry["delta_v_mps"] = float(np.linalg.norm(v[-1] - v[0])) if len(rows) else 0.0
        sats.append(entry)
    metrics = {
        "scenario": em.config.name,
        "mode": em.mode,
        "status": em.status,
        "duration_s": sim_s,
        "cycles": em.cycles,
        "rate_hz": em.config.loop.rate_hz,
        "realtime_factor": sim_s / wall_s if wall_s > 0 else None,
        "cycle_time_us": {
            "p50": float(np.percentile(ct, 50)) if len(ct) else None,
            "p99": float(np.percentile(ct, 99)) if len(ct) else None,
        },
        "force_scale": em.config.orbit.force_scale,
        "torque_scale": em.config.orbit.torque_scale,
        "vfdm_iterations": em.config.vfdm.iterations,
        "seed": em.config.loop.seed,
        "satellites": sats,
        "collision": None,
        "safety_stop": em.safety_stop,
        "passivity": passivity_metrics(em),
    }
    if em.n_sat >= 2 and len(rows):
        coll = collision_metrics(rows, index, em.dt_s)
        if coll is not None:
            coll["restitution_ideal"] = (
                coll["restitution"] if em.mode == "ideal" else restitution_ideal
            )
        metrics["collision"] = coll
    return metrics
