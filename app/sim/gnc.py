"""A satellite's own guidance, navigation and control (GNC): thrusters and reaction wheels.

Everything here is in ORBIT units (metres, seconds, newtons of the virtual satellite): the
loop hands it the satellite's ODS state converted from the lab's units by the scaling
(:func:`navigation`; app/sim/scaling.py) and adds the wrench it returns to the ODS input
converted back (:meth:`app.sim.scaling.Scaling.ods_force` / ``ods_torque``). The
satellite's own actuation goes straight into the ODS: it never passes the F/T sensor,
which measures only what touches the mockup (contact, the operator's hand).

* **Navigation**: the ODS state, exactly (no sensor model): position and velocity in R,
  attitude q_R_B, angular velocity relative to R in body axes.
* **Guidance**: a list of waypoints (positions in R) flown in order. The satellite is
  *within tolerance* of its waypoint while ``|r − r_wp| < tolerance_m`` and
  ``|v| < tolerance_mps``; once it has stayed so for the waypoint's ``hold_s`` (an
  unbroken stretch: leaving the tolerance starts the hold anew), the next waypoint is
  the target. The last one is held for good. Checked every loop cycle.
* **Control**, a sampled controller: at the start of each control period ``period_s`` it
  computes a command from the state then and holds it over the period (zero-order hold).

  Translation: PD with the Clohessy–Wiltshire accelerations cancelled (Eqs. 1–3),
  a = −ω_n² (r − r_wp) − 2 ζ ω_n v − a_CW, a_CW = (3Ω²x + 2Ωẏ, −2Ωẋ, −Ω²z), so holding a
  point off R's origin leaves no steady error; F_R = m a.
  Attitude: quaternion-error PD with the gyroscopic and gravity-gradient torques cancelled
  (Eqs. 4–6): τ = −I (2 ω_n² sgn(q_e,w) q_e,vec + 2 ζ ω_n ω_rel) + ω × I ω − 3Ω² c × I c,
  with q_e = q_R_T* ⊗ q_R_B the body's attitude relative to the target T, ω = ω_rel + Ω n.

* **Actuators.** Thrusters along the BODY axes (they are fixed to the satellite), a pair
  per axis: each axis's force is clipped to ±``thrust_max_N``, and an axis whose impulse
  over the period, |F|·period_s, is below the minimum impulse bit ``min_impulse_bit_Ns``
  is not fired at all (dead zone: a thruster cannot open for less than MIB / thrust). The
  period's impulse is applied as its mean force over the period (what a pulse-width
  modulated thruster averages to); the held body-axes force is turned into R with the
  attitude of each cycle. Reaction wheels: each body axis's torque clipped to
  ±``torque_max_Nm`` (no wheel momentum limit; no minimum).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from app.sim.rotations import quat_mul

__all__ = ["GncParams", "GncState", "Navigation", "attitude_torque_B", "cw_acceleration",
           "gnc_step", "guidance", "navigation", "thruster_force_B", "translation_force_R",
           "wheel_torque_B", "within_tolerance"]


@dataclass(frozen=True)
class GncParams:
    """One satellite's GNC (orbit units); built from its ``[satellites.gnc]`` table."""

    mass_kg: float
    inertia_kgm2: np.ndarray
    """Principal moments (3,)."""
    orbit_rate_radps: float
    """Ω of the orbit (not the lab's k_T Ω)."""
    waypoints_m: np.ndarray
    """(K, 3) positions in R."""
    hold_s: np.ndarray
    """(K,) how long each waypoint is held within tolerance before the next."""
    position_omega_radps: float = 0.1
    position_damping: float = 0.8
    attitude_omega_radps: float = 0.2
    attitude_damping: float = 0.8
    thrust_max_N: float = 1.0
    min_impulse_bit_Ns: float = 0.01
    torque_max_Nm: float = 0.1
    period_s: float = 1.0
    tolerance_m: float = 0.05
    tolerance_mps: float = 0.005
    attitude_wxyz: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0, 0.0]))

    @classmethod
    def from_config(cls, gnc, mass_kg: float, inertia_kgm2, orbit_rate_radps: float,
                    ) -> GncParams:
        """From an :class:`app.config.GncConfig` and the virtual body (orbit units)."""
        return cls(
            mass_kg=float(mass_kg), inertia_kgm2=np.array(inertia_kgm2, dtype=float),
            orbit_rate_radps=float(orbit_rate_radps),
            waypoints_m=np.array([w.position_m for w in gnc.waypoints], dtype=float),
            hold_s=np.array([w.hold_s for w in gnc.waypoints], dtype=float),
            position_omega_radps=gnc.position_omega_radps,
            position_damping=gnc.position_damping,
            attitude_omega_radps=gnc.attitude_omega_radps,
            attitude_damping=gnc.attitude_damping,
            thrust_max_N=gnc.thrust_max_N, min_impulse_bit_Ns=gnc.min_impulse_bit_Ns,
            torque_max_Nm=gnc.torque_max_Nm, period_s=gnc.period_s,
            tolerance_m=gnc.tolerance_m, tolerance_mps=gnc.tolerance_mps,
            attitude_wxyz=np.array(gnc.attitude_wxyz, dtype=float))

    def target_m(self, waypoint: int) -> np.ndarray:
        """The position flown to while ``waypoint`` waypoints are reached (the last one
        once all are)."""
        return self.waypoints_m[min(waypoint, len(self.waypoints_m) - 1)]


