"""The operator's hand (app/sim/hand.py): scripted pulses, pushes and the gizmo's
unilateral press and twist."""

from __future__ import annotations

import numpy as np
import pytest

from app.config import EmulatorConfig, HandConfig, LabConfig, PulseConfig, SatelliteConfig
from app.sim.hand import HandAnchor, OperatorHand, Push, pulse_wrenches, ray_box_hit
from app.sim.rotations import quat_to_matrix, rotvec_to_matrix, rotvec_to_quat

DT = 0.002
HAND = HandConfig(stiffness_Npm=200.0, max_force_N=60.0)
R_ATTITUDE = rotvec_to_quat(np.array([0.3, -0.5, 0.8]))  # a non-trivial R in W


def _config(pulses=()) -> EmulatorConfig:
    return EmulatorConfig(
        satellites=[SatelliteConfig(name="alpha"), SatelliteConfig(name="beta")],
        pulses=list(pulses),
        lab=LabConfig(r_attitude_wxyz=tuple(R_ATTITUDE)),
        hand=HAND,
    )


PULSES = (
    PulseConfig(satellite="beta", start_s=1.0, end_s=1.5, force_N=(1.0, 2.0, 3.0)),
    PulseConfig(satellite="beta", start_s=1.2, end_s=2.0, force_N=(0.0, 0.0, 4.0),
                torque_Nm=(0.0, 0.0, 1.0)),
    PulseConfig(satellite="alpha", start_s=0.5, end_s=1.0, torque_Nm=(0.5, 0.0, 0.0)),
)
# COM poses of the two mockups: positions and non-trivial attitudes in W
P_W_C = np.array([[0.1, -0.2, 1.0], [0.4, 0.3, 1.2]])
R_W_C = np.array([rotvec_to_matrix([0.0, 0.0, np.pi / 2]), rotvec_to_matrix([0.4, 0.2, -0.7])])


def _hand(pulses=()) -> tuple[OperatorHand, np.ndarray]:
    cfg = _config(pulses)
    R_W_R = quat_to_matrix(cfg.lab.r_attitude_wxyz)
    assert not np.allclose(R_W_R, np.eye(3))
    return OperatorHand(cfg, R_W_R), R_W_R


# --- scripted pulses -------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("t_s", "force", "torque"),
    [
        # (t, force on [alpha, beta] in R, torque on [alpha, beta] in body axes)
        (0.4999, [[0, 0, 0], [0, 0, 0]], [[0, 0, 0], [0, 0, 0]]),
        (0.5, [[0, 0, 0], [0, 0, 0]], [[0.5, 0, 0], [0, 0, 0]]),  # start is inclusive
        (0.9999, [[0, 0, 0], [0, 0, 0]], [[0.5, 0, 0], [0, 0, 0]]),
        (1.0, [[0, 0, 0], [1, 2, 3]], [[0, 0, 0], [0, 0, 0]]),  # alpha's ends, beta's starts
        (1.2, [[0, 0, 0], [1, 2, 7]], [[0, 0, 0], [0, 0, 1]]),  # two pulses on beta add up
        (1.4999, [[0, 0, 0], [1, 2, 7]], [[0, 0, 0], [0, 0, 1]]),
        (1.5, [[0, 0, 0], [0, 0, 4]], [[0, 0, 0], [0, 0, 1]]),  # end is exclusive
        (2.0, [[0, 0, 0], [0, 0, 0]], [[0, 0, 0], [0, 0, 0]]),
    ],
)
def test_pulses_act_on_start_end_interval_summed_per_named_satellite(t_s, force, torque):
    f, tq = pulse_wrenches(_config(PULSES), t_s)
    assert f.shape == tq.shape == (2, 3)
    np.testing.assert_array_equal(f, force)
    np.testing.assert_array_equal(tq, torque)


