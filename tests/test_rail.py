"""The UR10e on a rail as one 7-joint chain (app.sim.rail) against a Pinocchio model of the
same chain (tests/oracle.py build_rail_model): FK, Jacobian, H, Eq. 10's H⁻¹ Jᵀ f, and the
null-space posture term against the dynamically consistent projector written out.

Tolerances: 1e-12 where both sides compute the same quantity by different operation orders
(O(1) results); the projector is compared at postures away from the singularities (the
reference inverts J H⁻¹ Jᵀ), relative 1e-8.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

from app.config import RailConfig, VfdmConfig
from app.sim.rail import (
    N_CHAIN,
    chain_jacobian,
    chain_tcp_pose,
    null_vector,
    posture_acceleration,
    rail_arm,
    rail_axis_B,
    rail_joint_acceleration,
)
from app.sim.rotations import make_transform, quat_to_matrix, rotvec_to_matrix
from tests import oracle

ATOL = 1e-12
LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
T_F_C = make_transform(rotvec_to_matrix([0.3, -0.2, 0.5]), [0.02, -0.03, 0.07])
AXES = [np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]),
        np.array([0.48, -0.6, 0.64])]
POSTURE = np.array([0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0])


def chains(axis, rail_mass=1.0, cfg=None):
    """(our RailArm, the Pinocchio model and data, its tcp frame id) of the same chain."""
    cfg = cfg or VfdmConfig()
    arm = rail_arm(cfg, T_F_C, axis, rail_mass)
    model = oracle.build_rail_model(axis, oracle.virtual_inertias(cfg, T_F_C), rail_mass,
                                    T_F_C, cfg.joint_armature_kgm2)
    return arm, model, model.createData(), model.getFrameId("tcp")


def draws(n=300, seed=0):
    rng = np.random.default_rng(seed)
    q = rng.uniform(-2 * math.pi, 2 * math.pi, (n, N_CHAIN))
    q[:, 0] = rng.uniform(-3.0, 3.0, n)
    return [np.concatenate([[0.0], POSTURE]), np.zeros(N_CHAIN), *q]


@pytest.mark.parametrize("axis", AXES)
def test_fk_and_jacobian_equal_pinocchio(axis):
    arm, model, data, tcp = chains(axis)
    for q in draws():
        pin.computeJointJacobians(model, data, q)
        oMc = pin.updateFramePlacement(model, data, tcp)
        np.testing.assert_allclose(chain_tcp_pose(arm, q), oMc.homogeneous, rtol=0, atol=ATOL)
        J_ref = pin.getFrameJacobian(model, data, tcp, LWA)
        np.testing.assert_allclose(chain_jacobian(arm, q), J_ref, rtol=0, atol=ATOL)


@pytest.mark.parametrize("axis", AXES)
def test_eq10_acceleration_equals_aba(axis):
    """q̈ = H⁻¹ Jᵀ f of the 7-joint virtual model against pin.aba (zero velocity, no
    gravity; the armature on the arm's joints, Table 1's inertia, a 1 kg carriage)."""
    arm, model, data, tcp = chains(axis)
    rng = np.random.default_rng(1)
    for q in draws(200, seed=2):
        f = rng.normal(size=6)
        J = pin.computeFrameJacobian(model, data, q, tcp, LWA)
        tau = J.T @ f
        ref = pin.aba(model, data, q, np.zeros(N_CHAIN), tau)
        got = rail_joint_acceleration(arm, q, tau)
        np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-9 * np.abs(ref).max())


def test_rail_config_axis_is_taken_into_the_base_frame():
    """A base upside down (turned π about x) sees the lab's +y axis as its −y."""
    T_W_B0 = make_transform(quat_to_matrix([0.0, 1.0, 0.0, 0.0]), [0.0, 0.0, 2.0])
    a = rail_axis_B(RailConfig(axis_W=(0.0, 1.0, 0.0)), T_W_B0)
    np.testing.assert_allclose(a, [0.0, -1.0, 0.0], atol=1e-15)


@pytest.mark.parametrize("axis", AXES)
def test_null_vector_spans_the_jacobian_s_null_space(axis):
    arm, *_ = chains(axis)
    for q in draws(200, seed=3):
        J = chain_jacobian(arm, q)
        n = null_vector(J)
        sv = np.linalg.svd(J, compute_uv=False)
        # |n| is the product of J's singular values; J n = 0
        assert np.linalg.norm(n) == pytest.approx(np.prod(sv), rel=1e-9, abs=1e-14)
        np.testing.assert_allclose(J @ n, 0.0, atol=1e-12)


@pytest.mark.parametrize("axis", AXES)
def test_posture_term_is_the_dynamically_consistent_null_space_projection(axis):
    """q̈_p = H⁻¹ Nᵀ τ_p with N = I − J̄ J, J̄ = H⁻¹ Jᵀ Λ, Λ = (J H⁻¹ Jᵀ)⁻¹ (Pinocchio's H
    and J), and it moves the TCP not at all (J q̈_p = 0)."""
    arm, model, data, tcp = chains(axis)
    k = 0.7
    checked = 0
    for q in draws(200, seed=4):
        J = pin.computeFrameJacobian(model, data, q, tcp, LWA)
        if np.linalg.svd(J, compute_uv=False)[-1] < 0.05:
            continue  # the reference needs Λ: keep away from singularities
        H = pin.crba(model, data, q)
        H = np.triu(H) + np.triu(H, 1).T
        Hi = np.linalg.inv(H)
        Lam = np.linalg.inv(J @ Hi @ J.T)
        N = np.eye(N_CHAIN) - Hi @ J.T @ Lam @ J
        tau_p = np.concatenate([[0.0], -k * (q[1:] - POSTURE)])
        ref = Hi @ N.T @ tau_p
        got = posture_acceleration(arm, q, POSTURE, k)
        np.testing.assert_allclose(got, ref, rtol=1e-8, atol=1e-8 * np.abs(ref).max())
        np.testing.assert_allclose(J @ got, 0.0, atol=1e-10 * np.abs(got).max())
        checked += 1
    assert checked > 100


def test_a_cartesian_force_leaves_the_carriage_almost_at_rest():
    """The carriage's mass does not enter the operational space (app/sim/rail.py): a force
    at the TCP accelerates it as Table 1's 1 kg whatever the carriage's virtual mass, and
    the carriage takes a share that falls about as 1 / m_r (what the arm's armature and 10 g
    links make the arm's own motion cost): under 2 % of the TCP's at 1 kg."""
    cfg = VfdmConfig()
    q = np.concatenate([[0.3], [0.2, -1.2, 1.6, -1.9, -1.4, 0.3]])
    shares = []
    for m_r in (0.1, 1.0, 10.0):
        arm = rail_arm(cfg, T_F_C, AXES[0], m_r)
        J = chain_jacobian(arm, q)
        for f in np.eye(6)[:3]:
            qdd = rail_joint_acceleration(arm, q, J.T @ f)
            tcp_acc = J @ qdd
            assert tcp_acc @ f == pytest.approx(1.0, rel=0.05)
            if f[0] == 1.0:
                shares.append(abs(qdd[0]) / np.linalg.norm(tcp_acc[:3]))
    assert shares[1] < 0.02
    assert 50.0 < shares[0] / shares[2] <= 100.0  # ~1 / m_r over the 100x
