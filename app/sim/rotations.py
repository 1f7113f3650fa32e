"""Rotation helpers shared by the numeric core.

Conventions used everywhere in orbit-emulator:

* quaternions are stored scalar-first, ``q = [w, x, y, z]`` (as in the configuration
  files and the telemetry; the tests' Pinocchio oracles convert from its ``[x, y, z, w]``);
* ``R_A_B`` is the rotation matrix that maps coordinates in frame B to frame A, and a
  quaternion named ``q_A_B`` represents the same rotation;
* ``T_A_B`` is the 4x4 homogeneous transform with ``R_A_B`` and the origin of B in A.
"""

from __future__ import annotations

import numpy as np


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b of two 3-vectors: the same products and differences as ``np.cross`` (so the
    same bits), without its overhead on tiny arrays (~10 µs against ~1 µs)."""
    return np.array(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )


def cross3_floats(a: list[float], b: list[float]) -> list[float]:
    """:func:`cross3` on plain floats (the same products and differences: the same bits),
    for a few vectors in a cycle, where array calls cost more than the arithmetic."""
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def minus3_floats(a: list[float], b: list[float]) -> list[float]:
    """a − b of two 3-vectors of plain floats."""
    return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]


def point_velocity_floats(v: list[float], w: list[float], r: list[float]) -> list[float]:
    """v + ω × r on plain floats: the velocity of a body's point at offset r from its COM
    (as ``v + cross3(w, r)`` on arrays, to the bit)."""
    c = cross3_floats(w, r)
    return [v[0] + c[0], v[1] + c[1], v[2] + c[2]]


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix: ``skew(a) @ b == np.cross(a, b)``."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """Unit quaternion with non-negative scalar part (one representative per rotation)."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return q


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a ⊗ b`` (wxyz); works on (..., 4) arrays."""
    aw, ax, ay, az = np.moveaxis(np.asarray(a, dtype=float), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b, dtype=float), -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrix of a unit quaternion; (..., 4) -> (..., 3, 3)."""
    w, x, y, z = np.moveaxis(np.asarray(q, dtype=float), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=-2,
    )


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (wxyz, w >= 0) of a rotation matrix (Shepperd's method)."""
    R = np.asarray(R, dtype=float)
    tr = np.trace(R)
    if tr > 0.0:
        s = 2.0 * np.sqrt(1.0 + tr)
        q = np.array(
            [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
        )
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + R[i, i] - R[j, j] - R[k, k])
        q = np.empty(4)
        q[0] = (R[k, j] - R[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (R[j, i] + R[i, j]) / s
        q[1 + k] = (R[k, i] + R[i, k]) / s
    if q[0] < 0.0:
        q = -q
    return q / np.linalg.norm(q)


def rotvec_to_matrix(v: np.ndarray) -> np.ndarray:
    """Rodrigues' formula: rotation of angle |v| about v/|v| (exponential map of SO(3))."""
    v = np.asarray(v, dtype=float)
    theta = float(np.linalg.norm(v))
    K = skew(v)
    if theta < 1e-8:
        return np.eye(3) + K + 0.5 * K @ K
    return (
        np.eye(3) + (np.sin(theta) / theta) * K + ((1.0 - np.cos(theta)) / theta**2) * (K @ K)
    )


def matrix_to_rotvec(R: np.ndarray) -> np.ndarray:
    """Rotation vector of R (logarithm map of SO(3)), angle in [0, pi]."""
    q = matrix_to_quat(R)
    return quat_to_rotvec(q)


def quat_to_rotvec(q: np.ndarray) -> np.ndarray:
    """Rotation vector of a unit quaternion, taking the shorter way round."""
    q = np.asarray(q, dtype=float)
    if q[0] < 0.0:
        q = -q
    s = float(np.linalg.norm(q[1:]))
    if s < 1e-12:
        return 2.0 * q[1:]
    angle = 2.0 * np.arctan2(s, q[0])
    return q[1:] * (angle / s)


def rotvec_to_quat(v: np.ndarray) -> np.ndarray:
    """Unit quaternion (wxyz) of a rotation vector."""
    v = np.asarray(v, dtype=float)
    theta = float(np.linalg.norm(v))
    if theta < 1e-12:
        return quat_normalize(np.concatenate([[1.0], 0.5 * v]))
    return np.concatenate([[np.cos(theta / 2)], np.sin(theta / 2) * v / theta])


def make_transform(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """4x4 homogeneous transform from a rotation matrix and a translation."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = p
    return T


def invert_transform(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform without a general matrix inverse."""
    Ti = np.eye(4)
    Ti[:3, :3] = T[:3, :3].T
    Ti[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return Ti