def test_pulse_force_is_rotated_from_R_into_W_and_torque_from_body_axes():
    hand, R_W_R = _hand(PULSES)
    t = 1.2
    hand.update(t)
    w = hand.wrenches_W(t, P_W_C, R_W_C)
    np.testing.assert_allclose(w[1, :3], R_W_R @ [1.0, 2.0, 7.0], atol=1e-12)
    np.testing.assert_allclose(w[1, 3:], R_W_C[1] @ [0.0, 0.0, 1.0], atol=1e-12)
    np.testing.assert_array_equal(w[0], np.zeros(6))
    # alpha's torque pulse: body x of a body turned 90 deg about z is W's y
    hand.update(0.7)
    w = hand.wrenches_W(0.7, P_W_C, R_W_C)
    np.testing.assert_allclose(w[0], [0, 0, 0, 0.0, 0.5, 0.0], atol=1e-12)
    # the force magnitude is that of the pulse: a rotation, nothing else
    w = hand.wrenches_W(1.0, P_W_C, R_W_C)
    assert np.linalg.norm(w[1, :3]) == pytest.approx(np.sqrt(14.0))


# --- pushes --------------------------------------------------------------------------------


def test_push_acts_from_the_next_update_for_exactly_its_duration():
    hand, R_W_R = _hand()
    push = Push(satellite=1, force_R_N=(3.0, -4.0, 12.0), duration_s=0.01)  # 5 cycles
    t, active, posted_at = 0.0, [], 7
    for k in range(30):
        hand.update(t)
        w = hand.wrenches_W(t, P_W_C, R_W_C)
        if w.any():
            active.append(k)
            np.testing.assert_allclose(w[1, :3], R_W_R @ push.force_R_N, atol=1e-12)
            assert np.linalg.norm(w[1, :3]) == pytest.approx(13.0)
            np.testing.assert_array_equal(w[1, 3:], 0.0)  # through the COM
            np.testing.assert_array_equal(w[0], 0.0)  # the other satellite untouched
        if k == posted_at:  # between cycles, as the web app does
            hand.post(push)
            np.testing.assert_array_equal(hand.wrenches_W(t, P_W_C, R_W_C), 0.0)
        t += DT  # the ODS clock: accumulated, with its rounding
    assert active == list(range(posted_at + 1, posted_at + 6))


def test_overlapping_pushes_add_and_end_independently():
    hand, R_W_R = _hand()
    hand.post(Push(0, (1.0, 0.0, 0.0), 0.004))  # 2 cycles
    hand.post(Push(0, (0.0, 2.0, 0.0), 0.008))  # 4 cycles
    forces_R = []
    t = 0.0
    for _ in range(6):
        hand.update(t)
        forces_R.append(R_W_R.T @ hand.wrenches_W(t, P_W_C, R_W_C)[0, :3])
        t += DT
    expected = [[1, 2, 0], [1, 2, 0], [0, 2, 0], [0, 2, 0], [0, 0, 0], [0, 0, 0]]
    np.testing.assert_allclose(forces_R, expected, atol=1e-12)


@pytest.mark.parametrize(
    ("command", "message"),
    [
        (Push(satellite=2, force_R_N=(1.0, 0.0, 0.0), duration_s=0.1),
         "satellite must be between 1 and 2, got 3"),
        (HandAnchor(satellite=5, anchor_W_m=(0.0, 0.0, 1.0)),
         "satellite must be between 1 and 2, got 6"),
    ],
)
def test_bad_satellite_index_raises_and_changes_nothing(command, message):
    hand, _ = _hand()
    with pytest.raises(ValueError) as err:
        hand.post(command)
    assert str(err.value) == message
    hand.update(0.0)
    assert hand.idle(0.0)
    np.testing.assert_array_equal(hand.wrenches_W(0.0, P_W_C, R_W_C), 0.0)


# --- the gizmo -------------------------------------------------------------------------------


