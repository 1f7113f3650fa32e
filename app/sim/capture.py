"""Capture: two satellites that dock become one rigid body in the ODS.

A capture envelope (relative position of the target's COM in the chaser's body frame
against the mated offset, relative speed, relative attitude, relative rate) is checked
each cycle; inside it, the pair is joined (:func:`join`) into a compound whose state
conserves the pair's linear and angular momentum (a perfectly inelastic latch: kinetic
energy can only drop). From then on the ODS moves the compound as one body (combined mass,
combined inertia about its COM on its principal axes, the members' wrenches summed about
its COM: :func:`compound_wrench`) and each member's state is spread from it
(:func:`spread`), so both arms follow the one body.

Units: the ODS's (app/sim/scaling.py). Its rotational equation is I ω̇ = … + s_τ τ and its
translational one a = s_F F / m, so the lab-equivalent body of a satellite has mass
m / s_F and inertia I / s_τ; the compound is built from those (parallel-axis term and
momenta), which under similarity is the orbit's own rigid body and under the paper's
knobs keeps its knobs.

State rows as in app/sim/orbital.py: position (R), velocity relative to R (R), attitude
q_R_B (wxyz), inertial angular velocity (body axes).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from app.sim.rotations import matrix_to_quat, quat_to_matrix, quat_to_rotvec

__all__ = ["Compound", "compound_wrench", "join", "relative_state", "spread"]

Z = np.array([0.0, 0.0, 1.0])  # the orbit normal: R turns about it at Omega


def relative_state(y: np.ndarray, chaser: int, target: int, orbit_rate_radps: float):
    """(target COM in the chaser's body frame, relative velocity in the chaser's frame as
    the chaser sees it, relative rotation angle, relative angular rate): what a capture
    envelope compares."""
    R1, R2 = quat_to_matrix(y[chaser, 6:10]), quat_to_matrix(y[target, 6:10])
    d_R = y[target, :3] - y[chaser, :3]
    w1_R = R1 @ y[chaser, 10:13]  # inertial rates, in R
    w2_R = R2 @ y[target, 10:13]
    # the target's velocity seen from the chaser's rotating body frame
    v_rel_R = y[target, 3:6] - y[chaser, 3:6] - np.cross(w1_R - orbit_rate_radps * Z, d_R)
    angle = float(np.linalg.norm(quat_to_rotvec(matrix_to_quat(R1.T @ R2))))
    return R1.T @ d_R, R1.T @ v_rel_R, angle, float(np.linalg.norm(w2_R - w1_R))


@dataclass(frozen=True)
class Compound:
    """Two joined satellites: the members, the compound's lab-equivalent mass and
    principal inertia (in the ODS's units: mass × s_F, inertia × s_τ, i.e. the virtual
    body's), and each member's fixed pose in the compound's body frame."""

    members: tuple[int, int]
    mass_kg: float
    inertia_kgm2: np.ndarray  # (3,) principal moments
    r_Bc_m: np.ndarray  # (2, 3) member COMs from the compound COM, compound axes (lab m)
    R_Bc_Bi: np.ndarray  # (2, 3, 3) member attitudes in the compound's axes


def join(y: np.ndarray, members: tuple[int, int], mass_kg: np.ndarray,
         inertia_kgm2: np.ndarray, force_scale: float, torque_scale: float,
         orbit_rate_radps: float) -> tuple[Compound, np.ndarray]:
    """The compound of ``members`` and its state row (13,), conserving the pair's linear
    momentum and its angular momentum about their common COM (inertial velocities)."""
    idx = list(members)
    m_eq = mass_kg[idx] / force_scale  # lab-equivalent masses and inertias
    M = float(m_eq.sum())
    p_c = (m_eq[:, None] * y[idx, :3]).sum(axis=0) / M
    v_c = (m_eq[:, None] * y[idx, 3:6]).sum(axis=0) / M
    R_i = np.array([quat_to_matrix(y[i, 6:10]) for i in idx])
    r_R = y[idx, :3] - p_c
    u_R = y[idx, 3:6] - v_c + orbit_rate_radps * np.cross(Z, r_R)  # inertial, about the COM
    I_R = np.zeros((3, 3))
    H_R = np.zeros(3)
    for k, i in enumerate(idx):
        I_k = R_i[k] @ np.diag(inertia_kgm2[i] / torque_scale) @ R_i[k].T
        r = r_R[k]
        I_R += I_k + m_eq[k] * (r @ r * np.eye(3) - np.outer(r, r))
        H_R += I_k @ (R_i[k] @ y[i, 10:13]) + m_eq[k] * np.cross(r, u_R[k])
    moments, V = np.linalg.eigh(I_R)  # principal axes, in R
    if np.linalg.det(V) < 0.0:
        V[:, 2] *= -1.0
    R_R_Bc = V
    w_R = np.linalg.solve(I_R, H_R)
    row = np.empty(13)
    row[:3], row[3:6] = p_c, v_c
    row[6:10] = _positive(matrix_to_quat(R_R_Bc))
    row[10:13] = R_R_Bc.T @ w_R
    compound = Compound(members=tuple(members), mass_kg=M * force_scale,
                        inertia_kgm2=moments * torque_scale,
                        r_Bc_m=r_R @ R_R_Bc, R_Bc_Bi=np.einsum("ji,kjl->kil", R_R_Bc, R_i))
    return compound, row


def spread(compound: Compound, row: np.ndarray, orbit_rate_radps: float,
           y: np.ndarray) -> None:
    """Write each member's state into y from the compound's state row (in place)."""
    R_R_Bc = quat_to_matrix(row[6:10])
    w_R = R_R_Bc @ row[10:13]
    for k, i in enumerate(compound.members):
        r_R = R_R_Bc @ compound.r_Bc_m[k]
        R_R_Bi = R_R_Bc @ compound.R_Bc_Bi[k]
        y[i, :3] = row[:3] + r_R
        y[i, 3:6] = row[3:6] + np.cross(w_R - orbit_rate_radps * Z, r_R)
        y[i, 6:10] = _positive(matrix_to_quat(R_R_Bi))
        y[i, 10:13] = R_R_Bi.T @ w_R


def compound_wrench(compound: Compound, row: np.ndarray, force_R: np.ndarray,
                    torque_B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The members' wrenches (force in R, torque in each member's body axes, as the ODS
    receives them) as one wrench on the compound: the forces summed, the torques and the
    forces' moments about its COM summed in its body axes. The ODS's input is the
    lab-equivalent body's wrench (module doc), so the moment is plainly r × F; an internal
    force pair (equal and opposite at one point) cancels."""
    R_R_Bc = quat_to_matrix(row[6:10])
    F = np.zeros(3)
    tau_Bc = np.zeros(3)
    for k, i in enumerate(compound.members):
        F += force_R[i]
        tau_Bc += compound.R_Bc_Bi[k] @ torque_B[i]
        tau_Bc += np.cross(compound.r_Bc_m[k], R_R_Bc.T @ force_R[i])
    return F, tau_Bc


def _positive(q: np.ndarray) -> np.ndarray:
    return -q if q[0] < 0.0 else q
