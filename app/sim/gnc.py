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

  A waypoint may name how its leg is flown (otherwise the PD below flies it):

  - ``transfer_s``: a Clohessy–Wiltshire two-impulse transfer of that duration
    (app/sim/guidance.py), *re-targeted* every control period: the first impulse that
    takes the satellite from where it is to the waypoint, at rest, in the time left is
    commanded as the period's force m Δv / period_s. While saturated, this spreads the
    first burn over several periods; afterwards the re-targeted impulse is what the coast
    has drifted off, fired when it exceeds the minimum impulse bit (mid-course
    corrections). In the last ``RETARGET_FRACTION`` of the transfer it coasts (the
    re-targeted impulse grows without bound as the time left goes to zero). At the
    arrival time, the second impulse: it brakes (m Δv / period_s with Δv = −v) until it
    is slower than ``tolerance_mps``; from then on (once per leg) the PD flies to the point
    and holds it.
  - ``approach_speed_mps``: a straight closing at that speed, aimed at the waypoint every
    period (a velocity loop of gain 2 ζ ω_n, slowing as ω_n times the distance left near
    it); ``free_drift_m``: within that distance of the waypoint the thrusters and wheels
    stop for good, and it drifts in (a docking's last centimetres: the chaser does not
    fire into the interface).
    A GNC flying relative to the satellite it is captured with ([capture]) goes into free
    drift at the capture (app/sim/loop.py): its reference is part of its own body then.

  *Relative to another satellite* (``relative_to``, e.g. a tumbling target or a docking
  port): the waypoints and the held attitude are in that satellite's body frame, from its
  centre of mass, and move with it: the reference point is r_T + R_R_T p, its velocity
  v_T + ω_T × R_R_T p, its acceleration the target's free CW acceleration plus
  ω_T × (ω_T × R_R_T p) (a spin about a principal axis: ω_T constant), the reference
  attitude q_R_T ⊗ q_wp and the reference rate ω_T. The tolerance then bounds the error
  to that moving reference.
* **Control**, a sampled controller: at the start of each control period ``period_s`` it
  computes a command from the state then and holds it over the period (zero-order hold).

  Translation: PD with the Clohessy–Wiltshire accelerations cancelled (Eqs. 1–3),
  a = a_ref − ω_n² (r − r_ref) − 2 ζ ω_n (v − v_ref) − a_CW,
  a_CW = (3Ω²x + 2Ωẏ, −2Ωẋ, −Ω²z), so holding a point off R's origin leaves no steady
  error; F_R = m a (a fixed waypoint: r_ref = r_wp, v_ref = a_ref = 0).
  Attitude: quaternion-error PD with the gyroscopic and gravity-gradient torques cancelled
  (Eqs. 4–6): τ = −I (2 ω_n² sgn(q_e,w) q_e,vec + 2 ζ ω_n (ω_rel − ω_ref)) + ω × I ω
  − 3Ω² c × I c, with q_e = q_ref* ⊗ q_R_B the body's attitude relative to the reference,
  ω = ω_rel + Ω n, ω_ref the reference rate in body axes.

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

from app.sim.guidance import SingularTransfer, two_impulse_transfer
from app.sim.rotations import quat_mul, quat_to_matrix

__all__ = ["GncParams", "GncState", "Navigation", "Reference", "attitude_torque_B",
           "cw_acceleration", "gnc_step", "guidance", "moving_point", "navigation",
           "reference", "thruster_force_B", "translation_force_R", "wheel_torque_B",
           "within_tolerance"]

