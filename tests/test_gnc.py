"""A satellite's own GNC (app/sim/gnc.py): actuator limits, the controller on the CW plant,
the waypoint guidance, the units its wrench enters the ODS in, and its configuration."""

import math
import re

import numpy as np
import pytest

from app.config import ConfigError, GncConfig, parse_config, sampled_pd_radius
from app.sim.gnc import (
    GncParams,
    GncState,
    Navigation,
    attitude_torque_B,
    cw_acceleration,
    gnc_step,
    guidance,
    navigation,
    reference,
    thruster_force_B,
    wheel_torque_B,
    within_tolerance,
)
from app.sim.guidance import two_impulse_transfer
from app.sim.loop import Emulator
from app.sim.orbital import (
    OdsParams,
    OrbitalSimulator,
    cw_state_transition,
    derivative,
    omega_inertial_from_relative,
    orbit_rate,
)
from app.sim.rotations import quat_mul, quat_to_matrix, rotvec_to_quat
from app.sim.scaling import Scaling

OMEGA = orbit_rate(800e3)
FAR_ALTITUDE_M = 1e15
"""An orbit so wide that Ω ≈ 6e-16 rad/s: no CW or gravity-gradient term to speak of."""


def _params(**kw) -> GncParams:
    base = dict(mass_kg=100.0, inertia_kgm2=np.array([10.0, 12.0, 16.0]),
                orbit_rate_radps=OMEGA, waypoints_m=np.array([[0.0, 0.0, 0.0]]),
                hold_s=np.array([0.0]))
    return GncParams(**{**base, **kw})


def _nav(t_s=0.0, p=(0.0, 0.0, 0.0), v=(0.0, 0.0, 0.0), q=(1.0, 0.0, 0.0, 0.0),
         w=(0.0, 0.0, 0.0)) -> Navigation:
    q = np.array(q, dtype=float)
    return Navigation(t_s, np.array(p, float), np.array(v, float), q, np.array(w, float),
                      quat_to_matrix(q))


# --- actuators -------------------------------------------------------------------------------


def test_thrusters_saturate_each_body_axis_at_their_thrust():
    p = _params(thrust_max_N=1.0, min_impulse_bit_Ns=0.0)
    np.testing.assert_array_equal(thruster_force_B(p, np.array([3.0, -0.4, -7.0])),
                                  [1.0, -0.4, -1.0])
    np.testing.assert_array_equal(wheel_torque_B(_params(torque_max_Nm=0.1),
                                                 np.array([0.5, -0.05, -0.2])),
                                  [0.1, -0.05, -0.1])


def test_an_impulse_below_the_minimum_impulse_bit_is_not_fired():
    """MIB 0.01 N s over a 0.5 s period: a thruster commanded below 0.02 N stays shut; one
    at or above it fires what was asked; each axis on its own."""
    p = _params(thrust_max_N=1.0, min_impulse_bit_Ns=0.01, period_s=0.5)
    np.testing.assert_array_equal(thruster_force_B(p, np.array([0.0199, -0.0199, 0.02])),
                                  [0.0, 0.0, 0.02])
    np.testing.assert_array_equal(thruster_force_B(p, np.array([-0.5, 0.019, 2.0])),
                                  [-0.5, 0.0, 1.0])


def test_the_command_is_computed_once_a_period_and_held():
    """period 1 s, loop cycles of 0.25 s: the thrusters' force changes only at 0, 1, 2 s,
    though the state moves every cycle; it is the PD's force of the state at those times."""
    p = _params(waypoints_m=np.array([[1.0, 0.0, 0.0]]), min_impulse_bit_Ns=0.0,
                thrust_max_N=10.0, orbit_rate_radps=0.0)
    state, forces = GncState(), []
    for k in range(10):
        t = 0.25 * k
        state, f_R, _ = gnc_step(p, state, _nav(t, p=(0.1 * t, 0.0, 0.0)), 0.25)
        forces.append(f_R[0])
    wn, m = p.position_omega_radps, p.mass_kg
    expected = [m * wn * wn * (1.0 - 0.1 * t) for t in (0.0, 1.0, 2.0)]
    np.testing.assert_allclose(forces, np.repeat(expected, 4)[:10], rtol=1e-12)


# --- the controller on the plant -------------------------------------------------------------