def _grab(hand, sat: int, travel_W, point_B=(0.0, 0.0, 0.0), t: float = 0.0):
    """Grab satellite `sat` at point_B (the gizmo there), then move the hand by travel_W:
    the force's wrench at t + DT."""
    start = P_W_C[sat] + R_W_C[sat] @ np.asarray(point_B)
    hand.post(HandAnchor(satellite=sat, anchor_W_m=tuple(start), point_B_m=tuple(point_B)))
    hand.update(t)
    hand.wrenches_W(t, P_W_C, R_W_C)  # the grab: the fingertip touches the point
    hand.post(HandAnchor(satellite=sat, anchor_W_m=tuple(start + np.asarray(travel_W)),
                         point_B_m=tuple(point_B)))
    hand.update(t + DT)
    return start


def test_the_gizmo_presses_the_grab_point_by_hunt_crossley_along_its_travel():
    """Pressed in by d along the hand's travel n, the body still: F = k d n (Hunt-Crossley
    at zero rate); moving towards the hand at v, F = k d (1 + c v) n."""
    hand, _ = _hand()
    travel = np.array([0.03, -0.04, 0.0])  # 5 cm: k d = 10 N, under the 60 N cap
    _grab(hand, 1, travel)
    w = hand.wrenches_W(DT, P_W_C, R_W_C)
    np.testing.assert_allclose(w[1, :3], HAND.stiffness_Npm * travel, atol=1e-12)
    np.testing.assert_array_equal(w[1, 3:], 0.0)
    np.testing.assert_array_equal(w[0], 0.0)
    n = travel / 0.05
    v = np.zeros((2, 3))
    v[1] = -0.2 * n  # the body runs into the hand at 0.2 m/s
    w = hand.wrenches_W(2 * DT, P_W_C, R_W_C, v, np.zeros((2, 3)))
    expected = HAND.stiffness_Npm * 0.05 * (1.0 + HAND.damping_spm * 0.2)
    np.testing.assert_allclose(w[1, :3], expected * n, atol=1e-12)


def test_the_gizmo_never_pulls_and_lets_go_when_the_satellite_runs_ahead():
    """The hand pressed 5 cm along n (k = 200 N/m: 10 N). As the body gives way along
    n the press relaxes; once the grab point has passed the hand the force is zero (no
    pull back), and a body moving away faster than 1 / c is not pulled either (the
    damping term would turn the force negative: it is clipped at zero). A drag back,
    against n, gives no force: the hand only presses."""
    hand, _ = _hand()
    n = np.array([1.0, 0.0, 0.0])
    start = _grab(hand, 0, 0.05 * n)
    p = P_W_C.copy()
    for ahead, expected in ((0.0, 10.0), (0.02, 6.0), (0.05, 0.0), (0.08, 0.0), (1.0, 0.0)):
        p[0] = P_W_C[0] + ahead * n
        f = hand.wrenches_W(DT, p, R_W_C)[0, :3]
        np.testing.assert_allclose(f, expected * n, atol=1e-12)
    p[0] = P_W_C[0] + 0.02 * n
    v = np.zeros((2, 3))
    v[0] = 1.0 / HAND.damping_spm * 1.5 * n  # separating fast
    np.testing.assert_array_equal(hand.wrenches_W(DT, p, R_W_C, v, np.zeros((2, 3))), 0.0)
    hand.post(HandAnchor(satellite=0, anchor_W_m=tuple(start - 0.1 * n)))  # dragged back
    hand.update(2 * DT)
    np.testing.assert_array_equal(hand.wrenches_W(2 * DT, P_W_C, R_W_C), 0.0)
    # a sideways drag after the direction is set presses only with its part along n
    hand.post(HandAnchor(satellite=0, anchor_W_m=tuple(start + [0.03, 0.2, 0.0])))
    hand.update(3 * DT)
    np.testing.assert_allclose(hand.wrenches_W(3 * DT, P_W_C, R_W_C)[0, :3],
                               [6.0, 0.0, 0.0], atol=1e-12)


