"""A UR10e on a linear rail as one 7-joint chain: kinematics and the VFDM's dynamics, compiled.

The rail is a prismatic joint before the robot's base (DESIGN.md "Rails"): with the
carriage at s, ``T_W_B(s) = Trans(s · axis_W) · T_W_B0``. Everything here is in B0, the
base frame with the carriage at s = 0, where the rail's axis is ``a = R_W_B0ᵀ axis_W``.
The joint vector is ``q = [s, q1 … q6]`` (metres, then radians).

Kinematics: the arm's joint frames are those of :func:`app.sim.ur10e.fk_joints` moved by
``s a``; the TCP Jacobian (rows ``[v_C; ω]`` in B0 axes) gains the rail's column ``[a; 0]``
in front of the arm's six (which the translation leaves as they are).

Dynamics (Eq. 10 on the 7-joint virtual model): the arm keeps Table 1's conditioned inertia
(app/sim/vfdm.py) and the carriage gets ``virtual_mass_kg``. The joint-space inertia is the
arm's 6x6 H bordered by the rail's row,

    H[0, 0] = m_r + Σ m_k,    H[0, j] = a · (z_j × (Σ_{k≥j} m_k (c_k − p_j)))

(the rail's motion ``S_0 = [a; 0]`` against the linear momentum of the links that joint j
moves; c_k: centres of mass). Which inertia for the carriage: with Table 1's H ≈ Jᵀ Λ J,
written in the coordinates (TCP velocity u, s), the kinetic energy is ``½ Λ|u|² +
½ (m_r + m_links) ṡ²``: the carriage's mass does not enter the operational-space inertia,
so Eq. 12's decoupled, posture-independent response is kept whatever m_r, and a Cartesian
force moves the arm, the carriage only by the share that the arm's armature and 10 g
links leave it, which falls about as 1 / m_r (1.4 % of the TCP's acceleration at 1 kg, 14 % at
0.1 kg; tests/test_rail.py). What m_r sets is the inertia of the chain's one null-space
motion (the carriage moving while the arm holds the TCP still): ``nᵀ H n ≈ m_r`` for the
null vector n scaled to ṡ = 1. Table 1 makes the end link as heavy as the operational
mass it conditions (m_e = 1 kg); m_r = 1 kg does the same for the null-space motion: H's
eigenvalues stay within the spread the 6-joint model already has, the carriage stays out
of the Cartesian response, and the posture spring below alone sets how fast it follows.

Null-space posture term (not in the paper): a joint-space spring ``τ_p = −K (q_arm −
q_posture)`` on the arm's joints, whose acceleration is projected onto the null space of
the 6x7 Jacobian, dynamically consistently: ``q̈_p = n (nᵀ τ_p) / (nᵀ H n)`` (the
H-orthogonal projection of H⁻¹ τ_p on null(J), what the projector ``N = I − J̄ J``,
``J̄ = H⁻¹ Jᵀ Λ``, gives with a one-dimensional null space). n comes in closed form, with no
inverse: ``n_i = (−1)^i det(J with column i removed)`` (the generalised cross product of J's
six rows). Where the arm is singular in a direction the rail does not cover, n → 0 and the
term fades out instead of blowing up. The posture term moves the carriage and the arm
against each other with the TCP held: the arm's spring pulls the carriage along under
it, so the rail carries the gross motion and the arm the fine. Together with the VFDM's
velocity damping (fraction d per internal step h, N steps per control cycle dt) the null-
space motion is a first-order lag of time constant (in real time)
``T ≈ m_r (d / ((1 − d) h)) / k_s · dt / (N h)``, where ``k_s = K |∂q_arm/∂s|²`` is the
spring seen along the rail; a target moving along the rail at v leaves the arm about v·T
away from its posture (measured in tests/test_rail.py).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from app.config import RailConfig, VfdmConfig
from app.sim.ur10e import end_frame, fk_joints, jacobian_at
from app.sim.vfdm import cholesky_solve, joint_space_inertia, virtual_arm

__all__ = [
    "N_CHAIN",
    "RailArm",
    "chain_jacobian",
    "chain_tcp_pose",
    "null_vector",
    "posture_acceleration",
    "rail_arm",
    "rail_axis_B",
    "rail_joint_acceleration",
]

N_CHAIN = 7
"""Rail + the UR10e's six joints."""


class RailArm(NamedTuple):
    """The 7-joint virtual model's numbers, as the kernels take them."""

    axis: np.ndarray
    """(3,) the rail's unit axis in B0."""
    pR: np.ndarray
    """(6, 3, 3) the arm's joint placement rotations."""
    pp: np.ndarray
    """(6, 3) the arm's joint placement translations."""
    mass: np.ndarray
    """(6,) the arm's link masses [kg] (Table 1)."""
    lever: np.ndarray
    """(6, 3) link centres of mass in their joint frames [m]."""
    Icom: np.ndarray
    """(6, 3, 3) link inertias about their centres of mass [kg m²]."""
    tR: np.ndarray
    """(3, 3) rotation of the TCP in the frame of joint 6."""
    tp: np.ndarray
    """(3,) position of the TCP in the frame of joint 6."""
    armature: float
    """Rotor inertia of every arm joint [kg m²]."""
    rail_mass: float
    """The carriage's virtual mass [kg]."""