def _fly(params: GncParams, y0: np.ndarray, duration_s: float, dt_s: float = 0.1,
         gravity_gradient: bool = True) -> tuple[OrbitalSimulator, list]:
    """The orbit-unit ODS (Eqs. 1-7, unit scales) under the GNC alone."""
    ods = OrbitalSimulator(OdsParams(params.orbit_rate_radps, np.array([params.mass_kg]),
                                     params.inertia_kgm2[None, :], gravity_gradient,
                                     1.0, 1.0), y0.copy())
    unit, state, states = Scaling("paper", 1.0, 1.0, 1.0, 1.0, 1.0), GncState(), []
    for _ in range(int(round(duration_s / dt_s))):
        nav = navigation(ods.y[0], ods.t_s, unit, params.orbit_rate_radps)
        state, f_R, tau_B = gnc_step(params, state, nav, dt_s)
        ods.step(f_R[None, :], tau_B[None, :], dt_s)
        states.append(state)
    return ods, states


def _at_rest(position_m, attitude_wxyz=(1.0, 0.0, 0.0, 0.0), w=OMEGA) -> np.ndarray:
    y = np.zeros((1, 13))
    y[0, :3] = position_m
    y[0, 6:10] = attitude_wxyz
    y[0, 10:] = omega_inertial_from_relative(y[:, 6:10], np.zeros((1, 3)), w)
    return y


def test_the_pd_holds_a_point_off_the_origin_without_steady_error():
    """Holding x = 20 m radial, where the CW plant pulls at 3Ω²x: a bare PD of ω_n = 0.02
    would sit 3Ω²x / ω_n² = 0.16 m off; with the CW terms cancelled it converges."""
    target = np.array([20.0, 5.0, -3.0])
    p = _params(waypoints_m=target[None, :], position_omega_radps=0.02, min_impulse_bit_Ns=0.0)
    assert 3 * OMEGA**2 * 20.0 / 0.02**2 > 0.15
    ods, _ = _fly(p, _at_rest(target + [1.0, -1.0, 0.5]), 1500.0, dt_s=0.5)
    assert np.linalg.norm(ods.position_m[0] - target) < 1e-4
    assert np.linalg.norm(ods.velocity_mps[0]) < 1e-6
    # the force it keeps on is the one the CW plant needs there: m 3Ω²x radially
    state = _fly(p, ods.y, 2.0, dt_s=0.5)[1][-1]
    np.testing.assert_allclose(state.force_B_N, [-p.mass_kg * 3 * OMEGA**2 * 20.0, 0.0,
                                                 p.mass_kg * OMEGA**2 * -3.0],
                               rtol=1e-3, atol=1e-9)


def test_the_minimum_impulse_bit_leaves_a_dead_band_it_stays_in():
    """With MIB the PD does not fire below |F| period < MIB, i.e. within
    MIB / (m ω_n² period) of the point: the satellite ends inside that band, not on it."""
    target = np.array([0.5, -0.3, 0.2])
    p = _params(waypoints_m=target[None, :], min_impulse_bit_Ns=0.05)
    band = p.min_impulse_bit_Ns / (p.mass_kg * p.position_omega_radps**2 * p.period_s)
    ods, _ = _fly(p, _at_rest([0.0, 0.0, 0.0]), 300.0)
    error = np.linalg.norm(ods.position_m[0] - target)
    assert error < 2.0 * band
    assert error > 1e-3  # a PD that fired every impulse would sit on it (previous test)


def test_the_attitude_pd_turns_to_its_target_under_the_gravity_gradient():
    """From 30 deg off, with wheels of 0.05 N m and the gravity-gradient torque of an
    asymmetric body at a tilted target (a torque the feedforward cancels), it settles
    on the target."""
    target = rotvec_to_quat(np.radians([10.0, -20.0, 35.0]))
    p = _params(attitude_wxyz=target, torque_max_Nm=0.05, inertia_kgm2=np.array([10.0, 14.0,
                                                                                  20.0]))
    start = rotvec_to_quat(np.radians([10.0, -20.0, 35.0]) + np.radians([20.0, 15.0, -15.0]))
    c = quat_to_matrix(target)[0]
    gg = 3 * OMEGA**2 * np.cross(c, p.inertia_kgm2 * c)
    assert np.linalg.norm(gg) > 1e-6  # a torque there to be held against
    ods, states = _fly(p, _at_rest([0.0, 0.0, 0.0], start), 200.0)
    q = ods.attitude_wxyz[0]
    angle = 2.0 * math.acos(min(1.0, abs(float(np.dot(q, target)))))
    assert angle < 1e-4
    assert np.linalg.norm(ods.omega_rel_radps[0]) < 1e-6
    held = np.array([s.torque_B_Nm for s in states])
    assert np.max(np.abs(held)) == 0.05  # the wheels saturated on the way, no more
    # held there, it gives what Euler's equations ask of a body turning with R at Ω:
    # ω × I ω − 3Ω² c × I c, with ω = Ω n (n: R's z in body axes)
    w = OMEGA * quat_to_matrix(target)[2]
    np.testing.assert_allclose(attitude_torque_B(p, _nav(q=q, w=ods.omega_rel_radps[0])),
                               np.cross(w, p.inertia_kgm2 * w) - gg, rtol=1e-3, atol=1e-10)