def test_the_press_is_continuous_in_depth_and_rate():
    """Hunt-Crossley with a clip at zero: the force along n is continuous across first
    touch (d = 0), across the clip (1 + c d_dot = 0) and at the cap, never negative."""
    hand, _ = _hand()
    n = np.array([0.0, 0.0, 1.0])
    _grab(hand, 0, 0.1 * n)
    depths = np.linspace(-0.02, 0.5, 2001)  # body behind/ahead of the hand: 0.1 - depth
    rates = np.linspace(-1.5, 0.5, 7)
    for rate in rates:
        forces = []
        for d in depths:
            p = P_W_C.copy()
            p[0] = P_W_C[0] + (0.1 - d) * n
            v = np.zeros((2, 3))
            v[0] = -rate * n
            forces.append(hand.wrenches_W(DT, p, R_W_C, v, np.zeros((2, 3)))[0, 2])
        forces = np.array(forces)
        assert forces.min() >= 0.0 and forces.max() <= HAND.max_force_N + 1e-12
        step = depths[1] - depths[0]
        slope = HAND.stiffness_Npm * (1.0 + HAND.damping_spm * max(rate, 0.0))
        assert np.max(np.abs(np.diff(forces))) <= slope * step * (1 + 1e-9)  # Lipschitz


def test_the_press_saturates_at_max_force():
    hand, _ = _hand()
    n = np.array([0.6, 0.8, 0.0])
    _grab(hand, 0, 1.0 * n)  # k d = 200 N > 60 N
    f = hand.wrenches_W(DT, P_W_C, R_W_C)[0, :3]
    np.testing.assert_allclose(f, HAND.max_force_N * n, atol=1e-12)


def test_a_free_body_pressed_and_held_leaves_along_the_press_never_back():
    """A 200 kg body (free-floating's lab-equivalent mass) pressed 10 cm along +x, the
    hand then held still for 30 s: the body accelerates until it has caught up with the
    hand, then the hand lets go; its velocity never decreases and ends at the closed form
    of a Hunt-Crossley press, a little under d sqrt(k / m) (the damping's share)."""
    cfg = EmulatorConfig(satellites=[SatelliteConfig(name="alpha")],
                         hand=HandConfig(stiffness_Npm=100.0, max_force_N=20.0))
    hand = OperatorHand(cfg, np.eye(3))
    m, dt = 200.0, 0.002
    p, v = np.zeros((1, 3)), np.zeros((1, 3))
    R = np.eye(3)[None]
    hand.post(HandAnchor(0, (0.0, 0.0, 0.0)))
    hand.update(0.0)
    hand.wrenches_W(0.0, p, R, v, np.zeros((1, 3)))
    hand.post(HandAnchor(0, (0.1, 0.0, 0.0)))
    vx, t = [], dt
    for _ in range(int(30.0 / dt)):
        hand.update(t)
        f = hand.wrenches_W(t, p, R, v, np.zeros((1, 3)))[0, :3]
        v = v + f / m * dt
        p = p + v * dt
        vx.append(v[0, 0])
        t += dt
    vx = np.array(vx)
    assert np.all(np.diff(vx) >= 0.0)  # never pulled back
    undamped = 0.1 * np.sqrt(100.0 / m)  # 7.07 cm/s
    assert 0.9 * undamped < vx[-1] <= undamped
    assert p[0, 0] > 0.1 + 25.0 * 0.9 * undamped  # long past the hand, let go


