"""Frame transformations of the loop (DESIGN.md "Frames"), compiled.

The ODS state lives in the CW frame R; the arms and the contact live in the lab W; each
arm's VFDM wants its TCP target in its base frame B. With a constant ``T_A_R`` (the lab
pose ``T_W_R``, or an arm's ``T_B_R = inv(T_W_B) · T_W_R``) a satellite's pose in A is
``T_A_R · T_R_S`` (the TCP target ``T_B_C* = inv(T_W_B) · T_W_R · T_R_sat`` of DESIGN.md).
The rotation formulas are those of :mod:`app.sim.rotations`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

__all__ = [
    "Bodies",
    "matrix_to_quat_into",
    "ods_states_W",
    "pose_distance",
    "satellite_pose",
    "tracking_error",
    "tracking_errors",
]


class Bodies(NamedTuple):
    """Pose and velocity of every body (mockup or satellite) in the lab W: the lab's
    forward kinematics of the arms (hil), or the ODS's satellites (ideal)."""

    T_W_C: np.ndarray
    """(N, 4, 4) COM poses."""
    v_W: np.ndarray
    """(N, 3) COM velocities."""
    w_W: np.ndarray
    """(N, 3) angular velocities."""


@njit(cache=True, fastmath=False)
def satellite_pose(T_A_R, y, i, out):
    """out (4, 4) := T_A_R · T_R_S of satellite i of the ODS state y (N, 13). IndexError:
    i not a row of y."""
    if i < 0 or i >= y.shape[0]:
        raise IndexError("satellite_pose: no such satellite in the ODS state")
    px, py, pz = y[i, 0], y[i, 1], y[i, 2]
    w, x, yy, z = y[i, 6], y[i, 7], y[i, 8], y[i, 9]
    R00, R01, R02 = 1 - 2 * (yy * yy + z * z), 2 * (x * yy - w * z), 2 * (x * z + w * yy)
    R10, R11, R12 = 2 * (x * yy + w * z), 1 - 2 * (x * x + z * z), 2 * (yy * z - w * x)
    R20, R21, R22 = 2 * (x * z - w * yy), 2 * (yy * z + w * x), 1 - 2 * (x * x + yy * yy)
    for a in range(3):
        A0, A1, A2 = T_A_R[a, 0], T_A_R[a, 1], T_A_R[a, 2]
        out[a, 0] = A0 * R00 + A1 * R10 + A2 * R20
        out[a, 1] = A0 * R01 + A1 * R11 + A2 * R21
        out[a, 2] = A0 * R02 + A1 * R12 + A2 * R22
        out[a, 3] = A0 * px + A1 * py + A2 * pz + T_A_R[a, 3]
    out[3, 0] = out[3, 1] = out[3, 2] = 0.0
    out[3, 3] = 1.0


@njit(cache=True, fastmath=False)
def ods_states_W(T_W_R, y, T_W_S, v_W):
    """Every satellite's pose T_W_S (N, 4, 4) and COM velocity v_W (N, 3) in the lab."""
    for i in range(y.shape[0]):
        satellite_pose(T_W_R, y, i, T_W_S[i])
        for a in range(3):
            v_W[i, a] = T_W_R[a, 0] * y[i, 3] + T_W_R[a, 1] * y[i, 4] + T_W_R[a, 2] * y[i, 5]


@njit(cache=True, fastmath=False)
def matrix_to_quat_into(R, out, k):
    """out[k:k + 4] := the unit quaternion (wxyz, w ≥ 0) of the 3x3 rotation R (Shepperd)."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    q0 = q1 = q2 = q3 = 0.0
    if tr > 0.0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q0, q1 = 0.25 * s, (R[2, 1] - R[1, 2]) / s
        q2, q3 = (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s
    else:
        i = 0
        if R[1, 1] > R[i, i]:
            i = 1
        if R[2, 2] > R[i, i]:
            i = 2
        j, m = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * math.sqrt(1.0 + R[i, i] - R[j, j] - R[m, m])
        v = [0.0, 0.0, 0.0]
        v[i] = 0.25 * s
        v[j] = (R[j, i] + R[i, j]) / s
        v[m] = (R[m, i] + R[i, m]) / s
        q0, q1, q2, q3 = (R[m, j] - R[j, m]) / s, v[0], v[1], v[2]
    if q0 < 0.0:
        q0, q1, q2, q3 = -q0, -q1, -q2, -q3
    n = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    out[k], out[k + 1], out[k + 2], out[k + 3] = q0 / n, q1 / n, q2 / n, q3 / n


@njit(cache=True, fastmath=False)
def pose_distance(T_a, T_b):
    """(distance m, angle rad) between two poses: |p_a − p_b| and the angle of R_aᵀ R_b."""
    dx, dy, dz = T_a[0, 3] - T_b[0, 3], T_a[1, 3] - T_b[1, 3], T_a[2, 3] - T_b[2, 3]
    tr = 0.0
    for a in range(3):
        for b in range(3):
            tr += T_a[b, a] * T_b[b, a]
    c = 0.5 * (tr - 1.0)
    c = 1.0 if c > 1.0 else (-1.0 if c < -1.0 else c)
    return math.sqrt(dx * dx + dy * dy + dz * dz), math.acos(c)


@njit(cache=True, fastmath=False)
def tracking_error(T_W_R, y, i, T_W_C):
    """(distance m, angle rad) of the pose T_W_C from satellite i's ODS pose in the lab."""
    T = np.empty((4, 4))
    satellite_pose(T_W_R, y, i, T)
    return pose_distance(T_W_C, T)


@njit(cache=True, fastmath=False)
def tracking_errors(T_W_R, y, satellites, T_W_C, max_m, max_rad, out):
    """out (k, 2) := :func:`tracking_error` of each satellite in ``satellites`` (k,), the
    body poses T_W_C (N, 4, 4) indexed by satellite; returns the first k beyond max_m or
    max_rad, or -1."""
    first = -1
    for k in range(satellites.shape[0]):
        d_m, d_rad = tracking_error(T_W_R, y, satellites[k], T_W_C[satellites[k]])
        out[k, 0], out[k, 1] = d_m, d_rad
        if first < 0 and (d_m > max_m or d_rad > max_rad):
            first = k
    return first