def test_the_cw_acceleration_is_eqs_1_to_3_of_a_free_body():
    params = OdsParams(OMEGA, np.array([1.0]), np.ones((1, 3)), False, 1.0, 1.0)
    y = np.zeros((1, 13))
    y[0, :7] = [2.0, -1.0, 0.5, 0.01, 0.03, -0.02, 1.0]
    dy = derivative(params, y, np.zeros((1, 3)), np.zeros((1, 3)))
    np.testing.assert_allclose(cw_acceleration(OMEGA, y[0, :3], y[0, 3:6]), dy[0, 3:6],
                               rtol=1e-15)


# --- guidance --------------------------------------------------------------------------------


def test_waypoints_advance_after_their_hold_and_a_break_starts_the_hold_anew():
    p = _params(waypoints_m=np.array([[1.0, 0.0, 0.0], [2.0, 0.0, 0.0]]),
                hold_s=np.array([3.0, 0.0]), tolerance_m=0.1, tolerance_mps=0.01)
    s = GncState()
    s = guidance(p, s, _nav(0.0, p=(0.5, 0.0, 0.0)))  # too far
    assert (s.waypoint, math.isnan(s.inside_since_s)) == (0, True)
    s = guidance(p, s, _nav(1.0, p=(0.95, 0.0, 0.0), v=(0.02, 0.0, 0.0)))  # too fast
    assert math.isnan(s.inside_since_s)
    s = guidance(p, s, _nav(2.0, p=(0.95, 0.0, 0.0)))
    assert (s.waypoint, s.inside_since_s) == (0, 2.0)
    s = guidance(p, s, _nav(4.0, p=(1.05, 0.0, 0.0)))
    assert s.waypoint == 0  # held 2 s of 3
    s = guidance(p, s, _nav(4.5, p=(1.2, 0.0, 0.0)))  # out: the hold starts anew
    s = guidance(p, s, _nav(5.0, p=(1.0, 0.0, 0.0)))
    s = guidance(p, s, _nav(7.9, p=(1.0, 0.0, 0.0)))
    assert s.waypoint == 0
    s = guidance(p, s, _nav(8.0, p=(1.0, 0.0, 0.0)))
    assert s.waypoint == 1 and np.array_equal(p.target_m(s.waypoint), [2.0, 0.0, 0.0])
    s = guidance(p, s, _nav(9.0, p=(2.0, 0.0, 0.0)))  # hold 0: reached at once
    assert s.waypoint == 2
    assert np.array_equal(p.target_m(s.waypoint), [2.0, 0.0, 0.0])  # the last is held
    assert guidance(p, s, _nav(10.0, p=(0.0, 0.0, 0.0))) == s


def test_it_flies_its_waypoints_in_order_on_the_plant():
    wps = np.array([[1.0, 0.0, 0.0], [1.0, 1.0, 0.5], [0.0, 0.0, 0.0]])
    p = _params(waypoints_m=wps, hold_s=np.array([5.0, 5.0, 0.0]))
    ods, states = _fly(p, _at_rest([0.0, 0.0, 0.0]), 400.0)
    reached = [next(k for k, s in enumerate(states) if s.waypoint > n) for n in range(3)]
    assert reached == sorted(reached) and states[-1].waypoint == 3
    assert np.linalg.norm(ods.position_m[0]) < p.tolerance_m


# --- navigation and the units the wrench enters the ODS in -----------------------------------