RETARGET_FRACTION = 0.2
"""The last fraction of a CW transfer flown without re-targeting (module doc)."""


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
    transfer_s: np.ndarray | None = None
    """(K,) each leg's CW transfer time (orbit s), NaN: flown by the PD; None: none is."""
    approach_speed_mps: np.ndarray | None = None
    """(K,) each leg's closing speed, NaN: flown by the PD; None: none is."""
    free_drift_m: np.ndarray | None = None
    """(K,) within this distance of the waypoint it stops firing for good; NaN: never."""
    relative: bool = False
    """The waypoints and the attitude are in another satellite's body frame."""

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
            attitude_wxyz=np.array(gnc.attitude_wxyz, dtype=float),
            transfer_s=_per_leg(gnc, "transfer_s"),
            approach_speed_mps=_per_leg(gnc, "approach_speed_mps"),
            free_drift_m=_per_leg(gnc, "free_drift_m"), relative=gnc.relative_to is not None)

    def leg(self, name: str, waypoint: int) -> float:
        """A per-leg setting (``transfer_s``, …) of the leg to ``waypoint`` (NaN: none)."""
        values = getattr(self, name)
        if values is None or waypoint >= len(values):
            return math.nan
        return float(values[waypoint])

    def target_m(self, waypoint: int) -> np.ndarray:
        """The position flown to while ``waypoint`` waypoints are reached (the last one
        once all are)."""
        return self.waypoints_m[min(waypoint, len(self.waypoints_m) - 1)]


def _per_leg(gnc, name: str) -> np.ndarray | None:
    """A waypoint setting as an array (NaN where unset), None when no waypoint sets it."""
    values = [getattr(w, name) for w in gnc.waypoints]
    if all(v is None for v in values):
        return None
    return np.array([math.nan if v is None else v for v in values], dtype=float)


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
    leg_start_s: float = math.nan
    """When (orbit s) the leg to the current waypoint began; NaN: not yet."""
    drifting: bool = False
    """In free drift (``free_drift_m``): no more firing."""
    braked: bool = False
    """The current leg's CW transfer has arrived and braked: the PD flies on."""


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


@dataclass(frozen=True)
class Reference:
    """What the GNC flies to at one instant (orbit units, R): a point with its velocity and
    acceleration, an attitude q_R_ref and its rate (relative to R, in R's axes)."""

    position_m: np.ndarray
    velocity_mps: np.ndarray
    accel_mps2: np.ndarray
    attitude_wxyz: np.ndarray
    omega_R_radps: np.ndarray


