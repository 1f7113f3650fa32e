"""Physical interaction on the bodies (app/sim/interaction.py): contact + hand, body states."""

from __future__ import annotations

import numpy as np
import pytest

from app.config import EmulatorConfig, LabConfig, SatelliteConfig, merge_overrides, parse_config
from app.scenarios import load_scenario
from app.sim.contact import BoxContactModel
from app.sim.hand import OperatorHand, Push
from app.sim.interaction import (
    Bodies,
    PhysicalInteraction,
    actual_bodies,
    body_torque_B,
    ods_bodies,
)
from app.sim.orbital import OrbitalSimulator
from app.sim.rig import build_rig
from app.sim.rotations import (
    make_transform,
    matrix_to_rotvec,
    quat_to_matrix,
    rotvec_to_matrix,
    rotvec_to_quat,
)
from app.sim.ur10e import tcp_jacobian_B, tcp_pose_B

R_ATTITUDE = rotvec_to_quat(np.array([0.2, -0.4, 0.9]))
T_W_R = make_transform(quat_to_matrix(R_ATTITUDE), [-0.3, 0.1, 1.0])


def _config(**sat_b) -> EmulatorConfig:
    return EmulatorConfig(
        satellites=[
            SatelliteConfig(name="a", position_m=(0.01, -0.02, 0.03),
                            velocity_mps=(0.02, -0.01, 0.005),
                            attitude_wxyz=tuple(rotvec_to_quat(np.array([0.1, 0.2, -0.3]))),
                            omega_radps=(0.05, -0.02, 0.1), material="rigid"),
            SatelliteConfig(name="b", material="sponge", **sat_b),
        ],
        lab=LabConfig(r_origin_m=tuple(T_W_R[:3, 3]), r_attitude_wxyz=tuple(R_ATTITUDE)),
    )


def _interaction(cfg: EmulatorConfig) -> PhysicalInteraction:
    hand = OperatorHand(cfg, T_W_R[:3, :3])
    return PhysicalInteraction(BoxContactModel.from_satellites(cfg.satellites, cfg.materials),
                               hand)


def _overlapping_bodies(v_b=(-0.05, 0.01, 0.0)) -> Bodies:
    """Two 0.2 x 0.2 x 0.1 m boxes pressed together about 1 cm, turned, b approaching a."""
    T_a = make_transform(rotvec_to_matrix([0.05, -0.03, 0.1]), [0.2, 0.1, 1.0])
    T_b = make_transform(rotvec_to_matrix([-0.02, 0.04, -0.15]), [0.39, 0.13, 1.01])
    return Bodies(np.array([T_a, T_b]), np.array([[0.01, 0.0, 0.0], v_b]),
                  np.array([[0.0, 0.0, 0.2], [0.1, -0.1, 0.0]]))


def test_contact_forces_are_equal_and_opposite_with_zero_total_moment():
    inter = _interaction(_config())
    bodies = _overlapping_bodies()
    w = inter.wrenches_W(bodies, 0.0)
    assert inter.contact_active
    assert np.linalg.norm(w[1, :3]) > 1.0  # a real push: k ~ 490 N/m, ~1 cm
    np.testing.assert_allclose(w[0, :3] + w[1, :3], 0.0, atol=1e-12)  # Newton's third law
    # total moment about any common point (here W's origin and an arbitrary one) is zero
    for o in (np.zeros(3), np.array([1.0, -2.0, 0.5])):
        moment = sum(w[i, 3:] + np.cross(bodies.T_W_C[i, :3, 3] - o, w[i, :3]) for i in (0, 1))
        np.testing.assert_allclose(moment, 0.0, atol=1e-12)
    # the boxes are turned: each moment about its own COM is not zero
    assert np.linalg.norm(w[0, 3:]) > 1e-3 and np.linalg.norm(w[1, 3:]) > 1e-3
    # b (at larger x) is pushed away from a
    assert w[1, 0] > 0 > w[0, 0]


def test_contact_active_follows_each_call():
    inter = _interaction(_config())
    inter.wrenches_W(_overlapping_bodies(), 0.0)
    assert inter.contact_active
    apart = _overlapping_bodies()
    apart.T_W_C[1, 0, 3] += 0.3
    w = inter.wrenches_W(apart, 0.0)
    assert not inter.contact_active
    np.testing.assert_array_equal(w, 0.0)
    # overlapping but separating faster than 1/c: no pull, so no force and not active
    separating = _overlapping_bodies(v_b=(5.0, 0.0, 0.0))
    w = inter.wrenches_W(separating, 0.0)
    assert not inter.contact_active
    np.testing.assert_array_equal(w, 0.0)


