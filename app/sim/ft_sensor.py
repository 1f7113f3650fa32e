"""Virtual UR10e flange force/torque sensor and the lab's wrench-processing chain.

Implements DESIGN.md, "The simulated UR10e" (built-in F/T sensor: range 100 N / 10 N·m,
noise, bias, delay, the mockup's weight and inertial load m·(g − a)) and "The loop"
(payload compensation, filter, deadband, shift to the satellite COM, rotation into R; the
force and torque scales are the ODS's).

Conventions
-----------
* A *wrench* is a (6,) array ``[force (N), torque (N·m)]``.
* An external wrench on a mockup, ``wrench_ext_W``, is given in lab axes W with its moment
  taken **about the mockup COM C**. Contributions (contact, operator's hand, …) add up as
  plain arrays; :func:`point_force_wrench_W` turns a force at a point into that form.
* The sensor frame S is the flange frame F (the UR10e sensor sits in the tool flange), or,
  with ``[sensor] placement = "mockup"``, a frame at the contact face fixed in the mockup
  body (app/sim/rig.py): the functions here take S's pose wherever they say T_W_F.
* The raw reading is the wrench the mockup exerts **on the sensor**, in S, moments about the
  origin of S: ``F_ext + m (g − a)`` and its moment. Processing removes ``m (g − a)`` and so
  returns ``F_ext``, the push acting on the satellite, which is what the ODS needs.
* Rotational inertial loads of the mockup (I·α + ω × I·ω) are not modelled.

One cycle of the sensor is one call of :func:`sensor_step`, one cycle of the processing
chain one call of :func:`process_step` (numba); the calibration, run once at rest, is NumPy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np
from numba import njit

from app.config import SensorConfig, WrenchProcessingConfig
from app.sim.rotations import skew
from app.sim.sensor_models import sample_every_cycles

__all__ = [
    "Calibration",
    "ProcessedWrench",
    "VirtualFTSensor",
    "WrenchProcessor",
    "lowpass_alpha",
    "point_force_wrench_W",
    "process_step",
    "sensor_step",
]


_ZERO3 = np.zeros(3)
NORMALS_BLOCK = 512
"""Rows of six standard normals a sensor draws from its generator at a time."""
_NO_NORMALS = np.empty((0, 6))


def _packed(slot: slice, doc: str, scalar: bool = False) -> property:
    """An attribute kept in a slice of the object's ``constants`` buffer: read, a view of
    it (a float for a scalar); assigned, its values are written into the buffer (an array
    of the slice's shape, or a number), so that the compiled sensor path, which takes the
    buffer, always sees what the attribute says."""
    n = slot.stop - slot.start

    def get(self):
        return float(self.constants[slot.start]) if scalar else self.constants[slot]

    def put(self, value) -> None:
        v = np.asarray(value, dtype=float)
        if v.shape != (() if scalar else (n,)):
            raise ValueError(f"expected {'a number' if scalar else f'shape ({n},)'}, "
                             f"got shape {v.shape}")
        self.constants[slot] = v

    return property(get, put, doc=doc)


SENSOR_CONSTANTS = 22
"""Length of :attr:`VirtualFTSensor.constants`: mass, gravity (3), bias (6), noise standard
deviation (6), range (6)."""
PROCESSOR_CONSTANTS = 18
"""Length of :attr:`WrenchProcessor.constants`: gravity (3), payload and inertial
compensation (1.0 on, 0.0 off), the calibration's bias (6), mass and COM (3), α, the
contact's α, soft deadband (1.0 soft)."""
PROCESSOR_STATE = 24
"""Length of :attr:`WrenchProcessor._x`: the filter state (6), the contact filter's (6),
the kernel's scratch (12)."""
POSE_ROW = 35
"""Width of a row of :attr:`WrenchProcessor._poses`: T_W_F (16), T_W_C (16), accel (3)."""


def _frozen(value, shape: tuple[int, ...]) -> np.ndarray:
    """A read-only float copy of ``value``, which must have ``shape`` (ValueError)."""
    v = np.array(value, dtype=float)
    if v.shape != shape:
        raise ValueError(f"expected shape {shape}, got shape {v.shape}")
    v.setflags(write=False)
    return v


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """3-vector cross product without np.cross's overhead on tiny arrays."""
    return np.array(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )


def point_force_wrench_W(
    force_W_N: np.ndarray, point_W_m: np.ndarray, com_W_m: np.ndarray
) -> np.ndarray:
    """Wrench (W axes, moment about the COM) of a force applied at a point: [F, r × F]."""
    force_W_N = np.asarray(force_W_N, dtype=float)
    r_W = np.asarray(point_W_m, dtype=float) - np.asarray(com_W_m, dtype=float)
    return np.concatenate([force_W_N, _cross(r_W, force_W_N)])


# --- kernels ------------------------------------------------------------------------------


@njit(cache=True, fastmath=False)
def sensor_step(wrench, T_W_C, T_W_F, mass, gravity, accel, normals, bias, noise_std,
                range_S, ring, head, fill, out):
    """One reading of the UR10e flange sensor into out (6,): load, bias, noise, range, delay.

    The load of a rigidly mounted mockup on the sensor, from Newton on the mockup
    (m a = F_ext + m g + F_sensor→mockup): ``f = F_ext + m (g − a)``, with its moment about
    the sensor origin ``τ_ext,C + r_FC × f``, rotated into S. Then per component
    clip(load + bias + std·normal, ±range) (data sheet: range 100 N / 10 N·m), written
    into the delay ring at row ``head``; out is the oldest row. ``fill``: the ring is
    empty and every row takes the new reading. ``normals``: six standard normal draws
    (the caller's generator); ``accel``: zeros for a mockup at rest.
    """
    fx = wrench[0] + mass * (gravity[0] - accel[0])
    fy = wrench[1] + mass * (gravity[1] - accel[1])
    fz = wrench[2] + mass * (gravity[2] - accel[2])
    rx, ry, rz = T_W_C[0, 3] - T_W_F[0, 3], T_W_C[1, 3] - T_W_F[1, 3], T_W_C[2, 3] - T_W_F[2, 3]
    tx = wrench[3] + (ry * fz - rz * fy)
    ty = wrench[4] + (rz * fx - rx * fz)
    tz = wrench[5] + (rx * fy - ry * fx)
    load = np.empty(6)
    for a in range(3):  # R_F_W = R_W_F^T
        load[a] = T_W_F[0, a] * fx + T_W_F[1, a] * fy + T_W_F[2, a] * fz
        load[a + 3] = T_W_F[0, a] * tx + T_W_F[1, a] * ty + T_W_F[2, a] * tz
    n = ring.shape[0]
    for k in range(6):
        v = load[k] + bias[k] + noise_std[k] * normals[k]
        if v < -range_S[k]:
            v = -range_S[k]
        elif v > range_S[k]:
            v = range_S[k]
        if fill:
            for r in range(n):
                ring[r, k] = v
        else:
            ring[head, k] = v
    oldest = (head + 1) % n
    for k in range(6):
        out[k] = ring[oldest, k]


@njit(cache=True, fastmath=False)
def _deadband(v, threshold, soft):
    """Deadband on the magnitude of a 3-vector, in place, direction kept.

    hard: v if |v| > threshold else 0 (a step at the edge; real pushes come through
    unchanged); soft: (|v| − threshold)·v/|v| above, 0 below (continuous, every output
    shrunk by the threshold).
    """
    n = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    if n <= threshold:
        v[0] = v[1] = v[2] = 0.0
    elif soft:
        s = (n - threshold) / n
        v[0] *= s
        v[1] *= s
        v[2] *= s


@njit(cache=True, fastmath=False)
def process_step(wrench_S, T_W_F, T_W_C, R_W_R, gravity, payload, accel, inertial, bias,
                 mass, com, alpha, state, db_force, db_torque, soft, out):
    """One cycle of the lab's processing chain; the filter state (6,) is updated in place.

    Bias removal → payload compensation ``m g`` (and, with ``inertial``, ``−m a``) in S
    with its moment ``c × f`` → first-order low-pass → moment shifted from S to the COM by
    the filtered force → deadbands on the force and on the torque about the COM → force
    rotated into R, torque into the body axes. The shift uses the whole force, whatever
    the force deadband keeps: a push through the COM then gives no torque, even one just
    under the force deadband (shifting by the force that passed would hand the ODS its
    lever-arm moment, r × F, as a false torque). T_W_F, T_W_C and accel are those of the
    instant the reading was taken. Fills out (12,) with the force in R, the torque about
    the COM in body axes and the processed wrench in S axes (moment about the COM).
    """
    ge = np.empty(3)
    for a in range(3):
        ge[a] = gravity[a] if payload else 0.0
        if inertial:
            ge[a] = ge[a] - accel[a]
    gx, gy, gz = mass * ge[0], mass * ge[1], mass * ge[2]
    lf = (T_W_F[0, 0] * gx + T_W_F[1, 0] * gy + T_W_F[2, 0] * gz,
          T_W_F[0, 1] * gx + T_W_F[1, 1] * gy + T_W_F[2, 1] * gz,
          T_W_F[0, 2] * gx + T_W_F[1, 2] * gy + T_W_F[2, 2] * gz)
    lt = (com[1] * lf[2] - com[2] * lf[1],
          com[2] * lf[0] - com[0] * lf[2],
          com[0] * lf[1] - com[1] * lf[0])
    w = out[6:12]
    for a in range(3):
        w[a] = (wrench_S[a] - bias[a]) - lf[a]
        w[a + 3] = (wrench_S[a + 3] - bias[a + 3]) - lt[a]
    for k in range(6):
        state[k] += alpha * (w[k] - state[k])
        w[k] = state[k]
    f = w[0:3]
    dx, dy, dz = T_W_C[0, 3] - T_W_F[0, 3], T_W_C[1, 3] - T_W_F[1, 3], T_W_C[2, 3] - T_W_F[2, 3]
    r = (T_W_F[0, 0] * dx + T_W_F[1, 0] * dy + T_W_F[2, 0] * dz,
         T_W_F[0, 1] * dx + T_W_F[1, 1] * dy + T_W_F[2, 1] * dz,
         T_W_F[0, 2] * dx + T_W_F[1, 2] * dy + T_W_F[2, 2] * dz)
    w[3] -= r[1] * f[2] - r[2] * f[1]
    w[4] -= r[2] * f[0] - r[0] * f[2]
    w[5] -= r[0] * f[1] - r[1] * f[0]
    _deadband(f, db_force, soft)
    tc = w[3:6]
    _deadband(tc, db_torque, soft)
    fW0 = T_W_F[0, 0] * f[0] + T_W_F[0, 1] * f[1] + T_W_F[0, 2] * f[2]
    fW1 = T_W_F[1, 0] * f[0] + T_W_F[1, 1] * f[1] + T_W_F[1, 2] * f[2]
    fW2 = T_W_F[2, 0] * f[0] + T_W_F[2, 1] * f[1] + T_W_F[2, 2] * f[2]
    tW0 = T_W_F[0, 0] * tc[0] + T_W_F[0, 1] * tc[1] + T_W_F[0, 2] * tc[2]
    tW1 = T_W_F[1, 0] * tc[0] + T_W_F[1, 1] * tc[1] + T_W_F[1, 2] * tc[2]
    tW2 = T_W_F[2, 0] * tc[0] + T_W_F[2, 1] * tc[1] + T_W_F[2, 2] * tc[2]
    for a in range(3):
        out[a] = R_W_R[0, a] * fW0 + R_W_R[1, a] * fW1 + R_W_R[2, a] * fW2
        out[a + 3] = T_W_C[0, a] * tW0 + T_W_C[1, a] * tW1 + T_W_C[2, a] * tW2


@njit(cache=True, fastmath=False)
def process_cycle(wrench_S, T_W_F, T_W_C, R_W_R, gravity, payload, accel, inertial, bias,
                  mass, com, alpha, contact_alpha, state, contact_state, gate_open,
                  reset_slow, db_force, db_torque, soft, scratch, out):
    """One cycle of the chain with both its filters (:meth:`WrenchProcessor.process`):
    ``reset_slow`` zeroes the slow filter's state first (a gate that has just closed);
    :func:`process_step` at ``alpha`` always runs, into out (12,), or into scratch when
    the gate is open and the contact's filter (``contact_alpha``) differs, which then
    runs from its own state into out; with the gate closed the contact's state follows
    the slow one."""
    if reset_slow:
        for k in range(6):
            state[k] = 0.0
    dual = gate_open and contact_alpha != alpha
    process_step(wrench_S, T_W_F, T_W_C, R_W_R, gravity, payload, accel, inertial, bias,
                 mass, com, alpha, state, db_force, db_torque, soft, scratch if dual else out)
    if not gate_open:
        for k in range(6):
            contact_state[k] = state[k]
    elif dual:
        process_step(wrench_S, T_W_F, T_W_C, R_W_R, gravity, payload, accel, inertial, bias,
                     mass, com, contact_alpha, contact_state, db_force, db_torque, soft, out)


@njit(cache=True, fastmath=False, inline="always")
def push_pose(poses, at, T_W_F, T_W_C, accel, age):
    """Keep this cycle's (T_W_F, T_W_C, accel) in the ring ``poses`` (K, :data:`POSE_ROW`)
    (at: [rows kept, newest row], at most K kept, the oldest overwritten); returns the
    row of the cycle ``age`` calls ago, or the oldest kept when fewer are."""
    k = poses.shape[0]
    head = (at[1] + 1) % k
    kept = min(at[0] + 1, k)
    at[0], at[1] = kept, head
    row = poses[head]
    for a in range(4):
        for b in range(4):
            row[4 * a + b] = T_W_F[a, b]
            row[16 + 4 * a + b] = T_W_C[a, b]
    for a in range(3):
        row[32 + a] = accel[a]
    return (head - min(age, kept - 1)) % k


# --- the sensor and the processing chain ---------------------------------------------------


class VirtualFTSensor:
    """An F/T sensor (by default the UR10e's built-in one; ``[sensor] model``): true load +
    bias + Gaussian noise, saturated, held, delayed.

    Per component, in this order: reading = clip(load + bias + noise, ±range); a sensor
    slower than the loop (``sample_rate_hz`` below ``rate_hz``) takes a new reading only
    when its sample clock ticks and repeats the last one in between; the reading handed
    out is the one of ``delay_cycles`` calls ago. Until that many calls have been made, the
    first reading is repeated (the ring starts full of it). The noise is drawn on every
    call, so the generator's stream is the same whatever the sample rate.
    """

    mass_kg = _packed(slice(0, 1), "What the sensor carries [kg].", scalar=True)
    gravity_W_mps2 = _packed(slice(1, 4), "(3,) the lab's gravity in W [m/s²].")
    bias_S = _packed(slice(4, 10), "(6,) the sensor's bias [N, N·m].")
    noise_std_S = _packed(slice(10, 16), "(6,) the noise's standard deviation per axis.")
    range_S = _packed(slice(16, 22), "(6,) the range each axis saturates at.")

    def __init__(
        self,
        config: SensorConfig,
        mass_kg: float,
        gravity_W_mps2: np.ndarray,
        rng: np.random.Generator,
        rate_hz: float | None = None,
    ) -> None:
        self.config = config
        self.every_cycles = (1.0 if rate_hz is None
                            else sample_every_cycles(config.sample_rate_hz, rate_hz))
        """Loop cycles per new reading (1: every call samples; more: the reading is held
        between samples, the zero-order hold of a sensor slower than the loop; without the
        loop's ``rate_hz``, every call samples)."""
        self.constants = np.zeros(SENSOR_CONSTANTS)
        """The sensor's constants in one buffer (the compiled sensor path takes it as one
        argument): ``mass_kg``, ``gravity_W_mps2``, ``bias_S``, ``noise_std_S`` and
        ``range_S`` are views of it (:data:`SENSOR_CONSTANTS`)."""
        self.mass_kg = float(mass_kg)
        self.gravity_W_mps2 = gravity_W_mps2
        self.rng = rng  # (the property: an empty block of normals)
        self.bias_S = np.array([*config.bias_force_N, *config.bias_torque_Nm], dtype=float)
        self.noise_std_S = np.array(
            [config.noise_force_N] * 3 + [config.noise_torque_Nm] * 3, dtype=float
        )
        self.range_S = np.array(
            [config.range_force_N] * 3 + [config.range_torque_Nm] * 3, dtype=float
        )
        self._ring = np.zeros((config.delay_cycles + 1, 6))
        self._held_for = np.zeros(config.delay_cycles + 1, dtype=np.int64)
        """Per ring row: for how many calls its reading had been held when written."""
        self._head = -1  # index of the newest reading; -1: ring not yet filled
        self._calls = 0  # calls since the last reset (the hold's clock)
        self.age_cycles = config.delay_cycles
        """How many calls ago the reading last handed out was taken: the delay, plus the
        cycles it had been held (a lab knows it from the sensor's sample counter)."""

    @property
    def rng(self) -> np.random.Generator:
        """The generator the noise is drawn from, by blocks of :data:`NORMALS_BLOCK` × 6
        (:meth:`next_normals`), which this sensor alone draws from; assigning one (a
        reseeding) drops the draws left in the block, so the next six are the new
        generator's first."""
        return self._rng

    @rng.setter
    def rng(self, rng: np.random.Generator) -> None:
        self._rng = rng
        self._normals = _NO_NORMALS
        self._normals_at = 0

    def next_normals(self) -> np.ndarray:
        """The next six standard normal draws (a view of a row of the block): the same
        numbers, in the same order, as ``rng.standard_normal(6)`` called once per cycle,
        for a Generator hands out its normals in a stream that does not depend on how
        many are asked at a time (a block costs about one call, a row a tenth of it)."""
        k = self._normals_at
        if k == len(self._normals):
            self._normals = self._rng.standard_normal((NORMALS_BLOCK, 6))
            k = 0
        self._normals_at = k + 1
        return self._normals[k]

    def reset(self) -> None:
        """Forget past readings (the next call refills the delay ring; the noise goes on
        from where it was)."""
        self._head = -1
        self._calls = 0

    def _samples_now(self) -> bool:
        """Whether this call takes a new reading: the first call, then each call in which
        the sensor's sample clock (one sample every ``every_cycles`` calls) ticks."""
        k, n = self._calls, self.every_cycles
        self._calls += 1
        return n == 1.0 or k == 0 or math.floor(k / n) > math.floor((k - 1) / n)

    def advance(self) -> tuple[np.ndarray, bool, np.ndarray | None]:
        """The bookkeeping of one call, before the reading: (the six normal draws, whether
        the delay ring is to be filled, the held reading handed out when the sensor does
        not sample in this call, else None); the ring's head and ``age_cycles`` move on."""
        normals = self.next_normals()
        if self.every_cycles == 1.0 and self._head >= 0:
            # a sensor that samples every call, its ring filled: nothing is ever held
            # (every _held_for stays 0, age_cycles the delay), only the head moves on
            self._head = (self._head + 1) % self._ring.shape[0]
            return normals, False, None
        fill = self._head < 0
        held = None if fill or self.every_cycles == 1.0 else self._ring[self._head].copy()
        self._head = 0 if fill else (self._head + 1) % self._ring.shape[0]
        n = self._ring.shape[0]
        oldest = (self._head + 1) % n
        if held is not None and not self._samples_now():  # zero-order hold
            self._held_for[self._head] = self._held_for[(self._head - 1) % n] + 1
            self._ring[self._head] = held
            self.age_cycles = self.config.delay_cycles + int(self._held_for[oldest])
            return normals, fill, self._ring[oldest].copy()
        if fill:
            self._samples_now()
            self._held_for[:] = 0
        self._held_for[self._head] = 0
        self.age_cycles = self.config.delay_cycles + int(self._held_for[oldest])
        return normals, fill, None

    def measure(
        self,
        wrench_ext_W: np.ndarray,
        T_W_C: np.ndarray,
        T_W_F: np.ndarray,
        accel_W_mps2: np.ndarray | None = None,
    ) -> np.ndarray:
        """One cycle: the delayed raw reading (6,) in S [N, N·m], moments about S's origin.

        wrench_ext_W: sum of external wrenches on the mockup (W axes, moment about C);
        T_W_C, T_W_F: mockup COM and flange poses; accel_W_mps2: the mockup COM's linear
        acceleration in W (None: at rest).
        """
        normals, fill, held = self.advance()
        if held is not None:
            return held
        accel = _ZERO3 if accel_W_mps2 is None else np.asarray(accel_W_mps2, dtype=float)
        out = np.empty(6)
        sensor_step(
            np.asarray(wrench_ext_W, dtype=float), T_W_C, T_W_F, self.mass_kg,
            self.gravity_W_mps2, accel, normals, self.bias_S, self.noise_std_S, self.range_S,
            self._ring, self._head, fill, out,
        )
        return out


def lowpass_alpha(cutoff_hz: float, rate_hz: float) -> float:
    """Smoothing factor of the discrete first-order low-pass y += α (x − y).

    Exact discretisation (zero-order hold) of 1/(1 + s/ω_c): α = 1 − exp(−ω_c / rate).
    """
    return 1.0 - math.exp(-2.0 * math.pi * cutoff_hz / rate_hz)


@dataclass(frozen=True)
class Calibration:
    """Result of a calibration: sensor bias (in S) and the payload's mass and COM."""

    bias_S: np.ndarray
    """(6,) [N, N·m] subtracted from every reading."""
    mass_kg: float
    com_F_m: np.ndarray
    """(3,) payload COM in the flange frame."""
    force_noise_cov_S: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    """(3, 3) [N²] covariance of the force readings about the fit, in S: the sensor's
    noise as the calibration measured it (not as configured)."""
    torque_noise_cov_S: np.ndarray = field(default_factory=lambda: np.zeros((3, 3)))
    """(3, 3) [N²·m²] covariance of the torque about the COM the readings give about the
    fit (the sensor's torque noise and the lever arm of its force noise), in S."""


class ProcessedWrench(NamedTuple):
    """Output of one processing cycle (a named tuple: built every cycle, it costs a
    third of a frozen dataclass)."""

    force_R_N: np.ndarray
    """(3,) external force on the satellite in R: ODS input (the ODS applies its scales)."""
    torque_B_Nm: np.ndarray
    """(3,) external torque about the COM in body axes: ODS input."""
    wrench_S: np.ndarray
    """(6,) compensated, filtered, deadbanded wrench in S axes, moment about the COM,
    unscaled."""


class WrenchProcessor:
    """The lab's processing chain from a raw reading in S to the ODS's (F in R, τ in B).

    Stages: bias removal (calibration) → payload (gravity) compensation → optional inertial
    compensation → first-order low-pass at the loop rate → shift of the moment from S to
    the COM → deadband (force and COM-torque magnitudes) → rotation (force into R, torque
    into the body axes C). The force and torque scales of the configuration ([orbit]) are
    applied by the ODS, the one place that owns them.

    Time alignment: a reading is ``delay_cycles`` old when it arrives (the sensor's known
    latency; more for a held reading of a slower sensor: ``reading_age_cycles``), so the
    poses and the acceleration it is compensated, shifted and rotated with are those of the
    cycle it was taken in, kept in a short ring.

    Noise floor: a deadband lets the noise through whenever the filtered noise's
    magnitude crosses it. At the data sheet's noise, the 0.25 N·m torque deadband is about
    4.4 σ of the filtered COM torque (σ ≈ 0.058 N·m on its largest axis): a crossing every
    few tens of seconds at rest, each a step of about 6e-5 rad/s of a free-floating
    CubeSat's spin. So the calibration raises each deadband to ``deadband_noise_sigmas``
    (6) times the standard deviation, on its largest principal axis, of the noise it
    measured at rest, passed through the low-pass (white noise: variance × α / (2 − α)).
    The magnitude of a 3-D Gaussian exceeds 6 σ_max with probability under 1e-7 per
    sample, about one crossing in 6 hours at 500 Hz: the torque deadband becomes
    0.35 N·m, the force deadband 4.3 N at the data sheet's noise.

    Contact gate: with ``gate_open`` (the lab's geometry says the mockup is touching or
    about to touch another body), the deadbands are lifted, so that a contact force below
    the noise threshold still reaches the ODS whole.
    """

    gravity_W_mps2 = _packed(slice(0, 3), "(3,) the lab's gravity in W [m/s²].")
    alpha = _packed(slice(15, 16), "The low-pass's α (:func:`lowpass_alpha`).", scalar=True)
    contact_alpha = _packed(slice(16, 17), "The contact filter's α (the gate open).",
                            scalar=True)
    _state_S = property(lambda self: self._x[0:6],
                        lambda self, v: self._x.__setitem__(slice(0, 6), v))
    _contact_state_S = property(lambda self: self._x[6:12],
                                lambda self, v: self._x.__setitem__(slice(6, 12), v))
    _scratch = property(lambda self: self._x[12:24])

    @property
    def config(self) -> WrenchProcessingConfig:
        return self._config

    @config.setter
    def config(self, config: WrenchProcessingConfig) -> None:
        """The configuration, its switches packed into :attr:`constants` too."""
        self._config = config
        c = self.constants
        c[3] = float(config.payload_compensation)
        c[4] = float(config.inertial_compensation)
        c[17] = float(config.deadband_mode == "soft")

    @property
    def calibration(self) -> Calibration:
        """The payload calibration (:meth:`calibrate`); assigning one (an immutable
        :class:`Calibration`) packs its bias, mass and COM into :attr:`constants`."""
        return self._calibration

    @calibration.setter
    def calibration(self, cal: Calibration) -> None:
        """Its arrays are kept as read-only copies: an in-place change would reach the
        stages but not the packed buffer (a new Calibration is the way to change one)."""
        bias_S, com_F_m = _frozen(cal.bias_S, (6,)), _frozen(cal.com_F_m, (3,))
        cal = replace(cal, bias_S=bias_S, com_F_m=com_F_m, mass_kg=float(cal.mass_kg))
        c = self.constants
        c[5:11] = bias_S
        c[11] = cal.mass_kg
        c[12:15] = com_F_m
        self._calibration = cal

    def __init__(
        self,
        config: WrenchProcessingConfig,
        rate_hz: float,
        gravity_W_mps2: np.ndarray,
        delay_cycles: int = 0,
        max_age_cycles: int | None = None,
    ) -> None:
        self.constants = np.zeros(PROCESSOR_CONSTANTS)
        """The chain's constants in one buffer (:data:`PROCESSOR_CONSTANTS`), which the
        compiled sensor path takes as one argument: ``gravity_W_mps2``, ``alpha``,
        ``contact_alpha``, the switches of ``config`` and the ``calibration``'s bias,
        mass and COM are kept in it."""
        self._x = np.zeros(PROCESSOR_STATE)
        """The filters' states and the kernel's scratch (:data:`PROCESSOR_STATE`)."""
        self.config = config
        self.gravity_W_mps2 = gravity_W_mps2
        self.alpha = lowpass_alpha(config.lowpass_hz, rate_hz)
        self.contact_alpha = (self.alpha if config.contact_lowpass_hz is None
                              else lowpass_alpha(config.contact_lowpass_hz, rate_hz))
        self.calibration = Calibration(np.zeros(6), 0.0, np.zeros(3))
        self._filtered_cov: tuple | None = None  # (calibration, α, its filtered Σ_f)
        self.deadband_force_N = float(config.deadband_force_N)
        self.deadband_torque_Nm = float(config.deadband_torque_Nm)
        """The deadbands applied (force N, torque about the COM N·m): the configured
        ones, raised by the calibration to ``deadband_noise_sigmas`` times the filtered
        noise it measured where that is larger."""
        self.delay_cycles = int(delay_cycles)
        self.max_age_cycles = self.delay_cycles if max_age_cycles is None \
            else max(int(max_age_cycles), self.delay_cycles)
        """The oldest a reading can be when it arrives: the delay, plus the hold of a
        sensor slower than the loop."""
        self.reading_age_cycles = self.delay_cycles
        """How old the next reading is (set by the rig from the sensor's ``age_cycles``
        before each :meth:`process`; the delay when the sensor samples every cycle)."""
        self._gate_was_open = False
        self._poses = np.zeros((self.max_age_cycles + 1, POSE_ROW))
        """The ring of the last cycles' (T_W_F, T_W_C, accel), one row each
        (:func:`push_pose`), that a delayed reading is aligned with."""
        self._pose_at = np.array([0, -1], dtype=np.int64)
        """(rows of ``_poses`` kept, its newest row)."""

    def reset(self) -> None:
        """Reset the filter states to zero (the expected compensated wrench at rest) and
        forget the poses of past readings."""
        self._state_S = np.zeros(6)
        self._contact_state_S = np.zeros(6)
        self._gate_was_open = False
        self._pose_at[:] = (0, -1)

    def _aligned(self, T_W_F: np.ndarray, T_W_C: np.ndarray,
                 accel: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(T_W_F, T_W_C, accel) of the cycle the arriving reading was taken in (views
        of the ring, where this cycle's are kept too)."""
        row = self._poses[push_pose(self._poses, self._pose_at, T_W_F, T_W_C,
                                       np.asarray(accel, dtype=float),
                                       self.reading_age_cycles)]
        return row[0:16].reshape(4, 4), row[16:32].reshape(4, 4), row[32:35]

    def calibrate(
        self,
        readings_S: np.ndarray,
        R_W_F: np.ndarray,
        mass_kg: float | None = None,
        com_F_m: np.ndarray | None = None,
    ) -> Calibration:
        """Estimate bias (and, if not given, payload mass and COM) from readings at rest.

        readings_S (N, 6) taken with the arm still and nothing touching the mockup; R_W_F
        the flange orientation of each reading (N, 3, 3) or one (3, 3) for all. Model:
        f = R_W_Fᵀ m g + b_f and τ = c × (R_W_Fᵀ m g) + b_τ, solved by least squares. A
        known mass/COM (from the mockup's data) needs one pose; estimating them needs at
        least two (mass) or three (COM) poses with different gravity directions in F.
        mass_kg=0 gives a plain tare (zeroes the weight at that pose only).
        """
        readings_S = np.atleast_2d(np.asarray(readings_S, dtype=float))
        R = np.asarray(R_W_F, dtype=float)
        R = np.broadcast_to(R, (len(readings_S), 3, 3))
        g_F = np.einsum("nji,j->ni", R, self.gravity_W_mps2)  # R_W_Fᵀ g per sample
        mass, bias_f = self._fit_force(readings_S[:, :3], g_F, mass_kg)
        com, bias_t = self._fit_torque(readings_S[:, 3:], mass * g_F, com_F_m)
        residual = readings_S[:, :3] - mass * g_F - bias_f
        residual_t = (readings_S[:, 3:] - np.cross(com, mass * g_F) - bias_t
                      - np.cross(com, residual))  # about the COM: τ_S − c × f
        n = len(residual)
        cov = residual.T @ residual / (n - 1) if n > 1 else np.zeros((3, 3))
        cov_t = residual_t.T @ residual_t / (n - 1) if n > 1 else np.zeros((3, 3))
        self.calibration = Calibration(np.concatenate([bias_f, bias_t]), mass, com, cov,
                                       cov_t)
        self.set_deadbands()
        self.reset()
        return self.calibration

    def set_deadbands(self) -> None:
        """The deadbands from the configuration and the calibration's noise (module
        doc of :class:`WrenchProcessor`, noise floor)."""
        cfg, cal = self.config, self.calibration
        gain = self.alpha / (2.0 - self.alpha)  # white noise through the low-pass
        floor = [cfg.deadband_noise_sigmas
                 * math.sqrt(max(0.0, float(np.linalg.eigvalsh(c * gain)[-1])))
                 for c in (cal.force_noise_cov_S, cal.torque_noise_cov_S)]
        self.deadband_force_N = max(cfg.deadband_force_N, floor[0])
        self.deadband_torque_Nm = max(cfg.deadband_torque_Nm, floor[1])

    def filtered_force_cov(self, R_X_S: np.ndarray) -> np.ndarray:
        """(3, 3) [N²] covariance of the noise on the chain's filtered force while the
        contact gate is open, in the axes X with R_X_S the sensor's orientation in them:
        the calibration's estimate of the reading noise through the low-pass at
        ``contact_lowpass_hz`` (white noise: variance × α / (2 − α))."""
        cal, alpha, kept = self.calibration, self.contact_alpha, self._filtered_cov
        if kept is None or kept[0] is not cal or kept[1] != alpha:  # the calibration's
            kept = self._filtered_cov = (cal, alpha, cal.force_noise_cov_S
                                         * (alpha / (2.0 - alpha)))
        return R_X_S.dot(kept[2]).dot(R_X_S.T)  # `@`'s gemm calls, less overhead

    @staticmethod
    def _fit_force(
        f: np.ndarray, g_F: np.ndarray, mass_kg: float | None
    ) -> tuple[float, np.ndarray]:
        if mass_kg is not None:
            return float(mass_kg), (f - mass_kg * g_F).mean(axis=0)
        A = np.zeros((3 * len(f), 4))
        A[:, 0] = g_F.ravel()
        A[:, 1:] = np.tile(np.eye(3), (len(f), 1))
        x, _, rank, _ = np.linalg.lstsq(A, f.ravel(), rcond=None)
        if rank < 4:
            raise ValueError("calibration: mass needs readings in two or more orientations")
        return float(x[0]), x[1:]

    @staticmethod
    def _fit_torque(
        t: np.ndarray, w_F: np.ndarray, com_F_m: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray]:
        if com_F_m is not None:
            com = np.array(com_F_m, dtype=float)  # a contiguous copy (as the kernel likes)
            return com, (t - np.cross(com, w_F)).mean(axis=0)
        A = np.zeros((3 * len(t), 6))
        for k, w in enumerate(w_F):
            A[3 * k : 3 * k + 3, :3] = -skew(w)  # c × w = −w × c
            A[3 * k : 3 * k + 3, 3:] = np.eye(3)
        x, _, rank, _ = np.linalg.lstsq(A, t.ravel(), rcond=None)
        if rank < 6:
            raise ValueError("calibration: COM needs readings in three or more orientations")
        return x[:3], x[3:]

    def begin(self, T_W_F: np.ndarray, T_W_C: np.ndarray, accel: np.ndarray,
              gate_open: bool) -> tuple[tuple, float, float, bool]:
        """The bookkeeping of one cycle, before the chain runs: ((T_W_F, T_W_C, accel) of
        the cycle the arriving reading was taken in, the force and torque deadbands, whether
        the slow filter restarts from rest).

        The filter at lowpass_hz always runs, so that the chain returns to it without a
        step when the gate closes; the contact's filter starts from it when it opens.
        When the gate closes after a contact the contact's force has been delivered whole
        by the contact's filter: the slow filter restarts from rest, so that its lagging
        copy of the contact (up to several N after a rigid one) is not handed over a
        second time."""
        return (self._aligned(T_W_F, T_W_C, accel), *self.gate(gate_open))

    def gate(self, gate_open: bool) -> tuple[float, float, bool]:
        """:meth:`begin`'s bookkeeping of the gate: (the force and torque deadbands,
        whether the slow filter restarts from rest)."""
        db_force, db_torque = ((0.0, 0.0) if gate_open
                               else (self.deadband_force_N, self.deadband_torque_Nm))
        reset_slow = self._gate_was_open and not gate_open and self.contact_alpha != self.alpha
        self._gate_was_open = gate_open
        return db_force, db_torque, reset_slow

    def process(
        self,
        wrench_S: np.ndarray,
        T_W_F: np.ndarray,
        T_W_C: np.ndarray,
        R_W_R: np.ndarray,
        accel_W_mps2: np.ndarray | None = None,
        gate_open: bool = False,
    ) -> ProcessedWrench:
        """One cycle: raw reading in S → ODS input (force in R, torque about COM in B).

        T_W_F: flange (= sensor) pose now; T_W_C: mockup COM pose now (its axes are the
        body axes B); R_W_R: orientation of the CW frame R in W; accel_W_mps2: the lab's
        estimate of the mockup's acceleration now, in W (used only with
        inertial_compensation); gate_open: lift the deadbands (a contact is near) and
        filter at ``contact_lowpass_hz``.
        """
        cfg, cal = self.config, self.calibration
        if cfg.inertial_compensation and accel_W_mps2 is None:
            raise ValueError("inertial_compensation needs the mockup's acceleration")
        accel = _ZERO3 if accel_W_mps2 is None else np.asarray(accel_W_mps2, dtype=float)
        (T_W_F, T_W_C, accel), db_force, db_torque, reset_slow = self.begin(
            T_W_F, T_W_C, accel, gate_open)
        out = np.empty(12)
        process_cycle(np.asarray(wrench_S, dtype=float), T_W_F, T_W_C, R_W_R,
                      self.gravity_W_mps2, cfg.payload_compensation, accel,
                      cfg.inertial_compensation, cal.bias_S, cal.mass_kg, cal.com_F_m,
                      self.alpha, self.contact_alpha, self._state_S, self._contact_state_S,
                      gate_open, reset_slow, db_force, db_torque,
                      cfg.deadband_mode == "soft", self._scratch, out)
        return ProcessedWrench(force_R_N=out[0:3], torque_B_Nm=out[3:6], wrench_S=out[6:12])