def moving_point(position_m, velocity_mps, attitude_wxyz, omega_rel_B_radps, offset_m,
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(r, v, ω_R) of the point ``offset_m`` (body frame of a satellite) of a satellite at
    (r_T, v_T, q_R_T, ω_T relative to R in its body axes): r_T + R_R_T p,
    v_T + ω × R_R_T p with ω = R_R_T ω_T the rate in R's axes. Works on (..., 3) rows."""
    R_R_T = quat_to_matrix(attitude_wxyz)
    d = R_R_T @ np.asarray(offset_m, dtype=float)
    w = np.einsum("...ij,...j->...i", R_R_T, omega_rel_B_radps)
    return position_m + d, velocity_mps + np.cross(w, d), w


def reference(params: GncParams, waypoint: int, target: Navigation | None) -> Reference:
    """The reference of ``waypoint`` (module doc): the fixed point, or the point of the
    target's body it names, moving with the target."""
    p = params.target_m(waypoint)
    if not params.relative:
        zero = np.zeros(3)
        return Reference(p, zero, zero, params.attitude_wxyz, zero)
    r, v, w = moving_point(target.position_m, target.velocity_mps, target.attitude_wxyz,
                           target.omega_rel_radps, p)
    a = (cw_acceleration(params.orbit_rate_radps, target.position_m, target.velocity_mps)
         + np.cross(w, np.cross(w, r - target.position_m)))
    return Reference(r, v, a, quat_mul(target.attitude_wxyz, params.attitude_wxyz), w)


def within_tolerance(params: GncParams, ref: Reference, nav: Navigation) -> bool:
    """|r − r_ref| < tolerance_m and |v − v_ref| < tolerance_mps."""
    return bool(np.linalg.norm(nav.position_m - ref.position_m) < params.tolerance_m
                and np.linalg.norm(nav.velocity_mps - ref.velocity_mps) < params.tolerance_mps)


def guidance(params: GncParams, state: GncState, nav: Navigation,
             target: Navigation | None = None) -> GncState:
    """The waypoint bookkeeping of one cycle: the hold starts when the satellite comes
    within tolerance, is dropped when it leaves, and once it has lasted ``hold_s`` the
    waypoint counts as reached and the next is the target (its leg begins now)."""
    if math.isnan(state.leg_start_s):
        state = replace(state, leg_start_s=nav.t_s)
    k = state.waypoint
    if k >= len(params.waypoints_m):
        return state
    if not within_tolerance(params, reference(params, k, target), nav):
        return replace(state, inside_since_s=math.nan)
    since = nav.t_s if math.isnan(state.inside_since_s) else state.inside_since_s
    if nav.t_s - since >= params.hold_s[k]:
        return replace(state, waypoint=k + 1, inside_since_s=math.nan, leg_start_s=nav.t_s,
                       braked=False)
    return replace(state, inside_since_s=since)


def cw_acceleration(orbit_rate_radps: float, position_m: np.ndarray,
                    velocity_mps: np.ndarray) -> np.ndarray:
    """The Clohessy–Wiltshire acceleration of a free body (Eqs. 1–3 without force):
    (3Ω²x + 2Ωẏ, −2Ωẋ, −Ω²z)."""
    w = orbit_rate_radps
    x, _, z = position_m
    vx, vy, _ = velocity_mps
    return np.array([3.0 * w * w * x + 2.0 * w * vy, -2.0 * w * vx, -w * w * z])


def translation_force_R(params: GncParams, nav: Navigation, ref: Reference | np.ndarray,
                        ) -> np.ndarray:
    """The force (R, N) the translation PD asks for (module doc):
    m (a_ref − ω_n² (r − r_ref) − 2 ζ ω_n (v − v_ref) − a_CW); ``ref`` a Reference or a
    fixed point."""
    if not isinstance(ref, Reference):
        zero = np.zeros(3)
        ref = Reference(np.asarray(ref, float), zero, zero, params.attitude_wxyz, zero)
    wn, zeta = params.position_omega_radps, params.position_damping
    a = (ref.accel_mps2 - wn * wn * (nav.position_m - ref.position_m)
         - 2.0 * zeta * wn * (nav.velocity_mps - ref.velocity_mps)
         - cw_acceleration(params.orbit_rate_radps, nav.position_m, nav.velocity_mps))
    return params.mass_kg * a


def transfer_force_R(params: GncParams, state: GncState, nav: Navigation, ref: Reference,
                     transfer_s: float) -> np.ndarray | None:
    """The force (R, N) of a CW transfer leg this period (module doc), or None once it has
    arrived and braked (the PD flies on then)."""
    left_s = state.leg_start_s + transfer_s - nav.t_s
    if left_s > RETARGET_FRACTION * transfer_s:
        try:
            dv, _ = two_impulse_transfer(nav.position_m, nav.velocity_mps, ref.position_m,
                                         ref.velocity_mps, left_s, params.orbit_rate_radps)
        except SingularTransfer:  # the time left is a half orbit: aim again next period
            return np.zeros(3)
        return params.mass_kg * dv / params.period_s
    if left_s > 0.0:
        return np.zeros(3)  # the coast
    if np.linalg.norm(nav.velocity_mps - ref.velocity_mps) >= params.tolerance_mps:
        return params.mass_kg * (ref.velocity_mps - nav.velocity_mps) / params.period_s
    return None


def approach_force_R(params: GncParams, nav: Navigation, ref: Reference, speed_mps: float,
                     ) -> np.ndarray:
    """The force (R, N) of a straight closing at ``speed_mps`` on the reference point:
    m (a_ref + 2 ζ ω_n (v_cmd − v) − a_CW), v_cmd = v_ref + u min(speed, ω_n d), u the unit
    vector to the point, d its distance."""
    wn, zeta = params.position_omega_radps, params.position_damping
    to_go = ref.position_m - nav.position_m
    d = float(np.linalg.norm(to_go))
    v_cmd = ref.velocity_mps + (to_go / d * min(speed_mps, wn * d) if d > 0.0 else 0.0)
    a = (ref.accel_mps2 + 2.0 * zeta * wn * (v_cmd - nav.velocity_mps)
         - cw_acceleration(params.orbit_rate_radps, nav.position_m, nav.velocity_mps))
    return params.mass_kg * a


def attitude_torque_B(params: GncParams, nav: Navigation, ref: Reference | None = None,
                      ) -> np.ndarray:
    """The torque (body axes, N m) the attitude PD asks for (module doc): quaternion error
    and rate relative to the reference (default: ``attitude_wxyz`` at rest in R), plus the
    gyroscopic and gravity-gradient torques cancelled."""
    wn, zeta, inertia = params.attitude_omega_radps, params.attitude_damping, params.inertia_kgm2
    q_ref = params.attitude_wxyz if ref is None else ref.attitude_wxyz
    omega_ref_B = np.zeros(3) if ref is None else nav.R_R_B.T @ ref.omega_R_radps
    q_e = quat_mul(q_ref * np.array([1.0, -1.0, -1.0, -1.0]), nav.attitude_wxyz)
    sign = -1.0 if q_e[0] < 0.0 else 1.0
    pd = -inertia * (2.0 * wn * wn * sign * q_e[1:]
                     + 2.0 * zeta * wn * (nav.omega_rel_radps - omega_ref_B))
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


def commanded_force_R(params: GncParams, state: GncState, nav: Navigation, ref: Reference,
                      ) -> tuple[GncState, np.ndarray]:
    """(the state, the force (R, N) asked of the thrusters this period) by how the current
    leg is flown (module doc); a CW transfer that has arrived and braked is marked
    ``braked`` (once: the PD flies on, a later push included)."""
    k = state.waypoint
    transfer_s = params.leg("transfer_s", k)
    if not math.isnan(transfer_s) and not state.braked:
        force = transfer_force_R(params, state, nav, ref, transfer_s)
        if force is not None:
            return state, force
        state = replace(state, braked=True)
    speed = params.leg("approach_speed_mps", k)
    if not math.isnan(speed):
        return state, approach_force_R(params, nav, ref, speed)
    return state, translation_force_R(params, nav, ref)


def gnc_step(params: GncParams, state: GncState, nav: Navigation, dt_s: float,
             target: Navigation | None = None) -> tuple[GncState, np.ndarray, np.ndarray]:
    """One loop cycle of the GNC (orbit units): (its new state, the thrusters' force in R
    (N), the wheels' torque in body axes (N m)) to hold over the cycle; ``target``: the
    satellite the waypoints are relative to (``relative_to``), as navigated.

    Guidance every cycle; a new command at the cycle nearest the start of each control
    period (``t + dt/2 ≥ next_update_s``), held until the next. In free drift, nothing."""
    state = guidance(params, state, nav, target)
    if state.drifting:
        return state, np.zeros(3), np.zeros(3)
    ref = reference(params, state.waypoint, target)
    drift_m = params.leg("free_drift_m", state.waypoint)
    if not math.isnan(drift_m) and np.linalg.norm(ref.position_m - nav.position_m) < drift_m:
        state = replace(state, drifting=True, force_B_N=np.zeros(3), torque_B_Nm=np.zeros(3))
        return state, np.zeros(3), np.zeros(3)
    if nav.t_s + 0.5 * dt_s >= state.next_update_s:
        state, force_R = commanded_force_R(params, state, nav, ref)
        state = replace(
            state, next_update_s=state.next_update_s + params.period_s,
            force_B_N=thruster_force_B(params, nav.R_R_B.T @ force_R),
            torque_B_Nm=wheel_torque_B(params, attitude_torque_B(params, nav, ref)))
    return state, nav.R_R_B @ state.force_B_N, state.torque_B_Nm