def test_the_hand_adds_to_the_contact():
    cfg = _config()
    bodies = _overlapping_bodies()
    contact_only = _interaction(cfg).wrenches_W(bodies, 0.0)
    inter = _interaction(cfg)
    inter.hand.post(Push(satellite=0, force_R_N=(0.0, 0.0, 7.0), duration_s=0.1))
    inter.hand.update(0.0)
    w = inter.wrenches_W(bodies, 0.0)
    assert inter.contact_active
    expected = contact_only.copy()
    expected[0, :3] += T_W_R[:3, :3] @ [0.0, 0.0, 7.0]
    np.testing.assert_allclose(w, expected, atol=1e-12)
    # the net force on the pair is now the hand's alone
    np.testing.assert_allclose(w[:, :3].sum(axis=0), T_W_R[:3, :3] @ [0.0, 0.0, 7.0],
                               atol=1e-12)
    # the hand alone, bodies apart: contact not active, the push still acts
    apart = _overlapping_bodies()
    apart.T_W_C[1, 0, 3] += 0.3
    w = inter.wrenches_W(apart, 0.0)
    assert not inter.contact_active
    np.testing.assert_allclose(w[0, :3], T_W_R[:3, :3] @ [0.0, 0.0, 7.0], atol=1e-12)


def test_which_bodies_touch_and_which_the_hand_pushes_follow_each_call():
    """touching and hand_acting, with the hand idle (its wrench skipped: the contact's
    own, bit for bit) and pushing one body."""
    cfg = _config()
    inter = _interaction(cfg)
    bodies = _overlapping_bodies()
    w = inter.wrenches_W(bodies, 0.0)
    assert inter.touching == frozenset({frozenset({0, 1})})
    np.testing.assert_array_equal(inter.hand_acting, [False, False])
    contact = inter.contact.compute(bodies.T_W_C, bodies.v_W, bodies.w_W).wrench_W
    assert w.tobytes() == contact.tobytes()
    inter.hand.post(Push(satellite=1, force_R_N=(0.0, 3.0, 0.0), duration_s=0.1))
    inter.hand.update(0.0)
    apart = _overlapping_bodies()
    apart.T_W_C[1, 0, 3] += 0.3
    w = inter.wrenches_W(apart, 0.0)
    assert inter.touching == frozenset() and not inter.contact_active
    np.testing.assert_array_equal(inter.hand_acting, [False, True])
    np.testing.assert_allclose(w[1, :3], T_W_R[:3, :3] @ [0.0, 3.0, 0.0], atol=1e-12)
    inter.hand.update(0.2)  # the push is over: nothing acts
    w = inter.wrenches_W(apart, 0.2)
    np.testing.assert_array_equal(inter.hand_acting, [False, False])
    np.testing.assert_array_equal(w, 0.0)


def test_the_free_flight_shortcut_gives_what_compute_gives():
    """Body b sliding along x from overlapping a, through the bounding spheres' reach, to
    far apart and back, the hand pushing for part of the way: each call's wrenches (bit
    for bit), contact_active, touching and hand_acting are those of an interaction that
    calls compute every time (its BoxContactModel.apart never true)."""
    cfg = _config()
    fast, general = _interaction(cfg), _interaction(cfg)
    general.contact.apart = lambda T_W_C, within_m=0.0: False
    reach = float(np.sqrt(2 * 0.2 ** 2 + 0.1 ** 2))  # two 0.2 x 0.2 x 0.1 boxes' radii, summed
    shortcuts = touched = 0
    for k, x in enumerate(np.concatenate([np.linspace(0.18, reach + 0.01, 30),
                                          np.linspace(reach + 0.01, 0.18, 30), [reach]])):
        t_s = 0.01 * k
        if k == 10:
            for inter in (fast, general):
                inter.hand.post(Push(satellite=1, force_R_N=(0.0, 3.0, 0.0), duration_s=0.3))
        for inter in (fast, general):
            inter.hand.update(t_s)
        bodies = _overlapping_bodies()
        bodies.T_W_C[1, 0, 3] = bodies.T_W_C[0, 0, 3] + x
        shortcuts += fast.contact.apart(bodies.T_W_C)
        expected = general.wrenches_W(bodies, t_s)
        assert fast.wrenches_W(bodies, t_s).tobytes() == expected.tobytes(), k
        assert fast.contact_active == general.contact_active, k
        assert fast.touching == general.touching, k
        assert fast.hand_acting.tolist() == general.hand_acting.tolist(), k
        touched += fast.contact_active
    assert 5 < shortcuts < 55 and touched > 5


