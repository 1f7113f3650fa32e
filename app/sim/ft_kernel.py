"""Compiled (numba) F/T sensor reading and wrench processing, same maths as ft_sensor.py.

:func:`sensor_step` is one :meth:`VirtualFTSensor.measure` (load on the sensor, bias,
the noise drawn by the caller, saturation, delay ring); :func:`process_step` is one
:meth:`WrenchProcessor.process` (bias and payload/inertial compensation, low-pass,
deadbands, shift to the COM, rotation into R and the body axes). The Python functions of
:mod:`app.sim.ft_sensor` stay the reference.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["process_step", "sensor_step"]


@njit(cache=True, fastmath=False)
def sensor_step(wrench, T_W_C, T_W_F, mass, gravity, accel, normals, bias, noise_std,
                range_S, ring, head, fill, out):
    """One delayed raw reading into out (6,); the ring row ``head`` gets the new one.

    ``fill``: the ring is empty, every row takes the new reading. ``normals``: six
    standard normal draws (the caller's generator). ``accel``: zeros for a mockup at rest.
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
    """apply_deadband on a 3-vector, in place."""
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
    """One processing cycle; the filter state (6,) is updated in place.

    payload / inertial: the compensation stages on; ``accel``: the mockup's acceleration
    in W (used with inertial compensation). Fills out (12,) with the force in R, the
    torque about the COM in body axes and the processed wrench in S.
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
    f, t = w[0:3], w[3:6]
    _deadband(f, db_force, soft)
    _deadband(t, db_torque, soft)
    dx, dy, dz = T_W_C[0, 3] - T_W_F[0, 3], T_W_C[1, 3] - T_W_F[1, 3], T_W_C[2, 3] - T_W_F[2, 3]
    r = (T_W_F[0, 0] * dx + T_W_F[1, 0] * dy + T_W_F[2, 0] * dz,
         T_W_F[0, 1] * dx + T_W_F[1, 1] * dy + T_W_F[2, 1] * dz,
         T_W_F[0, 2] * dx + T_W_F[1, 2] * dy + T_W_F[2, 2] * dz)
    tc = (t[0] - (r[1] * f[2] - r[2] * f[1]),
          t[1] - (r[2] * f[0] - r[0] * f[2]),
          t[2] - (r[0] * f[1] - r[1] * f[0]))
    fW0 = T_W_F[0, 0] * f[0] + T_W_F[0, 1] * f[1] + T_W_F[0, 2] * f[2]
    fW1 = T_W_F[1, 0] * f[0] + T_W_F[1, 1] * f[1] + T_W_F[1, 2] * f[2]
    fW2 = T_W_F[2, 0] * f[0] + T_W_F[2, 1] * f[1] + T_W_F[2, 2] * f[2]
    tW0 = T_W_F[0, 0] * tc[0] + T_W_F[0, 1] * tc[1] + T_W_F[0, 2] * tc[2]
    tW1 = T_W_F[1, 0] * tc[0] + T_W_F[1, 1] * tc[1] + T_W_F[1, 2] * tc[2]
    tW2 = T_W_F[2, 0] * tc[0] + T_W_F[2, 1] * tc[1] + T_W_F[2, 2] * tc[2]
    for a in range(3):
        out[a] = R_W_R[0, a] * fW0 + R_W_R[1, a] * fW1 + R_W_R[2, a] * fW2
        out[a + 3] = T_W_C[0, a] * tW0 + T_W_C[1, a] * tW1 + T_W_C[2, a] * tW2
