"""Orbital Dynamics Simulator (ODS): Clohessy-Wiltshire translation + attitude dynamics.

Paper, Section 2. Every satellite is described relative to the rotating observer frame R
(x radial away from Earth, y along-track, z orbit normal) of an observer on a circular
orbit of rate Omega.

State of N satellites, one row each, ``y`` of shape (N, 13)::

    y[:, 0:3]   position in R (m)
    y[:, 3:6]   velocity relative to R, in R (m/s)
    y[:, 6:10]  attitude of the body relative to R, unit quaternion wxyz (q_R_B)
    y[:, 10:13] angular velocity of the body relative to *inertial* space, body axes (rad/s)

The paper's Eqs. 4-7 use the inertial angular velocity. What the lab sees is motion
relative to R, which itself turns at Omega about z: ``omega_rel = omega - R_R_B^T Omega z``.
The configuration and the telemetry speak of omega_rel; convert with
:func:`omega_inertial_from_relative` and :attr:`OrbitalSimulator.omega_rel_radps`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numba import njit

from app.sim.scaling import box_inertia as box_inertia  # (was defined here)
from app.sim.scaling import ods_inertia_kgm2, scaling_of

MU_EARTH_M3PS2 = 3.986004418e14
R_EARTH_M = 6378.137e3

POS, VEL, QUAT, OMEGA = slice(0, 3), slice(3, 6), slice(6, 10), slice(10, 13)


def orbit_rate(altitude_m: float) -> float:
    """Mean motion Omega = sqrt(mu / a^3) of a circular orbit of radius a = R_E + h."""
    a = R_EARTH_M + altitude_m
    return float(np.sqrt(MU_EARTH_M3PS2 / a**3))


@dataclass(frozen=True)
class OdsParams:
    """Physical parameters of the ODS for N satellites."""

    orbit_rate_radps: float
    mass_kg: np.ndarray  # (N,)
    inertia_kgm2: np.ndarray  # (N, 3) principal moments
    gravity_gradient: bool = True
    force_scale: float = 1.0
    torque_scale: float = 1.0 / 2000.0

    @property
    def count(self) -> int:
        return len(self.mass_kg)


@njit(cache=True)
def _direction_cosines(q: np.ndarray) -> tuple:
    """R's x (radial) and z (orbit normal) axes in body axes: rows 0 and 2 of R_R_B."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    c = (1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y))
    n = (2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y))
    return c, n


def omega_inertial_from_relative(
    attitude_wxyz: np.ndarray, omega_rel_radps: np.ndarray, orbit_rate_radps: float
) -> np.ndarray:
    """Body-axes inertial angular velocity from the one relative to R (both (N, 3))."""
    q = np.atleast_2d(np.asarray(attitude_wxyz, dtype=float))
    n = np.array([_direction_cosines(qi)[1] for qi in q])
    return np.atleast_2d(omega_rel_radps) + orbit_rate_radps * n


@njit(cache=True)
def omega_relative_into(y, i, orbit_rate_radps, out, k):
    """out[k:k + 3] := satellite i's angular velocity relative to R (body axes)."""
    n = _direction_cosines(y[i, 6:10])[1]
    for a in range(3):
        out[k + a] = y[i, 10 + a] - orbit_rate_radps * n[a]


@njit(cache=True)
def _omega_relative(y, orbit_rate_radps, out):
    """out (N, 3) := every satellite's angular velocity relative to R (body axes)."""
    for i in range(y.shape[0]):
        omega_relative_into(y, i, orbit_rate_radps, out[i], 0)