# --- where the bodies are --------------------------------------------------------------------


def test_ods_bodies_are_the_ods_states_seen_from_the_lab():
    cfg = _config(position_m=(0.3, 0.0, -0.1), velocity_mps=(-0.01, 0.0, 0.02),
                  attitude_wxyz=tuple(rotvec_to_quat(np.array([0.0, 0.8, 0.3]))),
                  omega_radps=(0.0, 0.3, -0.2))
    ods = OrbitalSimulator.from_config(cfg)
    bodies = ods_bodies(T_W_R, ods)
    R_W_R = T_W_R[:3, :3]
    for i, sat in enumerate(cfg.satellites):
        T_R_S = make_transform(quat_to_matrix(sat.attitude_wxyz), sat.position_m)
        np.testing.assert_allclose(bodies.T_W_C[i], T_W_R @ T_R_S, atol=1e-12)
        np.testing.assert_allclose(bodies.v_W[i], R_W_R @ sat.velocity_mps, atol=1e-12)
        # the configured angular velocity relative to R, body axes, seen in W
        R_W_C = R_W_R @ quat_to_matrix(sat.attitude_wxyz)
        np.testing.assert_allclose(bodies.w_W[i], R_W_C @ sat.omega_radps, atol=1e-12)


def test_ods_bodies_velocities_are_the_rates_of_their_poses():
    """Finite differences of the lab poses over a short ODS step give v_W and w_W."""
    cfg = _config(attitude_wxyz=tuple(rotvec_to_quat(np.array([0.0, 0.8, 0.3]))),
                  omega_radps=(0.0, 0.3, -0.2))
    ods = OrbitalSimulator.from_config(cfg)
    h = 1e-4
    before = ods_bodies(T_W_R, ods)
    zeros = np.zeros((2, 3))
    ods.step(zeros, zeros, h)
    after = ods_bodies(T_W_R, ods)
    for i in range(2):
        v_fd = (after.T_W_C[i, :3, 3] - before.T_W_C[i, :3, 3]) / h
        np.testing.assert_allclose(v_fd, 0.5 * (before.v_W[i] + after.v_W[i]), atol=1e-9)
        R0, R1 = before.T_W_C[i, :3, :3], after.T_W_C[i, :3, :3]
        w_fd = matrix_to_rotvec(R1 @ R0.T) / h  # dR/dt = [w_W]x R
        np.testing.assert_allclose(w_fd, 0.5 * (before.w_W[i] + after.w_W[i]), atol=1e-6)
    assert np.linalg.norm(before.w_W[1]) > 0.3


@pytest.fixture(scope="module")
def one_arm_two_satellites():
    """The collision scenario with the sponge left without its arm (and spinning)."""
    cfg = merge_overrides(load_scenario("collision"), {
        "lab": {"r_attitude_wxyz": list(R_ATTITUDE)},
        "satellites": {"1": {"omega_radps": [0.1, -0.2, 0.3]}},
    })
    data = cfg.model_dump()
    data["robots"] = data["robots"][:1]
    return parse_config(data)