@dataclass(frozen=True)
class GncState:
    """What the GNC remembers between cycles (the loop keeps one per satellite)."""

    waypoint: int = 0
    """Waypoints reached so far (the one flown to is this one, or the last)."""
    inside_since_s: float = math.nan
    """Since when (orbit s) it is within tolerance of its waypoint; NaN: it is not."""
    next_update_s: float = 0.0
    """When (orbit s) the next control period starts."""
    force_B_N: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """The thrusters' force held over the period, body axes."""
    torque_B_Nm: np.ndarray = field(default_factory=lambda: np.zeros(3))
    """The wheels' torque held over the period, body axes."""


@dataclass(frozen=True)
class Navigation:
    """A satellite's state in orbit units, as the GNC knows it."""

    t_s: float
    position_m: np.ndarray
    velocity_mps: np.ndarray
    attitude_wxyz: np.ndarray
    omega_rel_radps: np.ndarray
    """Relative to R, body axes."""
    R_R_B: np.ndarray


def navigation(y_row: np.ndarray, t_lab_s: float, scaling, orbit_rate_lab_radps: float,
               ) -> Navigation:
    """One satellite's ODS state (a row of the lab-unit state, app/sim/orbital.py) in orbit
    units: x = k_L x', v = (k_L / k_T) v', ω_rel = ω'_rel / k_T, t = k_T t', the attitude
    as it is. ω'_rel = ω' − Ω' n, n being R's z axis in body axes."""
    q = y_row[6:10].copy()
    R_R_B = _rotation_matrix(*q.tolist())
    omega_rel_lab = y_row[10:13] - orbit_rate_lab_radps * R_R_B[2]
    return Navigation(t_s=scaling.time * t_lab_s, position_m=scaling.length * y_row[0:3],
                      velocity_mps=scaling.velocity * y_row[3:6], attitude_wxyz=q,
                      omega_rel_radps=omega_rel_lab / scaling.time, R_R_B=R_R_B)