@njit(cache=True)
def _derivative(W, mass, inertia, gg_on, f_scale, t_scale, y, force, torque, dy):
    """Kernel of :func:`derivative`, one satellite row at a time (writes dy)."""
    gg = 3.0 * W * W if gg_on else 0.0
    for i in range(y.shape[0]):
        x, z, vx, vy, vz = y[i, 0], y[i, 2], y[i, 3], y[i, 4], y[i, 5]
        # Eqs. 1-3: Clohessy-Wiltshire with external force F / m
        dy[i, 0], dy[i, 1], dy[i, 2] = vx, vy, vz
        dy[i, 3] = 3.0 * W * W * x + 2.0 * W * vy + f_scale * force[i, 0] / mass[i]
        dy[i, 4] = -2.0 * W * vx + f_scale * force[i, 1] / mass[i]
        dy[i, 5] = -W * W * z + f_scale * force[i, 2] / mass[i]
        # Eqs. 4-6: Euler's equations with gravity-gradient torque (inertial omega)
        q = y[i, 6:10]
        w1, w2, w3 = y[i, 10], y[i, 11], y[i, 12]
        I1, I2, I3 = inertia[i, 0], inertia[i, 1], inertia[i, 2]
        c, n = _direction_cosines(q)
        dy[i, 10] = (I3 - I2) / I1 * (gg * c[1] * c[2] - w2 * w3) + t_scale * torque[i, 0] / I1
        dy[i, 11] = (I1 - I3) / I2 * (gg * c[0] * c[2] - w1 * w3) + t_scale * torque[i, 1] / I2
        dy[i, 12] = (I2 - I1) / I3 * (gg * c[0] * c[1] - w1 * w2) + t_scale * torque[i, 2] / I3
        # Eq. 7 for the attitude relative to R: body rate relative to R is omega - W n
        r1, r2, r3 = w1 - W * n[0], w2 - W * n[1], w3 - W * n[2]
        qw, qx, qy, qz = q[0], q[1], q[2], q[3]
        dy[i, 6] = 0.5 * (-qx * r1 - qy * r2 - qz * r3)
        dy[i, 7] = 0.5 * (qw * r1 + qy * r3 - qz * r2)
        dy[i, 8] = 0.5 * (qw * r2 + qz * r1 - qx * r3)
        dy[i, 9] = 0.5 * (qw * r3 + qx * r2 - qy * r1)


@njit(cache=True, fastmath=False, inline="always")
def _along(y, h, k, out):
    """out := y + h k, element by element (an RK4 stage's state)."""
    for i in range(y.shape[0]):
        for j in range(y.shape[1]):
            out[i, j] = y[i, j] + h * k[i, j]


@njit(cache=True, fastmath=False, inline="always")
def _rk4_into(W, mass, inertia, gg_on, f_scale, t_scale, y, force, torque, dt, k1, k2, k3,
              k4, tmp, out):
    """out := one classical RK4 step of y (wrench held constant), quaternion renormalised,
    w >= 0; k1..k4 and tmp are scratch of y's shape. Element by element, the very
    operations of the array expressions it replaced (``y + 0.5 * dt * k1``, ...,
    ``y + (dt / 6) * (k1 + 2 k2 + 2 k3 + k4)``, the norm a sum from 0 in order): the same
    bits, without their temporaries."""
    n, m = y.shape
    h, c = 0.5 * dt, dt / 6.0
    _derivative(W, mass, inertia, gg_on, f_scale, t_scale, y, force, torque, k1)
    _along(y, h, k1, tmp)
    _derivative(W, mass, inertia, gg_on, f_scale, t_scale, tmp, force, torque, k2)
    _along(y, h, k2, tmp)
    _derivative(W, mass, inertia, gg_on, f_scale, t_scale, tmp, force, torque, k3)
    _along(y, dt, k3, tmp)
    _derivative(W, mass, inertia, gg_on, f_scale, t_scale, tmp, force, torque, k4)
    for i in range(n):
        for j in range(m):
            out[i, j] = y[i, j] + c * (k1[i, j] + 2.0 * k2[i, j] + 2.0 * k3[i, j] + k4[i, j])
        sq = 0.0
        for j in range(6, 10):
            sq += out[i, j] * out[i, j]
        scale = (-1.0 if out[i, 6] < 0.0 else 1.0) / np.sqrt(sq)
        for j in range(6, 10):
            out[i, j] *= scale


@njit(cache=True, fastmath=False)
def _rk4(W, mass, inertia, gg_on, f_scale, t_scale, y, force, torque, dt, out):
    """out := classical RK4 with the wrench held constant; quaternion renormalised,
    w >= 0 (out is the caller's: a compiled call that returns a new array pays more to
    hand it over than the step costs)."""
    k = np.empty((5,) + y.shape)
    _rk4_into(W, mass, inertia, gg_on, f_scale, t_scale, y, force, torque, dt, k[0], k[1],
              k[2], k[3], k[4], out)


