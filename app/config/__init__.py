"""Typed, validated scenario configuration (TOML file -> pydantic models).

Every default reproduces the paper (Makhdoomi et al., Sections 4-5 and Table 1) or the
UR10e data sheet. Unknown keys, non-finite numbers and impossible values are rejected
with a message that names the field.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import tomllib
from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    StrictBool,
    ValidationError,
    model_validator,
)

from app.config.inputs import InputFileError, read_bounded_text
from app.sim.sensor_models import SENSOR_MODELS

__all__ = [
    "CaptureConfig",
    "ConfigError",
    "ContactMaterial",
    "EmulatorConfig",
    "GncConfig",
    "HandConfig",
    "LabConfig",
    "LoopConfig",
    "OrbitConfig",
    "PulseConfig",
    "RailConfig",
    "RobotConfig",
    "SatelliteConfig",
    "ScalingConfig",
    "SuccessConfig",
    "SensorConfig",
    "ServoConfig",
    "VfdmConfig",
    "WaypointConfig",
    "WrenchProcessingConfig",
    "dotted_override",
    "load_config",
    "parse_config",
]


def _orbit_rate(altitude_m: float) -> float:
    """Mean motion of a circular orbit (app/sim/orbital.py orbit_rate; config cannot import
    the simulator)."""
    return math.sqrt(3.986004418e14 / (6378.137e3 + altitude_m) ** 3)


class ConfigError(ValueError):
    """A configuration could not be read or is invalid; the message names the field."""


def _finite(v: float) -> float:
    if not math.isfinite(v):
        raise ValueError("must be a finite number")
    return v


Finite = Annotated[float, AfterValidator(_finite)]
Positive = Annotated[float, AfterValidator(_finite), Field(gt=0.0)]
NonNegative = Annotated[float, AfterValidator(_finite), Field(ge=0.0)]
Vec3 = tuple[Finite, Finite, Finite]
PositiveVec3 = tuple[Positive, Positive, Positive]


def _unit_quaternion(q: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    n = math.sqrt(sum(c * c for c in q))
    if n < 1e-9:
        raise ValueError("quaternion must be non-zero (w, x, y, z)")
    return tuple(c / n for c in q)  # type: ignore[return-value]


Quaternion = Annotated[tuple[Finite, Finite, Finite, Finite], AfterValidator(_unit_quaternion)]
IDENTITY_WXYZ = (1.0, 0.0, 0.0, 0.0)


class _Model(BaseModel):
    # use_attribute_docstrings: the docstring under a key is its description (the manual's
    # reference and the OpenAPI schema show it)
    model_config = ConfigDict(extra="forbid", frozen=True, use_attribute_docstrings=True)


class OrbitConfig(_Model):
    """Observer orbit and what the ODS does with the wrenches it receives."""

    altitude_m: Positive = 800e3
    """Altitude of the circular observer orbit whose frame R the ODS works in; it sets the
    orbit rate n of the Clohessy-Wiltshire equations (paper Eqs. 1-3)."""
    gravity_gradient: StrictBool = True
    """Apply the gravity-gradient torque to the attitude (paper Eqs. 4-6); false: the
    attitude is torque-free."""
    force_scale: NonNegative | None = None
    """The paper's law only: multiplies every measured force before it enters the ODS
    (default 1). Under [scaling] law = "similarity" it is derived, not set."""
    torque_scale: NonNegative | None = None
    """The paper's law only: multiplies every measured torque before it enters the ODS
    (default 1/2000, the paper's). Under "similarity" it is derived, not set."""


ScaleFactor = Annotated[float, AfterValidator(_finite), Field(ge=1e-6, le=1e6)]
"""An orbit-per-lab scale factor: within a millionth and a million."""
MAX_LAB_EQUIVALENT = 1e30
"""The largest lab-equivalent mass (kg) or inertia (kg m^2) a capture may join."""
HALF_ORBIT_MARGIN = 0.01
"""A CW transfer time this close to half an orbit (as a fraction of one) is refused."""
MAX_ORBIT_TURN_PER_CYCLE_RAD = 0.01
"""The most the orbit frame may turn in one loop cycle under a time scale (k_T Omega / rate):
beyond, the 2 ms step no longer resolves the orbit's own motions (a libration, CW)."""

PAPER_FORCE_SCALE = 1.0
PAPER_TORQUE_SCALE = 1.0 / 2000.0


class ScalingConfig(_Model):
    """How the lab plays the orbit (app/sim/scaling.py). ``paper``: the ODS integrates the
    mockup itself under the two hand-set knobs [orbit] force_scale and torque_scale.
    ``similarity``: each satellite is a virtual body (its mass_kg and inertia_kgm2, in
    orbit units; its initial state too) played at these orbit-per-lab factors."""

    law: Literal["paper", "similarity"] = "paper"
    """"paper" or "similarity" (see the table's description)."""
    length: ScaleFactor = 1.0
    """k_L: orbit metres per lab metre."""
    time: ScaleFactor = 1.0
    """k_T: orbit seconds per lab second (100: a 100 s orbit phenomenon plays in 1 s)."""
    mass: ScaleFactor = 1.0
    """k_M: orbit kilograms per lab kilogram (what a lab newton is worth: k_M k_L / k_T² N)."""


MAX_WAYPOINTS = 100


class WaypointConfig(_Model):
    """A point a satellite's GNC flies to (orbit units)."""

    position_m: Vec3
    """In R (orbit metres)."""
    hold_s: NonNegative = 0.0
    """How long (orbit s) it must stay within tolerance before the next waypoint."""
    transfer_s: Positive | None = None
    """Fly the leg to this waypoint as a Clohessy-Wiltshire two-impulse transfer of this
    duration (orbit s), re-targeted every control period, then brake and hold (none: the
    PD flies it). Less than 0.9 of an orbit, and not within 1 % of an orbit of half of
    one; waypoints in R only."""
    approach_speed_mps: Positive | None = None
    """Fly the leg to this waypoint as a straight closing at this speed (orbit m/s)."""
    free_drift_m: Positive | None = None
    """Within this distance (orbit m) of this waypoint, stop firing for good and drift
    (a docking's last stretch into the interface)."""

    @model_validator(mode="after")
    def _one_way_to_fly(self) -> WaypointConfig:
        if self.transfer_s is not None and self.approach_speed_mps is not None:
            raise ValueError("transfer_s and approach_speed_mps: a leg is flown one way; "
                             "give one of them")
        return self


Damping = Annotated[float, AfterValidator(_finite), Field(gt=0.0, le=2.0)]


class GncConfig(_Model):
    """A satellite's own guidance, navigation and control (app/sim/gnc.py), in ORBIT units:
    thrusters and reaction wheels whose wrench goes straight into the ODS (not through the
    F/T sensor). Translation PD with the Clohessy-Wiltshire terms cancelled, attitude
    quaternion PD; both sampled every ``period_s`` and held."""

    waypoints: Annotated[list[WaypointConfig], Field(min_length=1, max_length=MAX_WAYPOINTS)]
    """Flown in order; the last is held."""
    relative_to: str | None = None
    """Another satellite's name: the waypoints and ``attitude_wxyz`` are then in its body
    frame (from its centre of mass) and move with it; the GNC synchronises with it."""
    position_omega_radps: Positive = 0.1
    """Natural frequency of the translation PD (kp = omega^2, kd = 2 zeta omega)."""
    position_damping: Damping = 0.8
    """Damping ratio of the translation PD."""
    attitude_omega_radps: Positive = 0.2
    """Natural frequency of the attitude PD."""
    attitude_damping: Damping = 0.8
    """Damping ratio of the attitude PD."""
    attitude_wxyz: Quaternion = IDENTITY_WXYZ
    """The attitude held, relative to R (or to ``relative_to``'s body)."""
    thrust_max_N: Positive = 1.0
    """Per body axis, each direction."""
    min_impulse_bit_Ns: NonNegative = 0.01
    """An axis whose impulse over a control period is below this is not fired."""
    torque_max_Nm: Positive = 0.1
    """Reaction wheels, per body axis."""
    period_s: Positive = 1.0
    """Control period (orbit s): the command is computed, then held, once per period."""
    tolerance_m: Positive = 0.05
    """Within tolerance of a waypoint: closer than this (orbit m) ..."""
    tolerance_mps: Positive = 0.005
    """... and slower than this (orbit m/s); reached once held so for its hold_s."""

    @model_validator(mode="after")
    def _can_fire_and_is_stable(self) -> GncConfig:
        if self.min_impulse_bit_Ns >= self.thrust_max_N * self.period_s:
            raise ValueError(
                f"min_impulse_bit_Ns: {self.min_impulse_bit_Ns:g} N s is not below a whole "
                f"period at full thrust ({self.thrust_max_N * self.period_s:g} N s): the "
                f"thrusters would never fire")
        for name in ("position", "attitude"):
            omega, zeta = getattr(self, f"{name}_omega_radps"), getattr(self, f"{name}_damping")
            if sampled_pd_radius(omega * self.period_s, zeta) >= 1.0:
                raise ValueError(
                    f"{name}_omega_radps: {omega:g} rad/s with damping {zeta:g}, sampled "
                    f"every {self.period_s:g} s, is unstable (the held PD of a double "
                    f"integrator): lower the frequency or the period")
        return self


def sampled_pd_radius(omega_period: float, damping: float) -> float:
    """Spectral radius of a double integrator under a PD (kp = ω², kd = 2ζω) sampled and
    held every T, as a function of ωT: x' = (A − B K) x with A = [[1, T], [0, 1]],
    B = [T²/2, T]; below 1 it converges."""
    w, T = omega_period, 1.0
    closed = np.array([[1.0 - w * w / 2.0, T - damping * w],
                       [-w * w, 1.0 - 2.0 * damping * w]])
    return float(np.max(np.abs(np.linalg.eigvals(closed))))


class SatelliteConfig(_Model):
    """One satellite: its mockup and its initial state (all relative to R)."""

    name: Annotated[str, Field(min_length=1, max_length=64)]
    """Its name, referred to by pulses, robots and capture."""
    mass_kg: Positive = 1.0
    """The body the ODS integrates (under the paper's law: the mockup itself)."""
    size_m: PositiveVec3 = (0.2, 0.2, 0.1)
    """The mockup's box (lab metres): contact, drawing, and the default inertia."""
    size_error_m: Annotated[float, AfterValidator(_finite), Field(ge=-0.01, le=0.01)] = 0.0
    """How much larger along each axis the mockup as built is than ``size_m`` (negative:
    smaller): the contact happens at the built size, while the lab's geometry (the contact
    gate, the estimator's normal and point, the identification's depth) uses ``size_m``,
    the drawing. 0: built as drawn."""
    inertia_kgm2: PositiveVec3 | None = None
    """Principal moments [Ixx, Iyy, Izz]; default: uniform box of mass_kg and size_m
    (times the length scale under "similarity")."""
    mockup_mass_kg: Positive | None = None
    """The physical mockup the arm carries (its sensor chain compensates it); default:
    mass_kg under the paper's law, required under "similarity"."""
    position_m: Vec3 = (0.0, 0.0, 0.0)
    """Initial position in R (x radial, y along-track, z orbit normal)."""
    velocity_mps: Vec3 = (0.0, 0.0, 0.0)
    """Initial velocity relative to R, in R."""
    attitude_wxyz: Quaternion = IDENTITY_WXYZ
    """Initial attitude relative to R, unit quaternion, scalar first."""
    omega_radps: Vec3 = (0.0, 0.0, 0.0)
    """Angular velocity relative to R, body axes (zero: at rest in the lab)."""
    material: Literal["rigid", "sponge"] = "rigid"
    """The mockup's contact face: "rigid" or "sponge", with the properties [materials]
    gives that name (a [materials] table may hold other names, but a satellite names one
    of these two)."""
    gnc: GncConfig | None = None
    """The satellite's own thrusters and wheels under a GNC (none: it is free)."""

    @model_validator(mode="after")
    def _inertia_is_physical(self) -> SatelliteConfig:
        if self.inertia_kgm2 is not None:
            a, b, c = self.inertia_kgm2
            if a + b < c or b + c < a or a + c < b:
                raise ValueError(
                    "inertia_kgm2 violates the triangle inequality of principal moments"
                )
        return self

    def principal_inertia(self) -> np.ndarray:
        """Principal inertia; a uniform box of size_m when not given."""
        if self.inertia_kgm2 is not None:
            return np.array(self.inertia_kgm2, dtype=float)
        sx, sy, sz = self.size_m
        m = self.mass_kg
        return m / 12.0 * np.array([sy**2 + sz**2, sx**2 + sz**2, sx**2 + sy**2])


class PulseConfig(_Model):
    """A scripted push: constant force (in R) and torque (body axes) over [start_s, end_s)."""

    satellite: str
    """The satellite pushed (its name)."""
    start_s: NonNegative
    """When the push begins (scenario time)."""
    end_s: NonNegative
    """When it ends (after start_s)."""
    force_N: Vec3 = (0.0, 0.0, 0.0)
    """Constant force, in R."""
    torque_Nm: Vec3 = (0.0, 0.0, 0.0)
    """Constant torque, body axes."""

    @model_validator(mode="after")
    def _ordered(self) -> PulseConfig:
        if self.end_s <= self.start_s:
            raise ValueError("end_s must be greater than start_s")
        return self


class LabConfig(_Model):
    """Where the CW frame R sits in the lab frame W (z up)."""

    r_origin_m: Vec3 = (0.0, 0.0, 1.0)
    """Where R's origin is in the lab frame W (the point the satellites orbit about)."""
    r_attitude_wxyz: Quaternion = IDENTITY_WXYZ
    """R's attitude in W, unit quaternion, scalar first."""
    gravity_mps2: Vec3 = (0.0, 0.0, -9.81)
    """The lab's gravity in W (what the F/T sensors feel from the mockups' weight)."""


MAX_RAIL_TRAVEL_M = 50.0
"""The farthest a rail's travel may reach from the base's position: longer than any lab's
robot track (the longest tracks sold are some tens of metres)."""


class RailConfig(_Model):
    """A linear axis (the robot's "7th axis") under a robot's base (app/sim/rail.py).

    The carriage moves the base along ``axis_W`` (a direction in the lab frame W, normalised
    here): with the carriage at s, the base sits at ``base_position_m + s · axis_W``, its
    attitude unchanged. ``travel_m`` bounds s; ``start_m`` is where the carriage starts.

    The servo (delay, second-order response, speed and acceleration limits, protective stop
    at the travel ends and on a set-point's speed or acceleration beyond the limits) is the
    joints' (ServoConfig) in metres.

    The defaults' sources, plainly: they are not one product's. No data sheet of a robot
    track (Güdel TrackMotion, KUKA KL, ABB IRBT, Festo, Yaskawa) with its speed,
    acceleration or servo figures could be consulted for this project; the one product
    figure found, 1.89 m/s for KUKA's KL 4000 track (payload up to 4000 kg), is quoted
    second-hand (a support article citing it, not KUKA's data sheet). So:
    ``speed_limit_mps`` 1 m/s, below that figure and equal to the UR10e's TCP speed limit
    (what the pre-flight lets a course ask of the arm it carries); ``accel_limit_mps2``
    1 m/s², the default maximum axis acceleration of a linear axis in Beckhoff's TwinCAT
    CNC (parameter P-AXIS-00008, 1000 mm/s²: a controller's presetting, not a track's
    rating); ``bandwidth_hz`` 10 Hz, ``damping_ratio`` 1, ``velocity_feedforward`` and
    ``delay_cycles`` 1 are this project's assumptions with no source (a carriage carrying
    a 40 kg arm answering several times slower than the arm's joints, tuned to follow a
    path, one cycle late as the arm's servo is). Set them from your axis's data sheet or
    a measured step response.

    ``virtual_mass_kg`` and ``posture_stiffness_Nm_per_rad`` belong to the VFDM's virtual
    model (app/sim/rail.py explains them): the carriage's conditioned mass and the spring
    that pulls the arm's joints toward ``posture_rad`` through the chain's null space (None:
    the arm's start posture, the one that holds the satellite's start pose with the
    carriage at ``start_m``; a posture whose TCP the rail cannot bring to the target keeps
    the carriage moving to no end).
    """

    axis_W: Vec3 = (1.0, 0.0, 0.0)
    """The direction the carriage moves the base along, in the lab frame W (normalised)."""
    travel_m: tuple[Finite, Finite] = (-2.0, 2.0)
    """[min, max] of the carriage's position s along ``axis_W`` (s = 0: the base at
    ``base_position_m``); reaching an end is a protective stop."""
    start_m: Finite = 0.0
    """Where the carriage starts, within ``travel_m``."""
    speed_limit_mps: Positive = 1.0
    """The carriage's speed limit [m/s]; a set-point asking for more is a protective stop
    (default: the UR10e's TCP limit, below the one track figure found, KUKA KL 4000's
    1.89 m/s, second-hand; the Rails page says where each default comes from)."""
    accel_limit_mps2: Positive = 1.0
    """The carriage's acceleration limit [m/s²]; a set-point asking for more is a
    protective stop (default: TwinCAT CNC's presetting of a linear axis, P-AXIS-00008 =
    1000 mm/s²; no track data sheet)."""
    bandwidth_hz: Positive = 10.0
    """Natural frequency [Hz] of the carriage's position loop, a second-order response (an
    assumption, no source)."""
    damping_ratio: Positive = 1.0
    """Damping ratio of the carriage's position loop (1: critical; an assumption)."""
    delay_cycles: Annotated[int, Field(ge=0, le=100)] = 1
    """Transport delay of a carriage set-point, in loop cycles (the arm servo's; an
    assumption)."""
    velocity_feedforward: StrictBool = True
    """The drive feeds the set-points' speed forward (as a following axis is tuned): on a
    ramp the carriage trails by its delay only (app/sim/rail_servo.py)."""
    virtual_mass_kg: Positive = 1.0
    """The carriage's mass in the VFDM's virtual model (a conditioning figure, not the real
    carriage's; 1 kg as Table 1's end link): the inertia of the chain's null-space motion
    (the carriage moving while the arm holds the TCP), which follows the posture spring
    the slower the heavier it is; the Cartesian response does not depend on it."""
    posture_stiffness_Nm_per_rad: NonNegative = 0.5
    """Stiffness K of the virtual joint spring that pulls the arm's joints toward
    ``posture_rad`` through the chain's null space, so that the rail carries the gross
    motion and the arm the fine (0: no pull; the carriage then moves only by the small
    share of a Cartesian push the arm leaves it)."""
    posture_rad: tuple[Finite, Finite, Finite, Finite, Finite, Finite] | None = None
    """The joint posture the spring pulls toward (None: the arm's start posture, the one
    that holds the satellite's start pose with the carriage at ``start_m``)."""

    @model_validator(mode="after")
    def _rail(self) -> RailConfig:
        big = max(abs(c) for c in self.axis_W)  # (scaled first: 1e200 squared overflows)
        n = big * math.sqrt(sum((c / big) ** 2 for c in self.axis_W)) if big > 0 else 0.0
        if not 1e-9 <= n < math.inf:
            raise ValueError("axis_W must be a non-zero direction in the lab frame W")
        if n != 1.0:
            object.__setattr__(self, "axis_W", tuple(c / n for c in self.axis_W))
        lo, hi = self.travel_m
        if not lo < hi:
            raise ValueError(f"travel_m must be [min, max] with min < max, got [{lo:g}, {hi:g}]")
        if max(abs(lo), abs(hi)) > MAX_RAIL_TRAVEL_M:
            raise ValueError(f"travel_m must lie within ±{MAX_RAIL_TRAVEL_M:g} m of the base's "
                             f"position (a lab's track), got [{lo:g}, {hi:g}]")
        if not lo <= self.start_m <= hi:
            raise ValueError(f"start_m = {self.start_m:g} is outside travel_m = "
                             f"[{lo:g}, {hi:g}]")
        return self


class RobotConfig(_Model):
    """One UR10e: base pose in W, home posture, mockup mounting and safety volume."""

    name: Annotated[str, Field(min_length=1, max_length=64)]
    """The arm's name."""
    satellite: str
    """The satellite whose mockup this arm carries (its name)."""
    base_position_m: Vec3 = (0.0, 0.0, 0.0)
    """The arm's base in W."""
    base_attitude_wxyz: Quaternion = IDENTITY_WXYZ
    """The base's attitude in W (the ceiling arm is upside down)."""
    q_home_rad: tuple[Finite, Finite, Finite, Finite, Finite, Finite] = (
        0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0,
    )
    """Joint angles the arm starts from before it approaches the start pose."""
    mockup_offset_m: Vec3 = (0.0, 0.0, 0.07)
    """Mockup centre of mass (= TCP) in the flange frame."""
    mockup_attitude_wxyz: Quaternion = IDENTITY_WXYZ
    """Rotation from the flange frame to the mockup (satellite body) frame."""
    safety_box_min_m: Vec3 = (-1.5, -1.5, 0.05)
    """Lower corner (in W) of the box the mockup's centre must stay in; leaving it is a
    protective stop."""
    safety_box_max_m: Vec3 = (1.5, 1.5, 2.4)
    """Upper corner (in W) of the same box."""
    rail: RailConfig | None = None
    """The linear axis under the base (None: the base is fixed at base_position_m)."""

    @model_validator(mode="after")
    def _box(self) -> RobotConfig:
        pairs = zip(self.safety_box_min_m, self.safety_box_max_m, strict=True)
        if any(lo >= hi for lo, hi in pairs):
            raise ValueError("safety_box_min_m must be below safety_box_max_m on every axis")
        return self


class VfdmConfig(_Model):
    """VFDM Cartesian motion controller (paper Eqs. 10-13, Table 1)."""

    kp_lin: NonNegative = 10.0
    """Proportional gain on the position error (paper Eq. 13)."""
    kp_rot: NonNegative = 1.0
    """Proportional gain on the orientation error (Eq. 13)."""
    kd_lin: NonNegative = 0.0
    """Derivative gain on the linear velocity error (Eq. 13; 0 in the paper)."""
    kd_rot: NonNegative = 0.0
    """Derivative gain on the angular velocity error."""
    error_scale: Positive = 1.0
    """Scales the pose error before the PD law."""
    end_mass_kg: Positive = 1.0
    """Mass of the virtual arm's last link (Table 1)."""
    end_inertia_kgm2: Positive = 1.0
    """Inertia I_e of the last link about each axis at the TCP (Table 1)."""
    link_mass_kg: Positive = 0.01
    """Mass of every other virtual link (Table 1: nearly massless)."""
    link_inertia_ratio: Positive = 1e-6
    """Every other link's inertia as a fraction of I_e (Table 1)."""
    joint_armature_kgm2: Annotated[float, AfterValidator(_finite), Field(ge=0.0, le=10.0)] = 0.0025
    """Rotor inertia of every virtual joint (not in Table 1; 0 is the paper's model): damps
    the virtual arm's motion near a singularity as damped least squares with λ² = armature
    / end inertia does (0.0025: λ = 0.05), so that the wrist does not swing through q5 = 0
    (app/sim/vfdm.py)."""
    iterations: Annotated[int, Field(ge=1, le=1000)] = 10
    """Virtual-model steps per control cycle."""
    internal_dt_s: Positive = 0.02
    """Virtual-model integration step, independent of the control period (as in the FZI
    cartesian_controllers the paper builds on): 10 steps x 0.02 s = 0.2 s of virtual time
    per cycle. At 0.002 s a 0.05 m/s target lags by ~27 mm; at 0.02 s by ~0.27 mm."""
    max_error_lin_m: Positive = 1.0
    """The position error is clamped to this before the PD law (Eq. 13)."""
    max_error_rot_rad: Positive = 1.0
    """The orientation error is clamped to this."""
    velocity_mode: Literal["damped", "reset"] = "damped"
    """"damped": the virtual joint velocity persists, damped by `damping` each step;
    "reset": zeroed every cycle."""
    damping: Annotated[float, AfterValidator(_finite), Field(ge=0.0, lt=1.0)] = 0.1
    """Fraction of virtual joint velocity removed per internal step (mode 'damped')."""
    velocity_feedforward: StrictBool = True
    """Add the target's velocity as a feedforward wrench (not in the paper): without it the
    virtual damping leaves the arm a steady lag behind a moving target (app/sim/vfdm.py
    target_feedforward). It answers that damping, so it does nothing where there is none:
    ``velocity_mode = "reset"`` or ``damping = 0``."""
    sync_to_measured: StrictBool = False
    """Each cycle, start the virtual arm from the measured joint positions (as FZI's
    cartesian_controllers can): the set-points then never drift from the real arm, at the
    cost of the servo's lag entering the virtual model."""
    limit_fraction: Annotated[float, AfterValidator(_finite), Field(gt=0.0, le=1.0)] = 0.95
    """The set-points ask each joint for at most this fraction of the servo's speed and
    acceleration limits: a cycle's joint step beyond the speed limit is scaled down as a
    whole (its direction kept, as the UR controller's speed scaling does), and its change
    from the last step is then held within the acceleration limit."""


UR10E_SPEED_LIMITS_RADPS = (
    math.radians(120), math.radians(120), math.radians(180),
    math.radians(180), math.radians(180), math.radians(180),
)


SERVOJ_LOOKAHEAD_RANGE_S = (0.03, 0.2)
"""UR's script manual, servoj: lookahead_time, range [0.03, 0.2] s."""
SERVOJ_GAIN_RANGE = (100.0, 2000.0)
"""UR's script manual, servoj: gain, range [100, 2000]."""
SERVOJ_DEFAULT_LOOKAHEAD_S = 0.03
SERVOJ_DEFAULT_GAIN = 1200.0
"""servoj(q, t=0.002, lookahead_time=0.03, gain=1200): as a lab streaming over RTDE at 2 ms
drives it (Universal_Robots_Client_Library issue #86)."""


def _within(lo: float, hi: float, what: str):
    def check(v: float | None) -> float | None:
        if v is not None and not (math.isfinite(v) and lo <= v <= hi):
            raise ValueError(f"{v!r} is outside servoj's {what} range [{lo:g}, {hi:g}] "
                             f"(UR script manual)")
        return v
    return AfterValidator(check)


class ServoConfig(_Model):
    """Simulated UR10e position servo (app/sim/servo.py).

    ``model``: "second-order" tracks each set-point with a response of ``bandwidth_hz``
    and ``damping_ratio``; "servoj" answers as UR's servoj(q, t, lookahead_time, gain)
    does (the acceleration is ``gain`` times the error between the target and the current
    position projected ``lookahead_time_s`` ahead with the current velocity). Both keep
    the transport delay, the speed and acceleration limits and the protective stops.
    """

    model: Literal["second-order", "servoj"] = "second-order"
    """"second-order": critically damped tracking of the set-points; "servoj": the UR
    controller's servoj over RTDE (docs: sensors)."""
    bandwidth_hz: Positive = 50.0
    """The tracking's natural frequency."""
    damping_ratio: Positive = 1.0
    """The tracking's damping ratio (1: critical)."""
    delay_cycles: Annotated[int, Field(ge=0, le=100)] = 1
    """Transport delay of a set-point, in loop cycles."""
    speed_limits_radps: tuple[Positive, Positive, Positive, Positive, Positive, Positive] = (
        UR10E_SPEED_LIMITS_RADPS
    )
    """Joint speed limits (UR10e data sheet); beyond is a protective stop."""
    accel_limit_radps2: Positive = 40.0
    """Joint acceleration limit the tracking saturates at."""
    position_limit_rad: Positive = 2.0 * math.pi
    """Joint position limit (±); beyond is a protective stop."""
    lookahead_time_s: Annotated[float | None,
                                _within(*SERVOJ_LOOKAHEAD_RANGE_S, "lookahead_time")] = None
    """servoj only: how far ahead (s) the target is projected with the current velocity,
    0.03 to 0.2 s as UR's servoj takes it (None: 0.03 s)."""
    gain: Annotated[float | None, _within(*SERVOJ_GAIN_RANGE, "gain")] = None
    """servoj only: the proportional gain from the projected error to the acceleration,
    100 to 2000 as UR's servoj takes it (None: 1200)."""

    @model_validator(mode="after")
    def _servoj_only(self) -> ServoConfig:
        if self.model != "servoj":
            for key in ("lookahead_time_s", "gain"):
                if getattr(self, key) is not None:
                    raise ValueError(f"{key} is servoj's; it has no effect with model = "
                                     f"{self.model!r} (set model = \"servoj\", or leave "
                                     f"{key} out)")
        return self

    @property
    def servoj_lookahead_s(self) -> float:
        return SERVOJ_DEFAULT_LOOKAHEAD_S if self.lookahead_time_s is None \
            else self.lookahead_time_s

    @property
    def servoj_gain(self) -> float:
        return SERVOJ_DEFAULT_GAIN if self.gain is None else self.gain


SENSOR_MODEL_FIELDS = ("range_force_N", "range_torque_Nm", "noise_force_N",
                       "noise_torque_Nm", "sample_rate_hz", "delay_cycles")
"""The [sensor] settings a model fills when they are not given."""


class SensorConfig(_Model):
    """Virtual F/T sensor (app/sim/ft_sensor.py).

    ``model`` names a sensor whose data sheet fills range, noise, sample rate and delay
    (app/sim/sensor_models.py, where each figure is cited); any of them given here
    overrides the model's. The defaults are the UR10e's built-in sensor.

    ``placement``: "flange", the sensor in the tool flange, carrying the whole mockup;
    "mockup", between the mockup body and its contact face: it carries only the face
    (``face_mass_kg``, centred at ``face_position_m`` in the body frame, where the sensor's
    origin is, its axes the body's), so the chain compensates that small mass, not the
    mockup's.
    """

    model: Literal["ur10e", "ati-gamma", "ati-mini45", "robotiq-ft300s"] = "ur10e"
    """The sensor whose data sheet fills range, noise, sample rate and delay
    (app/sim/sensor_models.py)."""
    range_force_N: Positive = 100.0
    """Force range per axis: readings saturate there, and a reading at the range stops the
    run."""
    range_torque_Nm: Positive = 10.0
    """Torque range per axis."""
    noise_force_N: NonNegative = 5.0 / 3.0
    """Standard deviation; the data sheet's precision of ±5 N read as a 3-sigma bound."""
    noise_torque_Nm: NonNegative = 0.2 / 3.0
    """Standard deviation of the torque noise."""
    sample_rate_hz: Positive | None = None
    """New readings per second; below the loop's rate each is held until the next. None:
    one every loop cycle."""
    bias_force_N: Vec3 = (1.5, -0.8, 2.0)
    """Constant force offset of the readings (removed by the calibration at rest)."""
    bias_torque_Nm: Vec3 = (0.05, -0.03, 0.02)
    """Constant torque offset of the readings."""
    delay_cycles: Annotated[int, Field(ge=0, le=100)] = 1
    """Loop cycles between a load and its reading."""
    placement: Literal["flange", "mockup"] = "flange"
    """"flange" or "mockup" (see the table's description)."""
    face_mass_kg: Annotated[float, AfterValidator(_finite), Field(ge=0.0, le=10.0)] = 0.05
    """placement "mockup" only: the contact face's mass behind the sensor."""
    face_position_m: Vec3 = (0.0, 0.0, 0.0)
    """placement "mockup" only: the sensor's origin (the face's centre of mass) in the
    body frame."""

    @model_validator(mode="after")
    def _fill_from_model(self) -> SensorConfig:
        """The model's figure for each of SENSOR_MODEL_FIELDS not given (the given ones
        stay: they are not in model_fields_set's complement)."""
        sheet = SENSOR_MODELS[self.model]
        for key in SENSOR_MODEL_FIELDS:
            if key not in self.model_fields_set:
                object.__setattr__(self, key, getattr(sheet, key))
        return self


class WrenchProcessingConfig(_Model):
    """What the lab does to a raw F/T reading before the ODS sees it."""

    payload_compensation: StrictBool = True
    """Subtract the mockup's weight (known mass and COM) from the readings."""
    inertial_compensation: StrictBool = True
    """Subtract the mockup's inertial load m a from the readings."""
    lowpass_hz: Positive = 30.0
    """Cut-off of the low-pass filter on the compensated wrench."""
    contact_lowpass_hz: Positive | None = None
    """The low-pass's cut-off while the contact gate is open (None: ``lowpass_hz``). A
    contact's force reaches the ODS sooner through a faster filter, and the lag
    compensation's lead, which holds the input over it, shrinks with it (its miss grows
    as lead³: app/sim/compensation.py). Without the contact gate it has no effect."""
    calibration_s: Annotated[float, AfterValidator(_finite), Field(ge=0.1, le=60.0)] = 2.0
    """Seconds of readings at rest averaged for the bias calibration at start-up. What is
    left of the bias is about noise_force_N / sqrt(calibration_s · rate_hz) per axis
    (0.04 N at the defaults, 0.15 N after 0.25 s): an offset the ODS receives wherever a
    deadband is lifted (the contact gate, or a zero deadband). At least 0.1 s: shorter,
    the bias left (0.75 N per axis after 10 ms) plus the noise clear the deadband."""
    deadband_force_N: NonNegative = 4.0
    """Force deadband: a smaller processed force is read as zero."""
    deadband_torque_Nm: NonNegative = 0.25
    """On the torque about the COM, which carries the sensor's torque noise and the lever
    arm of its force noise (std ≈ 0.06 N·m per axis after the low-pass, for the 0.07 m
    mockup offset): about 4 σ."""
    deadband_noise_sigmas: Annotated[float, AfterValidator(_finite), Field(ge=0.0)] = 6.0
    """Each deadband is at least this many standard deviations of the filtered noise the
    start-up calibration measured at rest (largest principal axis; 0: the configured
    deadbands only). At 6 the noise at rest crosses it about once in 6 hours
    (app/sim/ft_sensor.py, WrenchProcessor, noise floor): nothing moves at rest."""
    deadband_mode: Literal["hard", "soft"] = "hard"
    """'hard': zero below the threshold, unchanged above (keeps the size of real pushes);
    'soft': zero below, magnitude reduced by the threshold above (continuous)."""
    contact_gate: StrictBool = False
    """Contact-aware deadband (app/sim/contact_gate.py): while the lab's geometry (the
    mockups' boxes at their measured poses) has a mockup touching another body, or within
    ``contact_gate_margin_m`` of one and closing in, its deadbands are lifted, so that a
    contact below the noise threshold reaches the ODS whole. Off: the deadband always
    applies (the paper)."""
    contact_gate_margin_m: Annotated[float, AfterValidator(_finite),
                                     Field(ge=0.0, le=0.01)] = 0.001
    """How close (m) a mockup closing in on another opens its gate. At most 1 cm: the
    open gate lets the sensor's noise through for margin / closing speed before the
    touch (60 ms at the paper's 0.16 m/s, as long as the sponge contact itself)."""
    fuse_pair_contact: StrictBool = False
    """With the contact gate: while two carried mockups touch only each other, hand both
    satellites the one estimate ±(F_b − F_a)/2 of the two sensors (app/sim/contact_gate.py):
    the exchanged momentum balances exactly, the noise per satellite drops by √2. Only
    while the two sensors agree with Newton's third law within their measured noise (a
    push on either is passed as measured)."""
    contact_estimator: StrictBool = False
    """With the contact gate: while the gate is open for a mockup in one contact, hand its
    satellite the measured force projected on the contact's friction cone (tangential part
    at most μ times the normal part, a pull zeroed with ``contact_no_pull``; the normal and
    point from the
    mockups' known boxes at their measured poses, μ from the materials) and the moment of
    that force at the contact point as its torque (app/sim/contact_estimator.py)."""
    contact_no_pull: StrictBool = False
    """With the contact estimator: a measured normal force that pulls becomes zero. Off:
    it passes as measured (the clamp rectifies the noise where the true force is near zero
    and biases the restitution: app/sim/contact_estimator.py)."""
    contact_force: Literal["measured", "identified"] = "measured"
    """With the contact estimator, the normal force handed to the ODS: 'measured' (the
    processed F/T force), or 'identified': the Hunt–Crossley law identified by least
    squares from the measured normal forces and the contact's depth and rate (the mockups'
    boxes at their encoder poses) of every cycle of the pair's contact so far, evaluated
    at the reading's cycle (app/sim/contact_identification.py): the sensor's noise is
    averaged over the contact instead of handed over cycle by cycle."""


class CompensationConfig(_Model):
    """Lag compensation of the emulation loop (app/sim/compensation.py).

    The arm is commanded to where the ODS predicts its satellite will be ``lead_s``
    later, the lag from an ODS pose to the mockup pose plus the lag from a contact on the
    mockup to the ODS's input: the contact then happens, and its measured force arrives,
    in step with the virtual satellites. Off by default (the paper has none).
    """

    enabled: StrictBool = False
    """Switch the lag compensation on."""
    lead_s: Annotated[float, AfterValidator(_finite), Field(gt=0.0, le=0.1)] | None = None
    """None: the loop's own lag model (servo delay and bandwidth, VFDM, sensor delay,
    filter, zero-order hold). Only with ``enabled`` (a lead of 0 would be ``enabled =
    false``)."""
    servo_feedforward: StrictBool | None = None
    """Invert the servo's known tracking law (app/sim/feedforward.py): send
    ``q_d + (k_d/k_p) q̇_d + q̈_d/k_p`` (servoj: ``q_d + lookahead · q̇_d + q̈_d / gain``)
    so that the arm follows the VFDM's set-points ``q_d`` instead of lagging and ringing
    behind them; the lead is left the transport delay. None: on with ``[servo] model =
    "servoj"``, off with "second-order". Only with ``enabled``."""
    servo_correction_hz: Annotated[float, AfterValidator(_finite), Field(ge=0.0, le=50.0)] = 16.0
    """With the servo feedforward: the bandwidth (critically damped) at which the lab
    corrects the arm's tracking error from the joints it reports (Eq. FC,
    app/sim/feedforward.py); 0 sends the inverse of the law alone (Eq. FF), as does a
    servo whose own loop is faster (the default second-order servo's 50 Hz). 16 Hz keeps the
    phase the transport delay and the cycle cost the correction at 4 ms × 2π · 16 Hz = 23°;
    at 32 Hz the rigid collision on servoj ended in protective stops (tuning seeds
    1000-1001)."""

    @model_validator(mode="after")
    def _lead_needs_enabled(self) -> CompensationConfig:
        for key in ("lead_s", "servo_feedforward"):
            if getattr(self, key) is not None and not self.enabled:
                raise ValueError(f"{key} is set but enabled is false: it would have no "
                                 f"effect (set enabled = true, or leave {key} out)")
        return self


def _two_or_more(n: int) -> int:
    if n < 2:
        raise ValueError(f"must be 2 or more (a standard deviation needs two replicates), "
                         f"got {n}")
    return n


UNCERTAINTY_REPLICATES = 30
"""[uncertainty] replicates when not given."""
UNCERTAINTY_FORECAST_REPLICATES = 200
"""[uncertainty] forecast_replicates when not given."""
UNCERTAINTY_LEAD_S = 0.15
"""[uncertainty] lead_s when not given."""


class UncertaintyConfig(_Model):
    """The restitution's uncertainty (app/runs/uncertainty.py; docs/fidelity-uncertainty.md).

    A hil run keeps a snapshot of the whole loop ``lead_s`` before the contact its ideal
    run predicts; after the run, ``replicates`` copies of the contact window run from it
    through the same loop, each with fresh sensor noise of the covariance measured at the
    start-up calibration; their spread is the restitution's standard deviation. The
    pre-flight forecasts it the same way on a noise-free twin, with the configured noise.
    The other settings only with ``enabled`` (with it off they would have no effect).
    """

    enabled: StrictBool = True
    """Report the restitution's 95 % interval and the pre-flight's forecast."""
    replicates: Annotated[int, AfterValidator(_two_or_more), Field(le=1000)] | None = None
    """Replicates of a run's contact window (None: 30; the sd of 30 is known to about
    ±13 %)."""
    forecast_replicates: Annotated[int, AfterValidator(_two_or_more),
                                   Field(le=1000)] | None = None
    """Replicates of the pre-flight's forecast (None: 200, its sd known to about ±5 %). Its
    draws are the configuration's, the same for every seed, so its sampling error is not
    averaged out over a campaign: with 60 (±9 %) the rigid collision's forecast read 0.113
    where 600 give 0.099 (benchmarks/README.md, "The forecast's own sampling error, and
    the spread over 200 seeds")."""
    lead_s: Annotated[float, AfterValidator(_finite), Field(ge=0.1, le=5.0)] | None = None
    """How long before the ideal run's first touch the snapshot is taken (None: 0.15 s):
    the approach speed (read 50 ms before the first touch) and the contact gate's opening
    must be in the replicated window. A lead longer than the time to the first touch
    takes the snapshot at t = 0, with a warning in the run's metrics naming the lead
    used."""

    @model_validator(mode="after")
    def _settings_need_enabled(self) -> UncertaintyConfig:
        given = [key for key in ("replicates", "forecast_replicates", "lead_s")
                 if getattr(self, key) is not None]
        if given and not self.enabled:
            one = len(given) == 1
            raise ValueError(f"{', '.join(given)} {'is' if one else 'are'} set but enabled "
                             f"is false: {'it' if one else 'they'} would have no effect "
                             f"(set enabled = true, or leave {'it' if one else 'them'} out)")
        return self

    @property
    def run_replicates(self) -> int:
        """``replicates``, or its default."""
        return UNCERTAINTY_REPLICATES if self.replicates is None else self.replicates

    @property
    def forecast_count(self) -> int:
        """``forecast_replicates``, or its default."""
        return (UNCERTAINTY_FORECAST_REPLICATES if self.forecast_replicates is None
                else self.forecast_replicates)

    @property
    def snapshot_lead_s(self) -> float:
        """``lead_s``, or its default."""
        return UNCERTAINTY_LEAD_S if self.lead_s is None else self.lead_s


class PassivityConfig(_Model):
    """Passivity layer between the measured wrenches and the ODS (app/sim/passivity.py).

    Off by default (the paper has none). Loop lag makes an emulated contact gain energy;
    with this on, the satellites' forces pass one energy tank: together they never gain
    more energy than the mockups received from the contact, by an internal damper between
    the satellites that keeps momentum and never turns a push into a pull. It needs two
    satellites acted on at once (a contact both sides see); with one, it only counts.
    Each carried satellite's torque passes its own passivity controller. It treats the
    environment as passive, so an operator's push is throttled: scenarios with pushes
    keep it off.
    """

    enabled: StrictBool = False
    """Switch the passivity layer on."""
    idle_reset_s: NonNegative = 0.1
    """The balance is forgotten once the measured wrench has been zero this long."""
    tank_max_J: Annotated[float, AfterValidator(_finite), Field(ge=0.0, le=10.0)] = 1e-3
    """Cap of the force ports' energy tank: energy the contact dissipated early is not
    handed back to the satellites later beyond this."""


class ContactMaterial(_Model):
    """Hunt-Crossley contact parameters of one mockup's surface."""

    stiffness_Npm: Positive
    """Hunt-Crossley stiffness k of F = k d (1 + c ḋ)."""
    damping_spm: NonNegative
    """Hunt-Crossley damping (s/m): F = k d (1 + c d_dot), no pull."""
    friction: Annotated[float, AfterValidator(_finite), Field(ge=0.0, le=2.0)] = 0.0
    """Coulomb friction coefficient μ of the surface (0: frictionless). Two surfaces in
    contact slide with √(μ_a μ_b), regularised near zero sliding speed
    (app/sim/contact.py)."""
    exponent: Annotated[float, AfterValidator(_finite), Field(ge=1.0, le=2.0)] = 1.0
    """Hunt–Crossley exponent n of F = k dⁿ (1 + c ḋ) (1: the linear law the lab's
    contact identification assumes; 1.5: Hertz's law of a sphere), ``stiffness_Npm`` then
    in N/mⁿ. Two surfaces of different n meet with the larger (their k and c combined as
    for n = 1). For measuring a contact the lab's model does not describe
    (benchmarks/contact_fidelity.py --mismatch)."""


DEFAULT_MATERIALS = {
    "rigid": ContactMaterial(stiffness_Npm=2.0e4, damping_spm=0.5),
    "sponge": ContactMaterial(stiffness_Npm=500.0, damping_spm=20.0),
}


class HandConfig(_Model):
    """The operator's virtual hand (app/sim/hand.py): a compliant fingertip that presses
    on the mockup where it grabbed it, never pulls, and a twist that turns it one way.

    Pressing: 1 N per cm the hand has moved into the mockup, at most the scripted push's
    20 N; with free-floating's force scale (a 200 kg satellite in translation) a 10 cm
    press held sends the satellite off at 6.2 cm/s (benchmarks/hand_drag.py; at most
    d sqrt(k force_scale / m) = 7.1 cm/s); under 4 cm the F/T deadband (4 N) keeps it
    out. Twisting: 5 N m per rad (0.09 N m
    per degree) of the gizmo's turn, at most 2 N m (the sensor's range is 10 N m, its
    deadband 0.25 N m: about 3 degrees). Both with Hunt-Crossley damping
    F = k d (1 + c d_dot): continuous at first touch, zero on separation."""

    stiffness_Npm: Positive = 100.0
    """Stiffness of the hand's fingertip spring."""
    max_force_N: Positive = 20.0
    """The most force the hand applies."""
    damping_spm: NonNegative = 2.0
    """Hunt-Crossley damping of the press (s/m): F = k d (1 + c d_dot), never below 0."""
    twist_stiffness_Nmprad: Positive = 5.0
    """Stiffness of the rotation rings' twist."""
    max_torque_Nm: Positive = 2.0
    """The most torque the hand applies."""
    twist_damping_sprad: NonNegative = 2.0
    """Hunt-Crossley damping of the twist (s/rad): T = k_t a (1 + c_t a_dot), never < 0."""


class CaptureConfig(_Model):
    """Docking capture (app/sim/capture.py): when the target's COM, seen from the chaser's
    body frame, is within position_tolerance_m of mated_offset_m, and the relative speed,
    attitude and rate are within theirs, while the mockups touch, the pair latches and
    moves as one body."""

    chaser: str
    """The satellite that captures (its name)."""
    target: str
    """The satellite captured (its name)."""
    mated_offset_m: Vec3
    """The target's COM in the chaser's body frame when docked (lab metres)."""
    position_tolerance_m: Positive = 0.01
    """Latch when the target's COM is within this of mated_offset_m ..."""
    velocity_tolerance_mps: Positive = 0.01
    """... and the relative speed within this ..."""
    attitude_tolerance_rad: Positive = 0.05
    """... and the relative angle within this ..."""
    rate_tolerance_radps: Positive = 0.05
    """... and the relative angular rate within this."""
    require_contact: StrictBool = True
    """The latch closes only while the two mockups touch (a mechanism grabs what it
    touches); false: on the envelope alone, touching or not (a virtual capture)."""


class SuccessConfig(_Model):
    """What a scenario must achieve (app/runs/success.py): each criterion given is computed
    from the run's telemetry and reported in metrics.json ``success``."""

    libration_period_error_max: Annotated[float, AfterValidator(_finite),
                                          Field(gt=0.0, lt=1.0)] | None = None
    """Gravity-gradient pitch libration: the measured period against theory (the
    large-amplitude pendulum in 2 theta, Omega sqrt(3 (Iy - Ix) / Iz)), as a fraction."""
    captured: StrictBool | None = None
    """Docking: the pair must (true) or must not (false) be captured ([capture])."""
    residual_rate_max_radps: NonNegative | None = None
    """Docking: the compound's angular rate relative to R at the end, at most."""
    waypoints_reached: StrictBool = False
    """The first satellite with a GNC reached every waypoint, in order (within its
    tolerance for its hold, judged on the ODS state)."""
    final_position_error_max_m: Positive | None = None
    """... and ends within this distance (orbit m) of its last waypoint."""
    recovery_time_max_s: Positive | None = None
    """... and, after the last scripted pulse on it ends, is back within tolerance of the
    waypoint it was flying to within this time (orbit s)."""
    no_contact: StrictBool = False
    """The satellites never touch (a rendezvous that ends in a collision has failed)."""
    synchronisation_position_error_max_m: Positive | None = None
    """A GNC flying relative to another satellite (``relative_to``): at its last waypoint
    (the capture point), over the hold that reaches it, at most this far (orbit m) from
    the point that moves with the target ..."""
    synchronisation_attitude_error_max_rad: Positive | None = None
    """... and at most this angle from the attitude that turns with it."""

    @property
    def needs_sync(self) -> bool:
        return (self.synchronisation_position_error_max_m is not None
                or self.synchronisation_attitude_error_max_rad is not None)

    @property
    def needs_gnc(self) -> bool:
        return (self.waypoints_reached or self.final_position_error_max_m is not None
                or self.recovery_time_max_s is not None or self.needs_sync)


class LoopConfig(_Model):
    """The emulation loop."""

    rate_hz: Annotated[float, AfterValidator(_finite), Field(ge=100.0, le=5000.0)] = 500.0
    """At least 100 Hz: below, a servo step is longer than the servo's own response and a
    contact lasts a cycle or two (the paper: 500 Hz)."""
    duration_s: Annotated[float, AfterValidator(_finite), Field(gt=0.0, le=1e6)] = 30.0
    """Scenario seconds a headless run lasts (run --duration overrides)."""
    mode: Literal["hil", "ideal"] = "hil"
    """"hil": the arms in the loop; "ideal": the converged reference without arms."""
    seed: Annotated[int, Field(ge=0)] = 0
    """Seed of the sensor noise (run --seed overrides)."""
    telemetry_capacity: Annotated[int, Field(ge=100, le=10_000_000)] = 140_000
    """Rows the web app's telemetry ring keeps (the last ones: 280 s at 500 Hz); a headless
    run keeps every cycle instead. The web app takes at most 128 MiB of them per run
    (two arms: 113 values a row, 120 MiB by default; app/backend/service.py)."""
    approach_timeout_s: Annotated[float, AfterValidator(_finite), Field(gt=0.0, le=120.0)] = 20.0
    """How long the start-up may search for each arm's start posture (VFDM iterations on
    its virtual model), at most 2 minutes."""
    run_up_s: Annotated[float, AfterValidator(_finite), Field(ge=0.0, le=10.0)] = 1.0
    """A flying start (hil): over this long before t = 0 the arms run up from rest to
    their satellites' initial velocity and spin, reaching the initial poses at t = 0
    (app/sim/run_up.py), instead of starting at rest and catching up with a jolt; 0
    starts them at rest. The run-up covers v0·run_up_s/2 (4 cm in the collision)."""
    max_tracking_error_m: Positive = 0.05
    """A mockup this far from its satellite's ODS position stops the run (hil): the arm
    can no longer show the orbit (the paper's lab tracked within 0.01 m)."""
    max_tracking_error_rad: Positive = 0.25
    """The same for the attitude."""
    stop_at_sensor_range: StrictBool = True
    """A raw F/T force reading at ``[sensor] range_force_N`` stops the run (hil): beyond
    it the readings clip, and a lab's arms would press the mockups together blind."""
    reference_substeps: Annotated[int, Field(ge=1, le=1000)] = 20
    """Ideal runs: a cycle that starts or ends in contact is integrated in this many
    sub-steps with the contact law inside (app/sim/reference.py), so that the reference
    converges to the exact impact."""


MAX_SATELLITES = 8
MAX_ROBOTS = 4
MAX_PULSES = 1000
MAX_MATERIALS = 32
MAX_TELEMETRY_BYTES = 1 << 30
"""The telemetry ring (and a headless run, which keeps every cycle) holds at most 1 GiB."""
MAX_VFDM_ITERATIONS_PER_S = 100_000
"""10x the paper's 10 iterations at 500 Hz: ~0.1 ms of VFDM per arm and cycle."""


def telemetry_row_floats(n_satellites: int, n_robots: int, n_rails: int = 0) -> int:
    """Values in one telemetry row (app/sim/telemetry.py loop_columns): the time, 19 ODS
    values, 3 true-force values and 6 GNC values per satellite, 28 values per arm, 3 per
    rail."""
    return 1 + 28 * n_satellites + 28 * n_robots + 3 * n_rails


def max_telemetry_rows(n_satellites: int, n_robots: int, n_rails: int = 0) -> int:
    """The most telemetry rows that fit MAX_TELEMETRY_BYTES for this layout."""
    return MAX_TELEMETRY_BYTES // (8 * telemetry_row_floats(n_satellites, n_robots, n_rails))


class EmulatorConfig(_Model):
    """A whole scenario: orbit, satellites, pulses and, for the emulation, the lab."""

    name: str = "custom"
    """The scenario's name, shown in the summary and metrics.json."""
    description: str = ""
    """One line on what the scenario shows (`orbit-emulator scenarios` lists it)."""
    orbit: OrbitConfig = OrbitConfig()
    satellites: Annotated[list[SatelliteConfig],
                          Field(min_length=1, max_length=MAX_SATELLITES)] = [
        SatelliteConfig(name="sat1")
    ]
    pulses: Annotated[list[PulseConfig], Field(max_length=MAX_PULSES)] = []
    lab: LabConfig = LabConfig()
    robots: Annotated[list[RobotConfig], Field(max_length=MAX_ROBOTS)] = []
    vfdm: VfdmConfig = VfdmConfig()
    servo: ServoConfig = ServoConfig()
    sensor: SensorConfig = SensorConfig()
    wrench: WrenchProcessingConfig = WrenchProcessingConfig()
    passivity: PassivityConfig = PassivityConfig()
    compensation: CompensationConfig = CompensationConfig()
    uncertainty: UncertaintyConfig = UncertaintyConfig()
    materials: Annotated[dict[str, ContactMaterial],
                         Field(max_length=MAX_MATERIALS)] = DEFAULT_MATERIALS
    hand: HandConfig = HandConfig()
    loop: LoopConfig = LoopConfig()
    scaling: ScalingConfig = ScalingConfig()
    success: SuccessConfig = SuccessConfig()
    capture: CaptureConfig | None = None

    @model_validator(mode="after")
    def _similar(self) -> EmulatorConfig:
        """What the similarity law needs and refuses (app/sim/scaling.py)."""
        sc = self.scaling
        if sc.law == "paper":
            if (sc.length, sc.time, sc.mass) != (1.0, 1.0, 1.0):
                raise ValueError("scaling: length, time and mass apply under law = "
                                 "'similarity'; the paper's law has [orbit] force_scale "
                                 "and torque_scale")
            return self
        for key in ("force_scale", "torque_scale"):
            if getattr(self.orbit, key) is not None:
                raise ValueError(f"orbit.{key}: derived under scaling.law = 'similarity' "
                                 f"(from scaling.mass and scaling.length); remove it")
        for i, sat in enumerate(self.satellites):
            if sat.mockup_mass_kg is None:
                raise ValueError(f"satellites.{i}.mockup_mass_kg: required under "
                                 f"scaling.law = 'similarity' (mass_kg is the virtual "
                                 f"satellite's, {sat.mass_kg:g} kg; the sensor chain "
                                 f"compensates the mockup's)")
        rate = _orbit_rate(self.orbit.altitude_m)
        turn = sc.time * rate / self.loop.rate_hz
        if turn > MAX_ORBIT_TURN_PER_CYCLE_RAD:
            k_max = MAX_ORBIT_TURN_PER_CYCLE_RAD * self.loop.rate_hz / rate
            raise ValueError(
                f"scaling.time: {sc.time:g} turns the orbit frame {turn:.3g} rad per loop "
                f"cycle at {self.loop.rate_hz:g} Hz; at most {MAX_ORBIT_TURN_PER_CYCLE_RAD:g} "
                f"(k_T <= {k_max:.0f} here), or the step cannot follow the orbit's motions")
        damped = sorted({s.material for s in self.satellites
                         if s.material in self.materials
                         and self.materials[s.material].damping_spm > 0.0})
        if len(self.satellites) >= 2 and damped and not math.isclose(sc.length, sc.time,
                                                                     rel_tol=1e-12):
            raise ValueError(
                f"scaling: length {sc.length:g} and time {sc.time:g} play velocities at "
                f"{sc.time / sc.length:g} x the orbit's, but the contact's Hunt-Crossley "
                f"damping (materials {', '.join(damped)}) makes restitution depend on the "
                f"impact speed, which the lab's mockups meet at the lab's speed: with "
                f"contact, scaling.length must equal scaling.time")
        return self

    @model_validator(mode="after")
    def _gnc(self) -> EmulatorConfig:
        """A GNC's period spans at least one loop cycle, its wrench can enter the ODS, and
        its legs can be flown."""
        cycle_orbit_s = (self.scaling.time if self.scaling.law == "similarity" else 1.0) \
            / self.loop.rate_hz
        for i, sat in enumerate(self.satellites):
            if sat.gnc is None:
                continue
            if sat.gnc.period_s < cycle_orbit_s * (1.0 - 1e-9):
                raise ValueError(f"satellites.{i}.gnc.period_s: {sat.gnc.period_s:g} s is "
                                 f"shorter than one loop cycle ({cycle_orbit_s:g} s of "
                                 f"orbit time)")
            if self.scaling.law == "paper" and 0.0 in (self.orbit.force_scale,
                                                        self.orbit.torque_scale):
                raise ValueError(f"satellites.{i}.gnc: a zero [orbit] force_scale or "
                                 f"torque_scale lets no thrust into the ODS")
            self._gnc_legs(i, sat.gnc)
        return self

    @model_validator(mode="after")
    def _success_applies(self) -> EmulatorConfig:
        """Each [success] criterion has something to judge."""
        crit = self.success
        if crit.needs_gnc and all(s.gnc is None for s in self.satellites):
            raise ValueError("success: waypoints_reached, final_position_error_max_m, "
                             "recovery_time_max_s and the synchronisation errors judge a "
                             "satellite's GNC; no satellite has a [satellites.gnc]")
        first = next((s for s in self.satellites if s.gnc is not None), None)
        if crit.needs_sync and first is not None and first.gnc.relative_to is None:
            raise ValueError(f"success: the synchronisation errors judge a GNC flying "
                             f"relative to another satellite; {first.name!r}'s "
                             f"[satellites.gnc] has no relative_to")
        for key in ("captured", "residual_rate_max_radps"):
            if getattr(crit, key) is not None and self.capture is None:
                raise ValueError(f"success.{key}: judges a docking's capture; this "
                                 f"configuration has no [capture]")
        if crit.no_contact and len(self.satellites) < 2:
            raise ValueError("success.no_contact: judges contact between satellites; "
                             "there is only one")
        if crit.libration_period_error_max is not None:
            if not self.orbit.gravity_gradient:
                raise ValueError("success.libration_period_error_max: the libration is the "
                                 "gravity gradient's, and orbit.gravity_gradient is off")
            ix, iy, _ = self.satellites[0].principal_inertia()
            if iy <= ix:
                raise ValueError(f"success.libration_period_error_max: satellites.0 has "
                                 f"I_y {iy:g} <= I_x {ix:g} kg m^2: the gravity gradient "
                                 f"gives its pitch no restoring torque, nothing librates")
        return self

    @model_validator(mode="after")
    def _capture_can_join(self) -> EmulatorConfig:
        """A capture joins lab-equivalent bodies (mass / force_scale, inertia /
        torque_scale): a zero or tiny knob makes them infinite, or their sums overflow."""
        if self.capture is None or self.scaling.law != "paper":
            return self
        fs, ts = self.orbit.force_scale, self.orbit.torque_scale
        heaviest = max(max(s.mass_kg, *s.principal_inertia()) for s in self.satellites)
        if min(fs, ts) <= 0.0 or heaviest / min(fs, ts) > MAX_LAB_EQUIVALENT:
            raise ValueError(f"capture: [orbit] force_scale {fs:g} and torque_scale {ts:g} "
                             f"make a satellite's lab-equivalent mass or inertia (mass / "
                             f"force_scale, inertia / torque_scale) infinite or over "
                             f"{MAX_LAB_EQUIVALENT:g}; no compound can be formed")
        return self

    def _gnc_legs(self, i: int, gnc: GncConfig) -> None:
        """``relative_to`` names another satellite; CW transfers fly between points of R,
        each shorter than 0.9 of an orbit and not near half of one (CW's singular transfer
        times: in plane a whole orbit, out of plane every half)."""
        names = [s.name for s in self.satellites]
        if gnc.relative_to is not None and (gnc.relative_to not in names
                                            or gnc.relative_to == self.satellites[i].name):
            raise ValueError(f"satellites.{i}.gnc.relative_to: {gnc.relative_to!r} names no "
                             f"other satellite (have {names})")
        period_s = 2.0 * math.pi / _orbit_rate(self.orbit.altitude_m)
        for k, wp in enumerate(gnc.waypoints):
            if wp.transfer_s is None:
                continue
            if gnc.relative_to is not None:
                raise ValueError(f"satellites.{i}.gnc.waypoints.{k}.transfer_s: a CW transfer "
                                 f"flies to a point of R; not with relative_to")
            if wp.transfer_s >= 0.9 * period_s:
                raise ValueError(f"satellites.{i}.gnc.waypoints.{k}.transfer_s: "
                                 f"{wp.transfer_s:g} s is not below 0.9 of an orbit "
                                 f"({0.9 * period_s:.0f} s of {period_s:.0f} s)")
            if abs(wp.transfer_s / period_s - 0.5) < HALF_ORBIT_MARGIN:
                raise ValueError(f"satellites.{i}.gnc.waypoints.{k}.transfer_s: "
                                 f"{wp.transfer_s:g} s is within "
                                 f"{HALF_ORBIT_MARGIN * period_s:.0f} s of half an orbit "
                                 f"({period_s / 2:.0f} s), where "
                                 f"the out-of-plane motion returns to its start whatever "
                                 f"the first impulse: no CW transfer can aim it")

    @model_validator(mode="after")
    def _references(self) -> EmulatorConfig:
        names = [s.name for s in self.satellites]
        if len(set(names)) != len(names):
            raise ValueError(f"satellites: names must be unique, got {names}")
        for i, p in enumerate(self.pulses):
            if p.satellite not in names:
                raise ValueError(
                    f"pulses.{i}.satellite: {p.satellite!r} names no satellite (have {names})"
                )
        for i, r in enumerate(self.robots):
            if r.satellite not in names:
                raise ValueError(
                    f"robots.{i}.satellite: {r.satellite!r} names no satellite (have {names})"
                )
        carried = [r.satellite for r in self.robots]
        if len(set(carried)) != len(carried):
            raise ValueError("robots: each satellite can be carried by one robot only")
        if self.capture is not None:
            for key in ("chaser", "target"):
                if getattr(self.capture, key) not in names:
                    raise ValueError(f"capture.{key}: {getattr(self.capture, key)!r} names "
                                     f"no satellite (have {names})")
            if self.capture.chaser == self.capture.target:
                raise ValueError("capture.target: must differ from capture.chaser")
        for i, s in enumerate(self.satellites):
            if s.material not in self.materials:
                raise ValueError(f"satellites.{i}.material: {s.material!r} is not in materials")
        layout = (len(self.satellites), len(self.robots), len(self.rail_robots))
        max_rows = max_telemetry_rows(*layout)
        if self.loop.telemetry_capacity > max_rows:
            raise ValueError(
                f"loop.telemetry_capacity: {self.loop.telemetry_capacity} rows of "
                f"{telemetry_row_floats(*layout)} values "
                f"exceed {MAX_TELEMETRY_BYTES // 2**20} MiB; at most {max_rows} for this layout")
        work = self.vfdm.iterations * self.loop.rate_hz
        if work > MAX_VFDM_ITERATIONS_PER_S:
            raise ValueError(
                f"vfdm.iterations: {self.vfdm.iterations} per cycle at {self.loop.rate_hz:g} Hz "
                f"is {work:g} per second; at most {MAX_VFDM_ITERATIONS_PER_S:,} "
                f"(the VFDM must leave the cycle time for the rest)")
        return self

    @property
    def rail_robots(self) -> list[int]:
        """The robots (1-based numbers) that stand on a rail."""
        return [i + 1 for i, r in enumerate(self.robots) if r.rail is not None]

    def rail_settings(self) -> list[dict | None]:
        """Per robot, its rail as the web panel and the REST settings show it (None: no
        rail): the axis, travel, start, the carriage's limits and its servo (response,
        feedforward, delay)."""
        return [None if r.rail is None else {
            "robot": r.name, "axis_W": list(r.rail.axis_W), "travel_m": list(r.rail.travel_m),
            "start_m": r.rail.start_m, "speed_limit_mps": r.rail.speed_limit_mps,
            "accel_limit_mps2": r.rail.accel_limit_mps2, "bandwidth_hz": r.rail.bandwidth_hz,
            "damping_ratio": r.rail.damping_ratio,
            "velocity_feedforward": r.rail.velocity_feedforward,
            "delay_cycles": r.rail.delay_cycles} for r in self.robots]

    def satellite_index(self, name: str) -> int:
        return [s.name for s in self.satellites].index(name)


def _format_error(err: ValidationError) -> str:
    lines = []
    for e in err.errors():
        loc = ".".join(str(p) for p in e["loc"])
        msg = e["msg"].removeprefix("Value error, ")
        if not loc and re.match(r"[\w.]+: ", msg):  # a whole-config check names its field
            lines.append(msg)
        else:
            lines.append(f"{loc or '(top level)'}: {msg}")
    return "invalid configuration: " + "; ".join(lines)


def parse_config(data: dict) -> EmulatorConfig:
    """Validate a plain dict (from TOML or JSON) into an EmulatorConfig.

    Strictly, as JSON: a number must be a number (``"5"`` is refused, an integer is taken
    where a float is expected), a flag ``true`` or ``false``; a list stands for a tuple."""
    _check_plain(data)
    text = json.dumps(data, allow_nan=True)
    try:
        return EmulatorConfig.model_validate_json(text, strict=True)
    except ValidationError as err:
        raise ConfigError(_format_error(err)) from None


def _check_plain(value, path: str = "") -> None:
    """Only what JSON holds (objects with text keys, lists, text, numbers, flags, null);
    anything else (a TOML date, text that is not Unicode) is an error naming its key."""
    where = path or "(top level)"
    if isinstance(value, dict):
        for key, item in value.items():
            if not isinstance(key, str):
                raise ConfigError(f"invalid configuration: {where}: a key must be text, "
                                  f"got {key!r}")
            _check_plain(item, f"{path}.{key}" if path else key)
    elif isinstance(value, (list, tuple)):
        for i, item in enumerate(value):
            _check_plain(item, f"{path}.{i}" if path else str(i))
    elif isinstance(value, str):
        try:
            value.encode("utf-8")
        except UnicodeEncodeError:
            raise ConfigError(f"invalid configuration: {where}: text that is not valid "
                              f"Unicode") from None
    elif value is not None and not isinstance(value, (bool, int, float)):
        raise ConfigError(f"invalid configuration: {where}: expected a number, flag, text "
                          f"or list, got a {type(value).__name__}")


def load_config(path: str | Path) -> EmulatorConfig:
    """Read and validate a TOML scenario file (see :func:`read_scenario_file`)."""
    return parse_config(read_scenario_file(path))


SCENARIO_DIR = Path(__file__).parent.parent / "scenarios"
MAX_EXTENDS = 32
"""A scenario file's ``extends`` chain is at most this many files long."""


def read_scenario_file(path: str | Path, _chain: tuple[Path, ...] = ()) -> dict:
    """A TOML scenario file as a plain dict, its ``extends`` resolved.

    ``extends = "NAME"`` starts from another scenario: ``NAME.toml`` (or ``NAME`` if it
    ends in .toml) beside this file, else the built-in scenario of that name; this file's
    settings are then merged over it as overrides are (:func:`merge_overrides`: a list
    given replaces the base's list)."""
    path = Path(path)
    try:
        data = tomllib.loads(read_bounded_text(path))
    except FileNotFoundError:
        raise ConfigError(f"config file not found: {path}") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a directory, not a TOML file") from None
    except InputFileError as err:
        raise ConfigError(str(err)) from None
    except (OSError, UnicodeDecodeError) as err:
        reason = getattr(err, "strerror", None) or err
        raise ConfigError(f"{path}: cannot be read: {reason}") from None
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{path}: not valid TOML: {err}") from None
    except RecursionError:
        raise ConfigError(f"{path}: not valid TOML: nested too deeply") from None
    base = data.pop("extends", None)
    if base is None:
        return data
    if not isinstance(base, str) or not base.strip():
        raise ConfigError(f"{path}: extends: must name a scenario, got {base!r}")
    if len(base) > 255 or "\0" in base:  # (longer than any file name can be)
        shown = base if len(base) <= 60 else f"{base[:60]!r}... ({len(base)} characters)"
        raise ConfigError(f"{path}: extends: not a scenario's file name: {shown}")
    file_name = base if base.endswith(".toml") else f"{base}.toml"
    base_path = path.parent / file_name
    if not base_path.exists():  # (a FIFO or a device there is refused when read)
        base_path = SCENARIO_DIR / file_name
    if not base_path.exists():
        raise ConfigError(f"{path}: extends: no scenario {base!r} beside it or built in")
    chain = (*_chain, path.resolve())
    if len(chain) >= MAX_EXTENDS:
        raise ConfigError(f"{path}: extends: more than {MAX_EXTENDS} files deep (from "
                          f"{chain[0].name}): a chain that long is a mistake")
    if base_path.resolve() in chain:
        cycle = " -> ".join(p.name for p in (*chain, base_path))
        raise ConfigError(f"{path}: extends: {base!r} makes a cycle: {cycle}")
    return _merge_patch(read_scenario_file(base_path, chain), data)


def merge_overrides(base: EmulatorConfig, overrides: dict) -> EmulatorConfig:
    """Apply a merge patch of overrides to a config and validate the result.

    JSON Merge Patch (RFC 7396) with one extension, for the REST start body and ``--set``
    alike: objects merge key by key; ``null`` removes a key, so it takes its default; a
    list replaces the whole list (``{"pulses": []}`` clears the pulses); an object whose
    keys are all item indices patches those items of a list in place
    (``{"satellites": {"1": {"mass_kg": 2}}}`` changes one field of the second satellite;
    an index beyond the list is an error naming it).
    """
    return merge_overrides_all(base, [overrides])


MAX_KEY_PARTS = 12
"""A dotted KEY's most parts (satellites.0.gnc.waypoints.0.position_m.0 has 7)."""


def merge_overrides_all(base: EmulatorConfig, overrides: list[dict]) -> EmulatorConfig:
    """Apply several merge patches in order, then validate once: settings that must change
    together (scaling.length and scaling.time, a satellite's name and the robot carrying
    it) may be given as separate patches (repeated --set, a sweep's [set] or linked axis)."""
    data = base.model_dump()
    # the sensor's model-filled figures are not settings: a patch naming another model
    # takes that model's (the ones given in [sensor] stay)
    data["sensor"] = base.sensor.model_dump(exclude_unset=True)
    for patch in overrides:
        if not isinstance(patch, dict):
            raise ConfigError("overrides: expected an object of settings")
        for key in ("name", "description"):
            if key in patch:
                raise ConfigError(f"{key}: the scenario's {key} is not a setting to override "
                                  f"(a run is reported under its scenario's name)")
        data = _merge_patch(data, patch)
    return parse_config(data)


def assignment_override(text: str) -> dict:
    """``"passivity.enabled=false"`` → ``{"passivity": {"enabled": False}}`` for merge_overrides.

    The value is read as TOML (``0.5``, ``true``, ``[0.1, 0, 0]``, ``"rigid"``), a bare
    word as a string; a numeric key picks an item of a list (``robots.1.q_home_rad=...``
    → ``{"robots": {"1": {"q_home_rad": ...}}}``); a list value replaces the whole list.
    The bare word ``null`` (TOML has none) removes the setting, which takes its default, as
    a merge patch's null does (``robots.0.rail=null``: the robot without its rail; the
    string is ``'"null"'``).
    """
    key, sep, value = text.partition("=")
    if not sep:
        raise ConfigError(f"expected KEY=VALUE with a dotted KEY, got {text!r}")
    if value.strip() == "null":
        return dotted_override(key, None, text)
    try:
        parsed = tomllib.loads(f"v = {value.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        parsed = value.strip()
    except RecursionError:
        raise ConfigError(f"{text[:60]!r}...: the value is nested too deeply") from None
    return dotted_override(key, parsed, text)


def dotted_override(key: str, value, text: str | None = None) -> dict:
    """``("satellites.0.mass_kg", 2)`` → ``{"satellites": {"0": {"mass_kg": 2}}}`` for
    merge_overrides: what ``--set KEY=VALUE`` does with a value already read (a numeric
    part picks a list item). text: the assignment as given, for the message."""
    path = [part.strip() for part in key.split(".")]
    if len(path) > MAX_KEY_PARTS:
        raise ConfigError(f"{key[:60]}...: a KEY has at most {MAX_KEY_PARTS} dotted parts "
                          f"(the deepest setting has 7), got {len(path)}")
    if not all(path):
        raise ConfigError(f"expected KEY=VALUE with a dotted KEY, got {text or key!r}")
    if path[0].isdigit():
        raise ConfigError(f"{key.strip()}: the first part of KEY must be a section name")
    for part in reversed(path):
        value = {part: value}  # a number picks a list item (merge_overrides)
    return value


def _merge_patch(target, patch, path: str = ""):
    """RFC 7396 MergePatch(target, patch), plus index-keyed objects for list items (see
    merge_overrides); path: where we are, for the messages."""
    if not isinstance(patch, dict):
        return patch
    if isinstance(target, (list, tuple)):  # a list of items, or a vector (a tuple)
        return _patch_items(list(target), patch, path)
    out = dict(target) if isinstance(target, dict) else {}
    for key, value in patch.items():
        if value is None:
            out.pop(key, None)
        else:
            out[key] = _merge_patch(out.get(key), value, f"{path}{key}.")
    return out


MAX_INDEX_DIGITS = 6
"""A list item's index is written in at most this many ASCII digits (no list has a
million items)."""
_INDEX = re.compile(f"[0-9]{{1,{MAX_INDEX_DIGITS}}}")


def item_index(part) -> int | None:
    """The list index a key part names (``"2"`` → 2): ASCII digits only, at most
    :data:`MAX_INDEX_DIGITS` of them; None for anything else (``"١"``, a 4,301-digit
    number, ``"x"``)."""
    if isinstance(part, str) and _INDEX.fullmatch(part):
        return int(part)
    return None


def _shown_key(key: str) -> str:
    """A key for a message: whole if short, else its start and its length."""
    return repr(key) if len(key) <= 20 else f"{key[:12]!r}... ({len(key)} characters)"


def _patch_items(items: list, patch: dict, path: str) -> list:
    """Patch the items of a list named by the (string) indices of ``patch``."""
    where = path.rstrip(".") or "(top level)"
    out = list(items)
    for key, value in patch.items():
        i = item_index(key)
        if i is None and isinstance(key, str) and key and all(c.isdigit() for c in key):
            raise ConfigError(f"{where}: a list item's index is written in 1 to "
                              f"{MAX_INDEX_DIGITS} ASCII digits (0-9), got "
                              f"{_shown_key(key)}")
        if i is None:
            raise ConfigError(f"{where}: a list is replaced by a list or patched by an object "
                              f"of item indices, got the key {_shown_key(str(key))}")
        if i >= len(items):
            raise ConfigError(f"{where}.{i}: index out of range: the list has "
                              f"{len(items)} item(s), indices 0..{len(items) - 1}")
        if value is None:
            raise ConfigError(f"{where}.{i}: an item cannot be removed by null; give the "
                              f"whole list instead")
        out[i] = _merge_patch(items[i], value, f"{path}{i}.")
    return out