def test_the_gizmo_turned_twists_about_its_axis_and_never_back():
    """The gizmo turned by a about an axis: a torque k_t a about it (no force); once the
    body has turned further than the gizmo, none."""
    hand, _ = _hand()
    axis = np.array([0.0, 0.6, 0.8])
    start = P_W_C[1]
    hand.post(HandAnchor(1, tuple(start), attitude_W_wxyz=(1.0, 0.0, 0.0, 0.0)))
    hand.update(0.0)
    hand.wrenches_W(0.0, P_W_C, R_W_C)
    hand.post(HandAnchor(1, tuple(start), attitude_W_wxyz=tuple(rotvec_to_quat(0.2 * axis))))
    hand.update(DT)
    w = hand.wrenches_W(DT, P_W_C, R_W_C)
    np.testing.assert_array_equal(w[1, :3], 0.0)
    np.testing.assert_allclose(w[1, 3:], HAND.twist_stiffness_Nmprad * 0.2 * axis, atol=1e-12)
    R = R_W_C.copy()
    R[1] = rotvec_to_matrix(0.15 * axis) @ R_W_C[1]  # the body turned 0.15 rad after it
    w = hand.wrenches_W(2 * DT, P_W_C, R)
    np.testing.assert_allclose(w[1, 3:], HAND.twist_stiffness_Nmprad * 0.05 * axis,
                               atol=1e-12)
    for k in range(1, 10):  # the body runs ahead, 1 rad a cycle: past whole turns
        R[1] = rotvec_to_matrix((0.15 + k) * axis) @ R_W_C[1]
        np.testing.assert_array_equal(hand.wrenches_W((2 + k) * DT, P_W_C, R)[1], 0.0)


def test_a_grab_at_a_point_presses_there_and_turns_the_body():
    """The hand holds the mockup at r_B: the press acts at that point (not the COM), so
    a press across the body's surface turns it: moment r × F."""
    hand, _ = _hand()
    r_B = np.array([0.1, 0.0, 0.0])
    _grab(hand, 0, np.array([0.0, 0.0, 0.05]), point_B=r_B)
    w = hand.wrenches_W(DT, P_W_C, R_W_C)[0]
    push = HAND.stiffness_Npm * np.array([0.0, 0.0, 0.05])
    np.testing.assert_allclose(w[:3], push, atol=1e-12)
    np.testing.assert_allclose(w[3:], np.cross(R_W_C[0] @ r_B, push), atol=1e-12)


def test_gizmo_adds_to_a_push_on_the_same_satellite():
    hand, R_W_R = _hand()
    hand.post(Push(0, (5.0, 0.0, 0.0), 1.0, torque_B_Nm=(0.0, 0.0, 0.5)))
    _grab(hand, 0, np.array([0.0, 0.0, 0.1]))
    w = hand.wrenches_W(DT, P_W_C, R_W_C)[0]
    np.testing.assert_allclose(w[:3], R_W_R @ [5.0, 0.0, 0.0] + [0.0, 0.0, 20.0], atol=1e-12)
    np.testing.assert_allclose(w[3:], R_W_C[0] @ [0.0, 0.0, 0.5], atol=1e-12)


def test_anchor_none_lets_go_and_a_new_grab_starts_afresh():
    hand, _ = _hand()
    start = _grab(hand, 1, np.array([0.1, 0.0, 0.0]))
    np.testing.assert_allclose(hand.wrenches_W(DT, P_W_C, R_W_C)[1, :3], [20.0, 0.0, 0.0])
    hand.post(HandAnchor(satellite=1, anchor_W_m=None))
    assert not hand.idle(DT)  # posted, not yet applied
    hand.update(2 * DT)
    assert hand.idle(2 * DT)
    np.testing.assert_array_equal(hand.wrenches_W(2 * DT, P_W_C, R_W_C), 0.0)
    # grabbed again where the hand was: that is the new touch, no force until it moves
    hand.post(HandAnchor(satellite=1, anchor_W_m=tuple(start + [0.1, 0.0, 0.0])))
    hand.update(3 * DT)
    np.testing.assert_array_equal(hand.wrenches_W(3 * DT, P_W_C, R_W_C), 0.0)
    hand.post(HandAnchor(satellite=0, anchor_W_m=None))  # letting go of nothing is harmless
    hand.update(4 * DT)
    assert not hand.idle(4 * DT)


# --- idle ------------------------------------------------------------------------------------