@njit(cache=True, fastmath=False)
def _rk4_then_leads(W, mass, inertia, gg_on, f_scale, t_scale, y, force, torque, dt, leads,
                    out):
    """out[0] := one RK4 step of y of length dt; out[1 + s] := one step of out[0] of
    length leads[s], for each s (the step and the predictions from its state, one call)."""
    k = np.empty((5,) + y.shape)
    _rk4_into(W, mass, inertia, gg_on, f_scale, t_scale, y, force, torque, dt, k[0], k[1],
              k[2], k[3], k[4], out[0])
    for s in range(leads.shape[0]):
        _rk4_into(W, mass, inertia, gg_on, f_scale, t_scale, out[0], force, torque, leads[s],
                  k[0], k[1], k[2], k[3], k[4], out[1 + s])


def _kernel_args(params: OdsParams) -> tuple:
    """The kernels' parameter arguments, kept on the (frozen) params once made: the cycle
    steps the ODS three times."""
    args = params.__dict__.get("_kernel_args")
    if args is None:
        args = (
            params.orbit_rate_radps,
            params.mass_kg,
            params.inertia_kgm2,
            params.gravity_gradient,
            params.force_scale,
            params.torque_scale,
        )
        object.__setattr__(params, "_kernel_args", args)
    return args


def derivative(
    params: OdsParams, y: np.ndarray, force_R_N: np.ndarray, torque_B_Nm: np.ndarray
) -> np.ndarray:
    """Time derivative of the state (N, 13) under constant external wrenches.

    Translation, Eqs. 1-3 (Clohessy-Wiltshire with external force F/m)::

        x'' = 3 W^2 x + 2 W y' + F1/m,   y'' = -2 W x' + F2/m,   z'' = -W^2 z + F3/m

    Attitude, Eqs. 4-6 (Euler's equations with the gravity-gradient torque, where
    C1j are the direction cosines of R's radial axis in body axes) and Eq. 7 (quaternion
    kinematics, written for the attitude relative to R, so with omega - W z_B).
    Forces and torques are multiplied by the configured force and torque scales.
    """
    dy = np.empty_like(y)
    _derivative(*_kernel_args(params), y, _f64(force_R_N), _f64(torque_B_Nm), dy)
    return dy


def rk4_step(
    params: OdsParams,
    y: np.ndarray,
    force_R_N: np.ndarray,
    torque_B_Nm: np.ndarray,
    dt_s: float,
) -> np.ndarray:
    """One classical Runge-Kutta step (wrench held constant), quaternion renormalised."""
    out = np.empty(y.shape)
    _rk4(*_kernel_args(params), y, _f64(force_R_N), _f64(torque_B_Nm), float(dt_s), out)
    return out


def _f64(a) -> np.ndarray:
    """a wrench as a contiguous (N, 3) float64 array (the array itself when it is one)."""
    a = np.ascontiguousarray(a, dtype=np.float64)
    return a if a.ndim == 2 else a.reshape(-1, 3)


def cw_state_transition(orbit_rate_radps: float, t_s: float) -> np.ndarray:
    """Closed-form CW solution: Phi(t) with [p; v](t) = Phi(t) [p; v](0), force-free."""
    W, c, s = orbit_rate_radps, np.cos(orbit_rate_radps * t_s), np.sin(orbit_rate_radps * t_s)
    return np.array(
        [
            [4 - 3 * c, 0, 0, s / W, 2 * (1 - c) / W, 0],
            [6 * (s - W * t_s), 1, 0, -2 * (1 - c) / W, (4 * s - 3 * W * t_s) / W, 0],
            [0, 0, c, 0, 0, s / W],
            [3 * W * s, 0, 0, c, 2 * s, 0],
            [-6 * W * (1 - c), 0, 0, -2 * s, 4 * c - 3, 0],
            [0, 0, -W * s, 0, 0, c],
        ]
    )


def cw_course_m(orbit_rate_radps: float, position_m, velocity_mps, t_s) -> np.ndarray:
    """Positions (len(t_s), 3) of a force-free CW course from (position_m, velocity_mps)
    at the times t_s: the first three rows of :func:`cw_state_transition`, all times at
    once."""
    W = float(orbit_rate_radps)
    t = np.asarray(t_s, float)[:, None]
    (x, y, z), (vx, vy, vz) = np.asarray(position_m, float), np.asarray(velocity_mps, float)
    c, s = np.cos(W * t), np.sin(W * t)
    return np.hstack([
        (4 - 3 * c) * x + s / W * vx + 2 * (1 - c) / W * vy,
        6 * (s - W * t) * x + y - 2 * (1 - c) / W * vx + (4 * s - 3 * W * t) / W * vy,
        c * z + s / W * vz,
    ])