def test_actual_bodies_carried_by_fk_uncarried_at_ods_pose_not_turning(one_arm_two_satellites):
    cfg = one_arm_two_satellites
    T_W_R_cfg = make_transform(quat_to_matrix(cfg.lab.r_attitude_wxyz), cfg.lab.r_origin_m)
    rig = build_rig(0, cfg.robots[0], cfg, T_W_R_cfg, np.random.default_rng(0))
    assert rig.satellite == 0
    q_home = rig.servo.state.q_rad.copy()
    rate = np.array([0.4, -0.2, 0.3, 0.2, -0.4, 0.5])  # rad/s, within the speed limits
    for k in range(1, 51):  # set the arm moving along a joint ramp
        rig.servo.step(q_home + rate * k * rig.servo.dt_s)
    q, qd = rig.servo.state.q_rad, rig.servo.state.qd_radps
    assert not rig.servo.stopped
    assert np.abs(qd).min() > 1e-3
    ods = OrbitalSimulator.from_config(cfg)
    bodies = actual_bodies(T_W_R_cfg, ods, [rig])
    # carried: forward kinematics of the arm, T_W_B · T_B_F(q) · T_F_C, and J(q) q̇
    T_W_B, T_F_C = rig.T_W_B, rig.T_F_C
    np.testing.assert_allclose(bodies.T_W_C[0], T_W_B @ tcp_pose_B(q, T_F_C), atol=1e-12)
    twist_B = tcp_jacobian_B(q, T_F_C) @ qd
    np.testing.assert_allclose(bodies.v_W[0], T_W_B[:3, :3] @ twist_B[:3], atol=1e-12)
    np.testing.assert_allclose(bodies.w_W[0], T_W_B[:3, :3] @ twist_B[3:], atol=1e-12)
    ods_pose = T_W_R_cfg @ make_transform(quat_to_matrix(ods.y[0, 6:10]), ods.y[0, :3])
    assert np.linalg.norm(bodies.T_W_C[0, :3, 3] - ods_pose[:3, 3]) > 0.01  # not the ODS's
    # uncarried: where the ODS has it, with its velocity, and not turning
    sat = cfg.satellites[1]
    np.testing.assert_allclose(
        bodies.T_W_C[1],
        T_W_R_cfg @ make_transform(quat_to_matrix(sat.attitude_wxyz), sat.position_m),
        atol=1e-12)
    np.testing.assert_allclose(bodies.v_W[1], T_W_R_cfg[:3, :3] @ sat.velocity_mps, atol=1e-12)
    np.testing.assert_array_equal(bodies.w_W[1], 0.0)
    assert np.linalg.norm(ods_bodies(T_W_R_cfg, ods).w_W[1]) > 0.3  # though the ODS's turns


def test_body_torque_B_against_a_hand_computed_rotation():
    # body turned 90 deg about W's z: body x = W y, body y = -W x, body z = W z
    T_W_C = make_transform(np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]),
                           [0.3, -0.2, 1.0])
    wrench_W = np.array([9.0, 8.0, 7.0, 1.0, 2.0, 3.0])  # the force plays no part
    np.testing.assert_allclose(body_torque_B(wrench_W, T_W_C), [2.0, -1.0, 3.0], atol=1e-15)
    # a cyclic permutation of the axes: body x = W y, body y = W z, body z = W x
    T_W_C2 = make_transform(np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]),
                            [0.0, 0.0, 0.0])
    np.testing.assert_allclose(body_torque_B(wrench_W, T_W_C2), [2.0, 3.0, 1.0], atol=1e-15)


def test_actual_bodies_of_one_carried_satellite_are_its_arms_forward_kinematics():
    """One arm, one satellite (free-floating): the bodies are the arm's forward kinematics
    as (1, ...) arrays, bit for bit what the general path copies, and a later command (new
    kinematics) leaves them as they were."""
    cfg = load_scenario("free-floating")
    T_W_R_cfg = make_transform(quat_to_matrix(cfg.lab.r_attitude_wxyz), cfg.lab.r_origin_m)
    rig = build_rig(0, cfg.robots[0], cfg, T_W_R_cfg, np.random.default_rng(0))
    ods = OrbitalSimulator.from_config(cfg)
    bodies = actual_bodies(T_W_R_cfg, ods, [rig])
    _, T_W_C, v_W, w_W = rig.mockup_state_W()
    assert bodies.T_W_C.shape == (1, 4, 4) and bodies.v_W.shape == bodies.w_W.shape == (1, 3)
    for got, fk in ((bodies.T_W_C[0], T_W_C), (bodies.v_W[0], v_W), (bodies.w_W[0], w_W)):
        assert got.tobytes() == fk.tobytes()
    kept = [a.copy() for a in bodies]
    y = ods.y.copy()
    y[0, 0] += 0.05  # the satellite 5 cm along x: the arm moves
    for _ in range(5):
        rig.command_towards(y)
    assert rig.mockup_state_W()[1].tobytes() != kept[0][0].tobytes()
    for a, b in zip(bodies, kept, strict=True):
        assert a.tobytes() == b.tobytes()