def test_idle_means_no_pulse_push_or_gizmo_acts():
    hand, _ = _hand(PULSES)
    assert hand.idle(0.0) and hand.idle(0.4999)
    assert not hand.idle(0.5)  # a torque-only pulse counts
    assert not hand.idle(1.9999)
    assert hand.idle(2.0)  # end exclusive
    np.testing.assert_array_equal(hand.wrenches_W(2.0, P_W_C, R_W_C), 0.0)
    hand.post(Push(0, (1.0, 0.0, 0.0), 0.004))
    assert hand.idle(3.0)  # posted, not applied until update
    hand.update(3.0)
    assert not hand.idle(3.0)
    hand.update(3.0 + DT)
    assert not hand.idle(3.0 + DT)
    hand.update(3.0 + 2 * DT)
    assert hand.idle(3.0 + 2 * DT)
    # a grip counts even where it does not press (the hand holds the mockup)
    hand.post(HandAnchor(satellite=0, anchor_W_m=tuple(P_W_C[0])))
    hand.update(4.0)
    assert not hand.idle(4.0)
    np.testing.assert_array_equal(hand.wrenches_W(4.0, P_W_C, R_W_C), 0.0)


@pytest.mark.parametrize("kwargs, message", [
    ({"satellite": 0, "force_R_N": (1.0, 2.0, float("nan")), "duration_s": 0.1},
     "force_R_N: must be 3 finite numbers"),
    ({"satellite": 0, "force_R_N": (1.0, 2.0), "duration_s": 0.1},
     "force_R_N: must be 3 finite numbers"),
    ({"satellite": 0, "force_R_N": "abc", "duration_s": 0.1}, "force_R_N: must be 3 numbers"),
    ({"satellite": 0.5, "force_R_N": (1.0, 2.0, 3.0), "duration_s": 0.1},
     "satellite: must be an index >= 0"),
    ({"satellite": True, "force_R_N": (1.0, 2.0, 3.0), "duration_s": 0.1},
     "satellite: must be an index >= 0"),
    ({"satellite": 0, "force_R_N": (1.0, 2.0, 3.0), "duration_s": -1.0},
     "duration_s: must be a finite number of seconds > 0"),
    ({"satellite": 0, "force_R_N": (1.0, 2.0, 3.0), "duration_s": float("inf")},
     "duration_s: must be a finite number of seconds > 0"),
])
def test_a_bad_push_is_refused_where_it_is_made(kwargs, message):
    with pytest.raises(ValueError, match=message):
        Push(**kwargs)


def test_a_bad_anchor_is_refused_and_none_lets_go():
    with pytest.raises(ValueError, match="anchor_W_m: must be 3 finite numbers"):
        HandAnchor(satellite=0, anchor_W_m=(0.1, float("inf"), 0.0))
    assert HandAnchor(satellite=0, anchor_W_m=None).anchor_W_m is None
    assert HandAnchor(satellite=0, anchor_W_m=[1, 2, 3]).anchor_W_m == (1.0, 2.0, 3.0)


def test_posting_something_else_is_refused_and_changes_nothing():
    hand, _ = _hand()
    with pytest.raises(TypeError, match="not a Push or HandAnchor"):
        hand.post(("push", 0))
    hand.update(0.0)
    assert hand.idle(0.0)


# --- where the hand acts: a point of the body --------------------------------------------


def test_a_push_at_a_point_adds_the_moment_r_cross_f_about_the_com():
    """A force F (in R) at point r_B of the body: force R_W_R F, moment (R_W_C r_B) × F_W,
    and in body axes r_B × F_B, as a lever does."""
    hand, R_W_R = _hand()
    r_B = np.array([0.1, -0.05, 0.02])
    f_R = np.array([0.0, 20.0, -5.0])
    hand.post(Push(satellite=1, force_R_N=tuple(f_R), duration_s=0.3, point_B_m=tuple(r_B)))
    hand.update(0.0)
    w = hand.wrenches_W(0.0, P_W_C, R_W_C)
    f_W = R_W_R @ f_R
    np.testing.assert_allclose(w[1, :3], f_W, atol=1e-12)
    np.testing.assert_allclose(w[1, 3:], np.cross(R_W_C[1] @ r_B, f_W), atol=1e-12)
    f_B = R_W_C[1].T @ f_W
    np.testing.assert_allclose(R_W_C[1].T @ w[1, 3:], np.cross(r_B, f_B), atol=1e-12)
    assert abs(w[1, 3:] @ f_W) < 1e-12  # the moment is normal to the force
    np.testing.assert_array_equal(w[0], np.zeros(6))


