"""Did a scenario do what it is for? Its ``[success]`` criteria, measured on its telemetry.

Each criterion a scenario names is computed here and reported in metrics.json as
``success``: the figures, the limit, and ``passed``. Pure: telemetry rows and the config in,
a dict out.
"""

from __future__ import annotations

import math

import numpy as np

from app.config import EmulatorConfig
from app.sim.orbital import orbit_rate
from app.sim.scaling import ods_inertia_kgm2, scaling_of

__all__ = ["docking", "libration", "libration_period_theory_s", "pitch_rad", "success_metrics"]


def success_metrics(config: EmulatorConfig, rows: np.ndarray, index: dict,
                    capture: dict | None = None) -> dict | None:
    """The ``success`` block of metrics.json (None when the scenario names no criterion);
    ``capture``: the run's capture metrics, if it has a [capture]."""
    crit = config.success
    checks = {}
    if crit.libration_period_error_max is not None:
        lib = libration(config, rows, index, satellite=0)
        lib["limit"] = crit.libration_period_error_max
        lib["passed"] = lib["period_error"] is not None and \
            abs(lib["period_error"]) <= crit.libration_period_error_max
        checks["libration"] = lib
    if crit.captured is not None or crit.residual_rate_max_radps is not None:
        checks["docking"] = docking(config, capture, crit)
    if not checks:
        return None
    return {"passed": all(c["passed"] for c in checks.values()), **checks}


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