def rail_axis_B(rail: RailConfig, T_W_B0: np.ndarray) -> np.ndarray:
    """The rail's unit axis in the base frame B0: ``R_W_B0ᵀ axis_W``."""
    return np.ascontiguousarray(np.asarray(T_W_B0, dtype=float)[:3, :3].T
                                @ np.asarray(rail.axis_W, dtype=float))


def rail_arm(cfg: VfdmConfig, T_F_C: np.ndarray, axis_B: np.ndarray,
             rail_mass_kg: float) -> RailArm:
    """Table 1's virtual arm (app.sim.vfdm.virtual_arm) on a carriage of ``rail_mass_kg``
    moving along ``axis_B``."""
    arm = virtual_arm(cfg, T_F_C)
    axis = np.asarray(axis_B, dtype=float)
    return RailArm(np.ascontiguousarray(axis / np.linalg.norm(axis)), *arm,
                   float(rail_mass_kg))


# --- kernels ------------------------------------------------------------------------------


@njit(cache=True, fastmath=False)
def chain_frames(q, axis, pR, pp, tR, tp, R, p, T_B_C):
    """The arm's joint frames R (6, 3, 3), p (6, 3) and the TCP pose T_B_C (4, 4) in B0
    for the chain's q (7,): the fixed-base frames moved by ``s · axis``."""
    fk_joints(q[1:], pR, pp, R, p)
    end_frame(R, p, tR, tp, T_B_C)
    s = q[0]
    for i in range(6):
        for a in range(3):
            p[i, a] += s * axis[a]
    for a in range(3):
        T_B_C[a, 3] += s * axis[a]
    T_B_C[3, 0] = T_B_C[3, 1] = T_B_C[3, 2] = 0.0
    T_B_C[3, 3] = 1.0


@njit(cache=True, fastmath=False)
def chain_jacobian_at(R, p, c, axis, J):
    """J (6, 7) := the chain's Jacobian at point c: ``[a; 0]`` then the arm's columns."""
    for a in range(3):
        J[a, 0] = axis[a]
        J[3 + a, 0] = 0.0
    jacobian_at(R, p, c, J[:, 1:])


@njit(cache=True, fastmath=False)
def chain_inertia(R, p, axis, mass, lever, Icom, armature, rail_mass, H, work):
    """H (7, 7) := the chain's joint-space inertia (module doc): the arm's composite-rigid-
    body H (with the armature) bordered by the rail's row. work: a (14, 3) scratch array."""
    joint_space_inertia(R, p, mass, lever, Icom, H[1:, 1:], work)
    for i in range(1, 7):
        H[i, i] += armature
    m_acc = 0.0
    sx = sy = sz = 0.0  # first moment of links j..6 about B0's origin
    for j in range(5, -1, -1):
        cx, cy, cz = p[j, 0], p[j, 1], p[j, 2]
        for b in range(3):
            cx += R[j, 0, b] * lever[j, b]
            cy += R[j, 1, b] * lever[j, b]
            cz += R[j, 2, b] * lever[j, b]
        m_acc += mass[j]
        sx += mass[j] * cx
        sy += mass[j] * cy
        sz += mass[j] * cz
        # z_j × (first moment − m p_j): the links' linear momentum under joint j's motion
        dx, dy, dz = sx - m_acc * p[j, 0], sy - m_acc * p[j, 1], sz - m_acc * p[j, 2]
        zx, zy, zz = R[j, 0, 2], R[j, 1, 2], R[j, 2, 2]
        lx, ly, lz = zy * dz - zz * dy, zz * dx - zx * dz, zx * dy - zy * dx
        h0 = axis[0] * lx + axis[1] * ly + axis[2] * lz
        H[0, j + 1] = h0
        H[j + 1, 0] = h0
    H[0, 0] = rail_mass + m_acc


@njit(cache=True, fastmath=False)
def _det6(A):
    """det of a 6x6 matrix (A is overwritten): Gaussian elimination, partial pivoting."""
    d = 1.0
    for k in range(6):
        piv, big = k, abs(A[k, k])
        for i in range(k + 1, 6):
            if abs(A[i, k]) > big:
                piv, big = i, abs(A[i, k])
        if big == 0.0:
            return 0.0
        if piv != k:
            for m in range(6):
                A[k, m], A[piv, m] = A[piv, m], A[k, m]
            d = -d
        d *= A[k, k]
        for i in range(k + 1, 6):
            f = A[i, k] / A[k, k]
            for m in range(k + 1, 6):
                A[i, m] -= f * A[k, m]
    return d


@njit(cache=True, fastmath=False)
def null_vector_of(J, n, M):
    """n (7,) := the generalised cross product of J's six rows, ``n_i = (−1)^i det(J
    without column i)``: J n = 0, |n| = the product of J's singular values (0 where J
    loses rank). M: a (6, 6) scratch array."""
    for i in range(7):
        for a in range(6):
            c = 0
            for k in range(7):
                if k != i:
                    M[a, c] = J[a, k]
                    c += 1
        d = _det6(M)
        n[i] = -d if i % 2 else d