def test_navigation_reads_the_lab_unit_state_in_orbit_units():
    sc = Scaling("similarity", 4.0, 50.0, 3.0, 3.0, 48.0)
    q = rotvec_to_quat(np.array([0.2, -0.1, 0.4]))
    p_lab, v_lab, w_lab = sc.to_lab([2.0, -1.0, 0.5], [0.01, -0.02, 0.005],
                                    [0.002, -0.001, 0.003])
    W_lab = sc.orbit_rate_lab(OMEGA)
    y = np.concatenate([p_lab, v_lab, q,
                        omega_inertial_from_relative(q[None, :], w_lab[None, :], W_lab)[0]])
    nav = navigation(y, 2.0, sc, W_lab)
    assert nav.t_s == 100.0
    np.testing.assert_allclose(nav.position_m, [2.0, -1.0, 0.5], rtol=1e-15)
    np.testing.assert_allclose(nav.velocity_mps, [0.01, -0.02, 0.005], rtol=1e-15)
    np.testing.assert_allclose(nav.omega_rel_radps, [0.002, -0.001, 0.003], rtol=1e-12)
    np.testing.assert_allclose(nav.R_R_B, quat_to_matrix(q), atol=1e-15)


K_L, K_T, K_M = 4.0, 20.0, 3.0


def _thrusting(law: dict, pulses=()) -> dict:
    """One satellite whose GNC flies to a far waypoint (thrusting, saturated) and turns
    about z to a far attitude (the wheels saturated): its wrench is known in orbit units."""
    return {"orbit": {"altitude_m": FAR_ALTITUDE_M}, **law,
            "loop": {"duration_s": 1.0},
            "pulses": list(pulses),
            "satellites": [{"name": "s", "mass_kg": 80.0, "inertia_kgm2": [6.0, 7.0, 9.0],
                            "mockup_mass_kg": 1.0,
                            "gnc": {"waypoints": [{"position_m": [30.0, -20.0, 10.0]}],
                                    "attitude_wxyz": [0.0, 0.0, 0.0, 1.0],
                                    "thrust_max_N": 2.0, "min_impulse_bit_Ns": 0.0,
                                    "torque_max_Nm": 0.3, "period_s": 0.4}}]}


@pytest.mark.parametrize("law", [
    {"scaling": {"law": "similarity", "length": K_L, "time": K_T, "mass": K_M}},
    {"orbit": {"altitude_m": FAR_ALTITUDE_M, "force_scale": 0.05, "torque_scale": 0.0005}},
], ids=["similarity", "paper"])
def test_the_orbit_impulse_commanded_is_the_orbit_momentum_gained(law):
    """An ideal run: the momentum the virtual satellite gains, in orbit units (m k_L/k_T
    Δv', I Δω'/k_T), is the sum over cycles of the GNC's recorded wrench × the orbit time
    of a cycle: the wrench entered the ODS as F k_T² / (k_L force_scale) and
    τ k_T² / torque_scale. (A torque about z with ω along z: no gyroscopic term.)"""
    cfg = parse_config(_thrusting(law))
    em = Emulator(cfg, mode="ideal")
    em.run(cfg.loop.duration_s)
    rows, ix = em.telemetry.rows(), em.telemetry.index
    sc = em.scaling
    dt_orbit = sc.time * em.dt_s
    cols = lambda names: rows[:, [ix[f"sat1_{n}"] for n in names]]  # noqa: E731
    gnc = cols(("gnc_fx_N", "gnc_fy_N", "gnc_fz_N", "gnc_tx_Nm", "gnc_ty_Nm", "gnc_tz_Nm"))
    impulse = gnc[:-1].sum(axis=0) * dt_orbit  # the last row: the final state, no step
    assert np.all(np.abs(impulse[:3]) > 0.05) and abs(impulse[5]) > 0.01
    dv = sc.velocity * (cols(("vx_mps", "vy_mps", "vz_mps"))[-1]
                        - cols(("vx_mps", "vy_mps", "vz_mps"))[0])
    np.testing.assert_allclose(80.0 * dv, impulse[:3], rtol=1e-9)
    dw = cols(("wx_radps", "wy_radps", "wz_radps"))[-1] / sc.time
    np.testing.assert_allclose(9.0 * dw[2], impulse[5], rtol=1e-9)
    np.testing.assert_allclose(dw[:2], 0.0, atol=1e-15)
    assert np.all(rows[:, ix["sat1_fx_N"]] == 0.0)  # its own thrust is not an external force