def along_track_drift_rate(orbit_rate_radps: float, x0_m: float, vy0_mps: float) -> float:
    """Secular along-track drift of a CW orbit, -3 (2 W x0 + y'0); zero when drift-free."""
    return -3.0 * (2.0 * orbit_rate_radps * x0_m + vy0_mps)


@dataclass
class OrbitalSimulator:
    """The ODS for N satellites: parameters, state and time, advanced by :meth:`step`."""

    params: OdsParams
    y: np.ndarray
    t_s: float = 0.0
    names: list[str] = field(default_factory=list)

    @classmethod
    def from_config(cls, config) -> OrbitalSimulator:
        """Build from an :class:`app.config.EmulatorConfig` (initial state relative to R),
        in lab units under its scaling (app/sim/scaling.py): the virtual bodies' mass and
        inertia, the orbit rate k_T Omega, the measured wrench times force_scale and
        torque_scale, the initial state divided down from orbit units."""
        sc = scaling_of(config)
        W = sc.orbit_rate_lab(orbit_rate(config.orbit.altitude_m))
        sats = config.satellites
        params = OdsParams(
            orbit_rate_radps=W,
            mass_kg=np.array([s.mass_kg for s in sats], dtype=float),
            inertia_kgm2=np.array([ods_inertia_kgm2(s, sc) for s in sats], dtype=float),
            gravity_gradient=config.orbit.gravity_gradient,
            force_scale=sc.force_scale,
            torque_scale=sc.torque_scale,
        )
        y = np.zeros((len(sats), 13))
        p, v, w = sc.to_lab([s.position_m for s in sats], [s.velocity_mps for s in sats],
                            [s.omega_radps for s in sats])
        y[:, POS], y[:, VEL] = p, v
        q = np.array([s.attitude_wxyz for s in sats], dtype=float)
        q *= np.where(q[:, :1] < 0.0, -1.0, 1.0)
        y[:, QUAT] = q
        y[:, OMEGA] = omega_inertial_from_relative(q, w, W)
        return cls(params=params, y=y, names=[s.name for s in sats])

    def step(self, force_R_N: np.ndarray, torque_B_Nm: np.ndarray, dt_s: float) -> None:
        """Advance all satellites by dt_s under wrenches held constant over the step."""
        self.commit(self.advance(force_R_N, torque_B_Nm, dt_s), dt_s)

    def advance(self, force_R_N: np.ndarray, torque_B_Nm: np.ndarray,
                dt_s: float) -> np.ndarray:
        """The state dt_s later under wrenches held constant (nothing changes here)."""
        return rk4_step(self.params, self.y, force_R_N, torque_B_Nm, dt_s)

    def advance_and_ahead(self, force_R_N: np.ndarray, torque_B_Nm: np.ndarray, dt_s: float,
                          leads_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(:meth:`advance`, (len(leads_s), N, 13) the states ``leads_s`` after that one
        under the same wrenches): the step and the predictions from its state in one
        compiled call, bit for bit :meth:`advance` and :func:`rk4_step` of its result."""
        leads = np.asarray(leads_s, dtype=np.float64)
        out = np.empty((1 + len(leads),) + self.y.shape)
        _rk4_then_leads(*_kernel_args(self.params), self.y, _f64(force_R_N), _f64(torque_B_Nm),
                        float(dt_s), leads, out)
        return out[0], out[1:]

    def commit(self, y: np.ndarray, dt_s: float) -> None:
        """Take the state y as the one dt_s later."""
        self.y = y
        self.t_s += dt_s

    @property
    def position_m(self) -> np.ndarray:
        return self.y[:, POS]

    @property
    def velocity_mps(self) -> np.ndarray:
        return self.y[:, VEL]

    @property
    def attitude_wxyz(self) -> np.ndarray:
        return self.y[:, QUAT]

    @property
    def omega_inertial_radps(self) -> np.ndarray:
        return self.y[:, OMEGA]

    @property
    def omega_rel_radps(self) -> np.ndarray:
        """Angular velocity relative to R, body axes (what the lab sees)."""
        out = np.empty((self.y.shape[0], 3))
        _omega_relative(self.y, self.params.orbit_rate_radps, out)
        return out