@pytest.mark.parametrize(
    ("origin", "direction", "hit"),
    [
        ((1.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.1, 0.0, 0.0)),  # straight at the +x face
        ((1.0, 0.03, -0.02), (-2.0, 0.0, 0.0), (0.1, 0.03, -0.02)),  # any length of ray
        ((0.0, 0.0, 1.0), (0.0, 0.0, -1.0), (0.0, 0.0, 0.05)),  # the top (z half 0.05)
        ((1.0, 1.0, 0.0), (-1.0, -1.0, 0.0), (0.1, 0.1, 0.0)),  # an edge, diagonally
        ((1.0, 0.2, 0.0), (-1.0, 0.0, 0.0), None),  # passes beside it
        ((1.0, 0.0, 0.0), (1.0, 0.0, 0.0), None),  # points away
        ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, 0.0)),  # starts inside: there
    ],
)
def test_a_click_ray_meets_the_box_where_geometry_says(origin, direction, hit):
    """ray_box_hit in the box's own frame, then with the box moved and turned in W: the
    same body point."""
    size = (0.2, 0.2, 0.1)
    got = ray_box_hit(np.array(origin), np.array(direction), np.eye(4), size)
    if hit is None:
        assert got is None
        return
    np.testing.assert_allclose(got, hit, atol=1e-12)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R_W_C[1], P_W_C[1]
    moved = ray_box_hit(T[:3, :3] @ origin + T[:3, 3], T[:3, :3] @ direction, T, size)
    np.testing.assert_allclose(moved, hit, atol=1e-12)


@pytest.mark.parametrize("point", [(0.0, float("nan"), 0.0), (1.0, 2.0), "abc"])
def test_a_bad_point_is_refused_where_it_is_made(point):
    with pytest.raises(ValueError, match="point_B_m: must be 3"):
        Push(satellite=0, force_R_N=(1.0, 0.0, 0.0), duration_s=0.1, point_B_m=point)
    with pytest.raises(ValueError, match="point_B_m: must be 3"):
        HandAnchor(satellite=0, anchor_W_m=(0.0, 0.0, 1.0), point_B_m=point)


def test_a_push_s_torque_acts_in_body_axes_and_a_bad_one_is_refused():
    hand, _ = _hand()
    hand.post(Push(1, (0.0, 0.0, 0.0), 0.1, torque_B_Nm=(0.0, 0.0, 2.0)))
    hand.update(0.0)
    w = hand.wrenches_W(0.0, P_W_C, R_W_C)
    np.testing.assert_allclose(w[1], [0, 0, 0, *(R_W_C[1] @ [0.0, 0.0, 2.0])], atol=1e-12)
    with pytest.raises(ValueError, match="torque_B_Nm: must be 3 finite numbers"):
        Push(0, (0.0, 0.0, 0.0), 0.1, torque_B_Nm=(0.0, float("nan"), 0.0))


@pytest.mark.parametrize("q", [(0.0, 0.0, 0.0, 0.0), (1.0, 0.0, float("inf"), 0.0),
                               (1.0, 0.0, 0.0)])
def test_a_bad_gizmo_attitude_is_refused(q):
    with pytest.raises(ValueError, match="attitude_W_wxyz: must be 4 finite numbers, not all"):
        HandAnchor(satellite=0, anchor_W_m=(0.0, 0.0, 1.0), attitude_W_wxyz=q)