def test_its_own_thrust_acts_within_the_sub_stepped_contact_cycles_of_an_ideal_run():
    """Two satellites collide in an ideal run while one thrusts: the contact forces cancel
    (each cycle's sub-steps included), so the pair's momentum changes by the GNC's impulse
    alone. Were the thrust left out of the sub-stepped cycles, the ~1e-3 N s it gives
    during the contact would be missing."""
    cfg = parse_config({
        "orbit": {"altitude_m": FAR_ALTITUDE_M, "force_scale": 1.0},
        "loop": {"duration_s": 1.5},
        "satellites": [
            {"name": "a", "gnc": {"waypoints": [{"position_m": [100.0, 0.0, 0.0]}],
                                  "thrust_max_N": 0.05, "min_impulse_bit_Ns": 0.0,
                                  "period_s": 0.002}},
            {"name": "b", "position_m": [0.25, 0.0, 0.0], "velocity_mps": [-0.1, 0.0, 0.0]}]})
    em = Emulator(cfg, mode="ideal")
    em.run(cfg.loop.duration_s)
    rows, ix = em.telemetry.rows(), em.telemetry.index
    touching = np.abs(rows[:, ix["sat2_true_fx_N"]]) > 0
    assert touching.sum() >= 5  # a contact of several cycles, sub-stepped
    np.testing.assert_array_equal(rows[touching, ix["sat1_gnc_fx_N"]], 0.05)  # thrusting
    v = rows[:, [ix["sat1_vx_mps"], ix["sat2_vx_mps"]]]
    momentum_change = float(np.sum(v[-1] - v[0]))  # both 1 kg
    thrust_impulse = float(rows[:-1, ix["sat1_gnc_fx_N"]].sum() * em.dt_s)
    assert momentum_change == pytest.approx(thrust_impulse, rel=1e-9, abs=1e-12)
    assert v[-1, 1] > 0.0  # b bounced off


# --- configuration ---------------------------------------------------------------------------


def test_gnc_settings_are_validated_naming_the_field():
    sat = {"name": "s", "mockup_mass_kg": 1.0, "gnc": {"waypoints": [{"position_m": [0, 0, 0]}]}}

    def config(gnc=None, **top):
        s = dict(sat, gnc={**sat["gnc"], **(gnc or {})})
        return {"scaling": {"law": "similarity", "time": 10.0}, "satellites": [s], **top}

    assert parse_config(config()).satellites[0].gnc.thrust_max_N == 1.0  # the defaults
    bad = [
        ({"thrust": 1.0}, "satellites.0.gnc.thrust: Extra inputs are not permitted"),
        ({"thrust_max_N": -1.0}, "satellites.0.gnc.thrust_max_N"),
        ({"waypoints": []}, "satellites.0.gnc.waypoints"),
        ({"waypoints": [{"position_m": [0, 0]}]}, "satellites.0.gnc.waypoints.0.position_m"),
        ({"waypoints": [{"position_m": [0, 0, 0], "hold_s": -1}]},
         "satellites.0.gnc.waypoints.0.hold_s"),
        ({"position_damping": 3.0}, "satellites.0.gnc.position_damping"),
        ({"min_impulse_bit_Ns": 1.0}, "min_impulse_bit_Ns: 1 N s is not below a whole period"),
        ({"position_omega_radps": 1.5}, "position_omega_radps: 1.5 rad/s with damping 0.8, "
                                        "sampled every 1 s, is unstable"),
        ({"period_s": 0.01, "min_impulse_bit_Ns": 0.001},
         "satellites.0.gnc.period_s: 0.01 s is shorter than one loop cycle (0.02 s"),
    ]
    for gnc, message in bad:
        with pytest.raises(ConfigError, match=re.escape(message)):
            parse_config(config(gnc))
    with pytest.raises(ConfigError, match="success: waypoints_reached"):
        parse_config({"success": {"waypoints_reached": True}})
    with pytest.raises(ConfigError, match="satellites.0.gnc: a zero"):
        parse_config({"orbit": {"force_scale": 0.0},
                      "satellites": [{"name": "s", "gnc": sat["gnc"]}]})


def test_the_stability_bound_is_the_sampled_double_integrator_s():
    """ωT = 1 with ζ = 1 puts both poles of the held PD at the unit circle's edge; the
    defaults (0.1 and 0.2 rad/s at 1 s) are well inside."""
    assert sampled_pd_radius(1.0, 1.0) == pytest.approx(1.0, abs=1e-6)
    assert sampled_pd_radius(0.1, 0.8) < 0.95 and sampled_pd_radius(0.2, 0.8) < 0.9
    assert GncConfig(waypoints=[{"position_m": [0, 0, 0]}]).period_s == 1.0


# --- legs: CW transfers, straight approaches, free drift; relative to a spinning target ------