@njit(cache=True, fastmath=False)
def add_posture_acceleration(q, H, J, posture, stiffness, qdd, n, M):
    """qdd += ``n (nᵀ τ_p) / (nᵀ H n)`` with ``τ_p = −K (q_arm − posture)`` (module doc):
    the posture spring's acceleration in the null space of J. Nothing where J has no
    one-dimensional null space (|n| tiny). n (7,), M (6, 6): scratch arrays."""
    if stiffness == 0.0:
        return
    null_vector_of(J, n, M)
    nn = 0.0
    for i in range(7):
        nn += n[i] * n[i]
    if nn < 1e-18:
        return
    num = 0.0
    for i in range(1, 7):
        num -= n[i] * stiffness * (q[i] - posture[i - 1])
    den = 0.0
    for i in range(7):
        hi = 0.0
        for k in range(7):
            hi += H[i, k] * n[k]
        den += n[i] * hi
    g = num / den
    for i in range(7):
        qdd[i] += g * n[i]


@njit(cache=True, fastmath=False)
def _chain_pose(q, axis, pR, pp, tR, tp, T):
    R = np.empty((6, 3, 3))
    p = np.empty((6, 3))
    chain_frames(q, axis, pR, pp, tR, tp, R, p, T)


@njit(cache=True, fastmath=False)
def _chain_jacobian(q, axis, pR, pp, tR, tp, J):
    R = np.empty((6, 3, 3))
    p = np.empty((6, 3))
    T = np.empty((4, 4))
    chain_frames(q, axis, pR, pp, tR, tp, R, p, T)
    chain_jacobian_at(R, p, T[:3, 3], axis, J)


@njit(cache=True, fastmath=False)
def _chain_acceleration(q, tau, axis, pR, pp, mass, lever, Icom, tR, tp, armature,
                        rail_mass, posture, stiffness, qdd):
    R = np.empty((6, 3, 3))
    p = np.empty((6, 3))
    T = np.empty((4, 4))
    H = np.zeros((7, 7))
    J = np.empty((6, 7))
    chain_frames(q, axis, pR, pp, tR, tp, R, p, T)
    chain_inertia(R, p, axis, mass, lever, Icom, armature, rail_mass, H, np.empty((14, 3)))
    cholesky_solve(H, tau, qdd, np.zeros((7, 7)), np.empty(7))
    chain_jacobian_at(R, p, T[:3, 3], axis, J)
    add_posture_acceleration(q, H, J, posture, stiffness, qdd, np.empty(7), np.empty((6, 6)))


# --- plain functions for callers outside the loop (tests, benchmarks) -------------------------


def chain_tcp_pose(arm: RailArm, q: np.ndarray) -> np.ndarray:
    """TCP pose ``T_B0_C`` (4x4) of the chain at q = [s, q1 … q6]."""
    T = np.empty((4, 4))
    _chain_pose(np.asarray(q, dtype=float), arm.axis, arm.pR, arm.pp, arm.tR, arm.tp, T)
    return T


def chain_jacobian(arm: RailArm, q: np.ndarray) -> np.ndarray:
    """6x7 TCP Jacobian of the chain, rows ``[v_C; ω]`` in B0 axes."""
    J = np.empty((6, N_CHAIN))
    _chain_jacobian(np.asarray(q, dtype=float), arm.axis, arm.pR, arm.pp, arm.tR, arm.tp, J)
    return J


def null_vector(J: np.ndarray) -> np.ndarray:
    """The generalised cross product of the rows of a 6x7 J (:func:`null_vector_of`)."""
    n = np.empty(N_CHAIN)
    null_vector_of(np.ascontiguousarray(J, dtype=float), n, np.empty((6, 6)))
    return n


def rail_joint_acceleration(arm: RailArm, q: np.ndarray, tau: np.ndarray,
                            posture: np.ndarray | None = None,
                            stiffness: float = 0.0) -> np.ndarray:
    """Eq. 10 on the chain, ``q̈ = H(q)⁻¹ τ``, plus the null-space posture term when a
    stiffness is given."""
    qdd = np.empty(N_CHAIN)
    post = np.zeros(6) if posture is None else np.asarray(posture, dtype=float)
    _chain_acceleration(np.asarray(q, dtype=float), np.asarray(tau, dtype=float),
                        arm.axis, arm.pR, arm.pp, arm.mass, arm.lever, arm.Icom, arm.tR,
                        arm.tp, arm.armature, arm.rail_mass, post, float(stiffness), qdd)
    return qdd


def posture_acceleration(arm: RailArm, q: np.ndarray, posture: np.ndarray,
                         stiffness: float) -> np.ndarray:
    """The posture term's acceleration alone (τ = 0)."""
    return rail_joint_acceleration(arm, q, np.zeros(N_CHAIN), posture, stiffness)