def _rotation_matrix(w: float, x: float, y: float, z: float) -> np.ndarray:
    """R_R_B of a unit quaternion (app/sim/rotations.py quat_to_matrix, for one, cheaply:
    the GNC runs every cycle)."""
    return np.array([[1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
                     [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
                     [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)]])


def within_tolerance(params: GncParams, target_m: np.ndarray, nav: Navigation) -> bool:
    """|r − r_wp| < tolerance_m and |v| < tolerance_mps."""
    return bool(np.linalg.norm(nav.position_m - target_m) < params.tolerance_m
                and np.linalg.norm(nav.velocity_mps) < params.tolerance_mps)


def guidance(params: GncParams, state: GncState, nav: Navigation) -> GncState:
    """The waypoint bookkeeping of one cycle: the hold starts when the satellite comes
    within tolerance, is dropped when it leaves, and once it has lasted ``hold_s`` the
    waypoint counts as reached and the next is the target."""
    k = state.waypoint
    if k >= len(params.waypoints_m):
        return state
    if not within_tolerance(params, params.waypoints_m[k], nav):
        return replace(state, inside_since_s=math.nan)
    since = nav.t_s if math.isnan(state.inside_since_s) else state.inside_since_s
    if nav.t_s - since >= params.hold_s[k]:
        return replace(state, waypoint=k + 1, inside_since_s=math.nan)
    return replace(state, inside_since_s=since)


def cw_acceleration(orbit_rate_radps: float, position_m: np.ndarray,
                    velocity_mps: np.ndarray) -> np.ndarray:
    """The Clohessy–Wiltshire acceleration of a free body (Eqs. 1–3 without force):
    (3Ω²x + 2Ωẏ, −2Ωẋ, −Ω²z)."""
    w = orbit_rate_radps
    x, _, z = position_m
    vx, vy, _ = velocity_mps
    return np.array([3.0 * w * w * x + 2.0 * w * vy, -2.0 * w * vx, -w * w * z])


def translation_force_R(params: GncParams, nav: Navigation, target_m: np.ndarray,
                        ) -> np.ndarray:
    """The force (R, N) the translation PD asks for: m (−ω_n² (r − r_wp) − 2 ζ ω_n v − a_CW)."""
    wn, zeta = params.position_omega_radps, params.position_damping
    a = (-wn * wn * (nav.position_m - target_m) - 2.0 * zeta * wn * nav.velocity_mps
         - cw_acceleration(params.orbit_rate_radps, nav.position_m, nav.velocity_mps))
    return params.mass_kg * a


def attitude_torque_B(params: GncParams, nav: Navigation) -> np.ndarray:
    """The torque (body axes, N m) the attitude PD asks for (module doc): quaternion error
    and rate relative to R, plus the gyroscopic and gravity-gradient torques cancelled."""
    wn, zeta, inertia = params.attitude_omega_radps, params.attitude_damping, params.inertia_kgm2
    target_conj = params.attitude_wxyz * np.array([1.0, -1.0, -1.0, -1.0])
    q_e = quat_mul(target_conj, nav.attitude_wxyz)
    sign = -1.0 if q_e[0] < 0.0 else 1.0
    pd = -inertia * (2.0 * wn * wn * sign * q_e[1:] + 2.0 * zeta * wn * nav.omega_rel_radps)
    W = params.orbit_rate_radps
    c, n = nav.R_R_B[0], nav.R_R_B[2]  # R's radial and orbit-normal axes in body axes
    omega = nav.omega_rel_radps + W * n
    feedforward = np.cross(omega, inertia * omega) - 3.0 * W * W * np.cross(c, inertia * c)
    return pd + feedforward


def thruster_force_B(params: GncParams, force_B_N: np.ndarray) -> np.ndarray:
    """What the thrusters give over a period for a commanded force (body axes): each axis
    clipped to ±thrust_max_N, and zero where |F| period_s < min_impulse_bit_Ns."""
    f = np.clip(force_B_N, -params.thrust_max_N, params.thrust_max_N)
    return np.where(np.abs(f) * params.period_s < params.min_impulse_bit_Ns, 0.0, f)


def wheel_torque_B(params: GncParams, torque_B_Nm: np.ndarray) -> np.ndarray:
    """What the reaction wheels give: each body axis clipped to ±torque_max_Nm."""
    return np.clip(torque_B_Nm, -params.torque_max_Nm, params.torque_max_Nm)


def gnc_step(params: GncParams, state: GncState, nav: Navigation, dt_s: float,
             ) -> tuple[GncState, np.ndarray, np.ndarray]:
    """One loop cycle of the GNC (orbit units): (its new state, the thrusters' force in R
    (N), the wheels' torque in body axes (N m)) to hold over the cycle.

    Guidance every cycle; a new command at the cycle nearest the start of each control
    period (``t + dt/2 ≥ next_update_s``), held until the next."""
    state = guidance(params, state, nav)
    if nav.t_s + 0.5 * dt_s >= state.next_update_s:
        force_R = translation_force_R(params, nav, params.target_m(state.waypoint))
        state = replace(
            state, next_update_s=state.next_update_s + params.period_s,
            force_B_N=thruster_force_B(params, nav.R_R_B.T @ force_R),
            torque_B_Nm=wheel_torque_B(params, attitude_torque_B(params, nav)))
    return state, nav.R_R_B @ state.force_B_N, state.torque_B_Nm