def _leg_params(**kw) -> GncParams:
    """One waypoint 25 m further along V-bar, flown as a 1200 s CW transfer (500 kg, 2 N
    thrusters, a 0.05 N s minimum impulse bit, a 2 s period)."""
    base = dict(mass_kg=500.0, inertia_kgm2=np.array([300.0, 300.0, 400.0]),
                waypoints_m=np.array([[0.0, -75.0, 0.0]]), hold_s=np.array([0.0]),
                transfer_s=np.array([1200.0]), position_omega_radps=0.02, thrust_max_N=2.0,
                min_impulse_bit_Ns=0.05, period_s=2.0, tolerance_m=0.5, tolerance_mps=0.002)
    return _params(**{**base, **kw})


def test_a_cw_transfer_leg_fires_the_closed_form_impulse_and_arrives_on_time():
    """From rest at y = -100 m to y = -75 m in 1200 s: the first burn (spread over the
    periods the 2 N thrusters need) delivers the closed-form Δv1 of
    app/sim/guidance.py; the satellite arrives within 5 cm when due, then brakes to a
    hold within tolerance."""
    p = _leg_params()
    dv1, dv2 = two_impulse_transfer([0, -100, 0], [0, 0, 0], [0, -75, 0], [0, 0, 0], 1200.0,
                                    OMEGA)
    assert p.mass_kg * np.max(np.abs(dv1)) > 2 * p.thrust_max_N * p.period_s  # saturated
    ods, states = _fly(p, _at_rest([0.0, -100.0, 0.0]), 1200.0, dt_s=0.5)
    burn = [s.force_B_N for s in states[:100:4]]  # one per 2 s period, the first 50 s
    np.testing.assert_allclose(np.sum(burn, axis=0) * p.period_s / p.mass_kg, dv1, rtol=0.01)
    assert np.linalg.norm(ods.position_m[0] - [0.0, -75.0, 0.0]) < 0.05
    np.testing.assert_allclose(ods.velocity_mps[0], -dv2, atol=2e-4)  # what braking removes
    ods, states = _fly(p, ods.y, 200.0, dt_s=0.5)
    assert np.linalg.norm(ods.position_m[0] - [0.0, -75.0, 0.0]) < p.tolerance_m
    assert np.linalg.norm(ods.velocity_mps[0]) < p.tolerance_mps


def test_a_cw_transfer_is_re_targeted_after_a_push_mid_course():
    """A 2 cm/s push at a quarter of the way: coasting, it would miss by metres; the
    re-targeted guidance fires a mid-course correction and still arrives within 0.5 m."""
    p = _leg_params()
    ods, states = _fly(p, _at_rest([0.0, -100.0, 0.0]), 300.0, dt_s=0.5)
    ods.y[0, 3] += 0.02  # the push, radial
    free = cw_state_transition(OMEGA, 900.0) @ np.concatenate([ods.position_m[0],
                                                              ods.velocity_mps[0]])
    assert np.linalg.norm(free[:3] - [0.0, -75.0, 0.0]) > 5.0
    state = states[-1]
    for _ in range(1800):
        nav = navigation(ods.y[0], ods.t_s, Scaling("paper", 1, 1, 1, 1, 1), OMEGA)
        state, f_R, tau_B = gnc_step(p, state, nav, 0.5)
        ods.step(f_R[None, :], tau_B[None, :], 0.5)
    assert np.linalg.norm(ods.position_m[0] - [0.0, -75.0, 0.0]) < 0.5


def test_an_approach_leg_closes_at_its_speed_and_drifts_its_last_stretch():
    """Straight at a point 1 m away at 2 cm/s (no orbit to speak of): the speed settles at
    2 cm/s; within free_drift_m it stops firing for good and drifts through."""
    p = _params(orbit_rate_radps=6e-16, waypoints_m=np.array([[1.0, 0.0, 0.0]]),
                approach_speed_mps=np.array([0.02]), free_drift_m=np.array([0.05]),
                position_omega_radps=0.5, period_s=0.2, min_impulse_bit_Ns=0.002)
    y0 = _at_rest([0.0, 0.0, 0.0], w=6e-16)
    ods, states = _fly(p, y0, 30.0, gravity_gradient=False)
    assert ods.velocity_mps[0] == pytest.approx([0.02, 0.0, 0.0], abs=2e-4)
    assert not states[-1].drifting
    ods, states = _fly(p, ods.y, 40.0, gravity_gradient=False)
    start = next(k for k, s in enumerate(states) if s.drifting)
    assert all(s.drifting and not s.force_B_N.any() and not s.torque_B_Nm.any()
               for s in states[start:])
    assert ods.position_m[0, 0] > 1.3  # it did not stop at the point: it drifted on


def _spinning(rate_radps=0.05, offset=(-0.5, 0.0, 0.0), yaw_rad=0.3):
    """A target at R's origin spinning about z and the reference of a point of its body."""
    q = rotvec_to_quat(np.array([0.0, 0.0, yaw_rad]))
    target = _nav(q=q, w=(0.0, 0.0, rate_radps))
    p = _params(waypoints_m=np.array([offset]), relative=True)
    return p, target, reference(p, 0, target)


def test_the_reference_of_a_point_of_a_spinning_target_turns_with_it():
    """r = R(θ) p, v = ω × r, a = -ω² r (a spin about z through the origin, Ω negligible
    here: its CW term on the target at rest at the origin is zero); the attitude is the
    target's, the rate ω."""
    rate, yaw = 0.05, 0.3
    p, target, ref = _spinning(rate, yaw_rad=yaw)
    r = -0.5 * np.array([math.cos(yaw), math.sin(yaw), 0.0])
    np.testing.assert_allclose(ref.position_m, r, atol=1e-15)
    np.testing.assert_allclose(ref.velocity_mps, rate * np.array([-r[1], r[0], 0.0]),
                               atol=1e-15)
    np.testing.assert_allclose(ref.accel_mps2, -rate**2 * r, atol=1e-15)
    np.testing.assert_allclose(ref.attitude_wxyz, target.attitude_wxyz)
    np.testing.assert_allclose(ref.omega_R_radps, [0.0, 0.0, rate])
    # the tolerance is to the moving reference: at its point, at its velocity, inside
    assert within_tolerance(p, ref, _nav(p=r, v=ref.velocity_mps))
    assert not within_tolerance(p, ref, _nav(p=r))  # at rest there: 2.5 cm/s off


def test_a_chaser_flying_relative_to_a_spinning_target_synchronises_with_it():
    """Two satellites in one ODS: the target spins at 3 deg/s about its major axis; the
    chaser, from rest, ends on the point 0.5 m off the target's -x face that turns with
    it, and with the target's attitude and rate."""
    rate = math.radians(3.0)
    p = _params(waypoints_m=np.array([[-0.5, 0.0, 0.0]]), relative=True,
                position_omega_radps=0.3, attitude_omega_radps=0.5, period_s=0.2,
                min_impulse_bit_Ns=0.0, torque_max_Nm=0.2)
    y0 = np.vstack([_at_rest([-0.6, 0.1, 0.0]), _at_rest([0.0, 0.0, 0.0])])
    y0[1, 10:] = omega_inertial_from_relative(y0[1:, 6:10], np.array([[0.0, 0.0, rate]]),
                                              OMEGA)[0]
    ods = OrbitalSimulator(OdsParams(OMEGA, np.array([100.0, 100.0]),
                                     np.array([[10.0, 12.0, 16.0], [10.0, 10.0, 16.0]]),
                                     True, 1.0, 1.0), y0)
    unit, state, dt = Scaling("paper", 1, 1, 1, 1, 1), GncState(), 0.05
    for _ in range(int(60.0 / dt)):
        nav, tgt = (navigation(ods.y[i], ods.t_s, unit, OMEGA) for i in (0, 1))
        state, f_R, tau_B = gnc_step(p, state, nav, dt, tgt)
        ods.step(np.vstack([f_R, np.zeros(3)]), np.vstack([tau_B, np.zeros(3)]), dt)
    ref = reference(p, 0, tgt)
    assert np.linalg.norm(nav.position_m - ref.position_m) < 1e-3
    assert np.linalg.norm(nav.velocity_mps - ref.velocity_mps) < 1e-4
    q_e = quat_mul(ref.attitude_wxyz * [1, -1, -1, -1], nav.attitude_wxyz)
    assert 2 * math.acos(min(1.0, abs(q_e[0]))) < math.radians(0.05)
    np.testing.assert_allclose(nav.R_R_B @ nav.omega_rel_radps, [0.0, 0.0, rate], atol=1e-5)
    # the point has turned with the target, nearly half a turn, from -x towards +x
    turned = rate * tgt.t_s
    np.testing.assert_allclose(ref.position_m, [-0.5 * math.cos(turned),
                                                -0.5 * math.sin(turned), 0.0], atol=1e-6)


@pytest.mark.parametrize(("gnc", "where", "message"), [
    ({"relative_to": "ghost"}, "satellites.0.gnc.relative_to",
     "'ghost' names no other satellite (have ['a', 'b'])"),
    ({"relative_to": "a"}, "satellites.0.gnc.relative_to",
     "'a' names no other satellite (have ['a', 'b'])"),
    ({"relative_to": "b", "waypoints": [{"position_m": [1, 0, 0], "transfer_s": 600.0}]},
     "satellites.0.gnc.waypoints.0.transfer_s",
     "a CW transfer flies to a point of R; not with relative_to"),
    ({"waypoints": [{"position_m": [1, 0, 0], "transfer_s": 6000.0}]},
     "satellites.0.gnc.waypoints.0.transfer_s",
     "6000 s is not below 0.9 of an orbit (5447 s of 6052 s)"),
    ({"waypoints": [{"position_m": [1, 0, 0], "transfer_s": 3000.0}]},
     "satellites.0.gnc.waypoints.0.transfer_s",
     "3000 s is within 61 s of half an orbit (3026 s), where the out-of-plane motion "
     "returns to its start whatever the first impulse: no CW transfer can aim it"),
    ({"waypoints": [{"position_m": [1, 0, 0], "transfer_s": 600.0,
                     "approach_speed_mps": 0.02}]},
     "satellites.0.gnc.waypoints.0",
     "transfer_s and approach_speed_mps: a leg is flown one way; give one of them"),
])
def test_gnc_legs_are_validated_naming_the_field(gnc, where, message):
    sat = {"name": "a", "gnc": {"waypoints": [{"position_m": [0.0, 0.0, 0.0]}], **gnc}}
    with pytest.raises(ConfigError) as err:
        parse_config({"orbit": {"altitude_m": 800e3},
                      "satellites": [sat, {"name": "b", "position_m": [1.0, 0.0, 0.0]}]})
    assert str(err.value) == f"invalid configuration: {where}: {message}"


def test_synchronisation_criteria_need_a_gnc_relative_to_a_target():
    with pytest.raises(ConfigError, match="the synchronisation errors judge a GNC flying "
                       "relative to another satellite; 'a''s"):
        parse_config({"success": {"synchronisation_attitude_error_max_rad": 0.01},
                      "satellites": [{"name": "a", "gnc": {
                          "waypoints": [{"position_m": [0.0, 0.0, 0.0]}]}}]})


def test_a_transfer_too_short_for_the_thrusters_brakes_once_and_the_pd_flies_on():
    """25 m in 1 s is far beyond 2 N on 500 kg: the transfer fires one saturated period,
    brakes once it is due, and from then on the PD brings the satellite to the waypoint
    at its own speed (braking does not hold it under tolerance_mps for good)."""
    p = _leg_params(transfer_s=np.array([1.0]))
    ods, states = _fly(p, _at_rest([0.0, -100.0, 0.0]), 4000.0, dt_s=0.5)
    assert any(s.braked for s in states)
    thrust = np.max([np.abs(s.force_B_N).max() for s in states])  # it flew, saturated
    assert thrust == pytest.approx(p.thrust_max_N, rel=1e-9)
    assert np.linalg.norm(ods.position_m[0] - [0.0, -75.0, 0.0]) < p.tolerance_m


def test_a_retargeted_transfer_coasts_the_period_whose_time_left_is_half_an_orbit():
    """A transfer longer than half an orbit passes a time left of exactly π/Ω, where Φrv
    is singular out of plane (it ended such a run with an error): that period coasts, and
    the next aims again."""
    from app.sim.gnc import Reference, transfer_force_R
    from app.sim.orbital import orbit_rate

    w = orbit_rate(800e3)
    half_s = math.pi / w
    p = _leg_params(orbit_rate_radps=w, transfer_s=np.array([half_s + 10.0]))
    zero = np.zeros(3)
    ref = Reference(np.array([0.0, -75.0, 0.0]), zero, zero, np.array([1.0, 0, 0, 0]), zero)
    state = GncState(leg_start_s=0.0)
    with pytest.raises(ValueError, match="a whole number of half orbits"):
        two_impulse_transfer([0, -100, 0], zero, ref.position_m, zero, half_s, w)
    coast = transfer_force_R(p, state, _nav(t_s=10.0, p=(0.0, -100.0, 0.0)), ref,
                             half_s + 10.0)
    np.testing.assert_array_equal(coast, 0.0)
    aim = transfer_force_R(p, state, _nav(t_s=12.0, p=(0.0, -100.0, 0.0)), ref,
                           half_s + 10.0)
    assert np.all(np.isfinite(aim)) and np.linalg.norm(aim) > 0.0
