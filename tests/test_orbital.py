"""ODS physics against closed forms and invariants (paper Eqs. 1-7)."""

import numpy as np
import pytest

from app.config import EmulatorConfig, SatelliteConfig
from app.sim.orbital import (
    OdsParams,
    OrbitalSimulator,
    along_track_drift_rate,
    box_inertia,
    cw_course_m,
    cw_state_transition,
    derivative,
    omega_inertial_from_relative,
    omega_relative_into,
    orbit_rate,
    rk4_step,
)
from app.sim.rotations import quat_to_matrix, rotvec_to_quat
from tests import oracle

W800 = orbit_rate(800e3)


def make_sim(gravity_gradient=True, **sat) -> OrbitalSimulator:
    cfg = EmulatorConfig(
        orbit={"gravity_gradient": gravity_gradient, "torque_scale": 1.0},
        satellites=[SatelliteConfig(name="s", **sat)],
    )
    return OrbitalSimulator.from_config(cfg)


def run(sim, seconds, dt, force=(0, 0, 0), torque=(0, 0, 0)):
    f = np.array([force], dtype=float)
    t = np.array([torque], dtype=float)
    for _ in range(int(round(seconds / dt))):
        sim.step(f, t, dt)
    return sim


def test_orbit_rate_800km_matches_design_numbers():
    assert W800 == pytest.approx(1.0381e-3, rel=1e-4)
    assert 2 * np.pi / W800 == pytest.approx(6052, abs=2)


def test_box_inertia_of_the_4u_cubesat():
    np.testing.assert_allclose(
        box_inertia(1.0, (0.2, 0.2, 0.1)), [0.05 / 12, 0.05 / 12, 0.08 / 12], rtol=1e-12
    )


def test_rk4_matches_closed_form_cw_over_600s():
    x0 = np.array([0.3, -0.2, 0.1, 1e-3, -2e-3, 5e-4])
    sim = make_sim(position_m=x0[:3], velocity_mps=x0[3:])
    run(sim, 600.0, 0.002)
    expected = cw_state_transition(W800, 600.0) @ x0
    assert np.max(np.abs(sim.position_m[0] - expected[:3])) < 1e-9
    assert np.max(np.abs(sim.velocity_mps[0] - expected[3:])) < 1e-12


def test_state_transition_is_a_flow():
    a = cw_state_transition(W800, 1234.0) @ cw_state_transition(W800, 567.0)
    np.testing.assert_allclose(a, cw_state_transition(W800, 1801.0), atol=1e-9)


def test_drift_free_orbit_is_a_bounded_ellipse():
    x0 = 0.2
    sim = make_sim(position_m=(x0, 0, 0), velocity_mps=(0, -2 * W800 * x0, 0))
    period = 2 * np.pi / W800
    ys = []
    dt = 1.0
    for _ in range(3):
        for _ in range(int(period / dt)):
            sim.step(np.zeros((1, 3)), np.zeros((1, 3)), dt)
            ys.append(sim.position_m[0].copy())
    ys = np.array(ys)
    # 2:1 ellipse centred on the along-track axis: |y| <= 2 x0, |x| <= x0, no drift
    assert np.max(np.abs(ys[:, 0])) == pytest.approx(x0, rel=1e-3)
    assert np.max(np.abs(ys[:, 1])) == pytest.approx(2 * x0, rel=1e-3)
    assert abs(np.mean(ys[:, 1])) < 0.01 * x0


def test_other_along_track_velocity_drifts_at_the_closed_form_rate():
    x0, vy0 = 0.2, 1e-4
    sim = make_sim(position_m=(x0, 0, 0), velocity_mps=(0, vy0, 0))
    period = 2 * np.pi / W800
    run(sim, period, 0.5)
    rate = along_track_drift_rate(W800, x0, vy0)
    # after one whole orbit the periodic part has returned: y = rate * T
    assert sim.position_m[0, 1] == pytest.approx(rate * sim.t_s, rel=1e-4)
    assert rate != pytest.approx(0.0)


def test_force_pulse_changes_velocity_by_impulse_over_mass():
    sim = make_sim(mass_kg=2.5)
    force = np.array([[3.0, -1.0, 2.0]])
    dt = 0.002
    for _ in range(50):  # 0.1 s pulse
        sim.step(force, np.zeros((1, 3)), dt)
    dv = sim.velocity_mps[0]
    # CW terms add only O(2 W dv t) ~ 1e-5 over 0.1 s
    coriolis = 2 * W800 * np.abs(force[0] * 0.1 / 2.5).max() * 0.1
    np.testing.assert_allclose(dv, force[0] * 0.1 / 2.5, atol=coriolis)


def test_force_scale_multiplies_the_pushes():
    cfg = EmulatorConfig(orbit={"force_scale": 0.01})
    sim = OrbitalSimulator.from_config(cfg)
    for _ in range(100):
        sim.step(np.array([[10.0, 0, 0]]), np.zeros((1, 3)), 0.002)
    assert sim.velocity_mps[0, 0] == pytest.approx(10.0 * 0.2 * 0.01, rel=1e-4)


def test_inertially_fixed_body_turns_at_minus_omega_in_R():
    sim = make_sim(gravity_gradient=False, omega_radps=(0, 0, -W800))
    np.testing.assert_allclose(sim.omega_inertial_radps[0], 0.0, atol=1e-15)
    t = 1500.0
    run(sim, t, 0.5)
    expected = rotvec_to_quat(np.array([0, 0, -W800 * t]))
    assert abs(np.dot(sim.attitude_wxyz[0], expected)) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(sim.omega_rel_radps[0], [0, 0, -W800], atol=1e-15)


def test_body_at_rest_in_R_with_principal_axes_along_R_stays_at_rest():
    sim = make_sim(gravity_gradient=True, inertia_kgm2=(0.02, 0.03, 0.04))
    run(sim, 3000.0, 0.5)
    assert abs(sim.attitude_wxyz[0, 0]) == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(sim.omega_rel_radps[0], 0.0, atol=1e-15)


def test_small_pitch_offset_librates_at_the_gravity_gradient_frequency():
    Ix, Iy, Iz = 0.02, 0.035, 0.04
    theta0 = 0.01
    sim = make_sim(inertia_kgm2=(Ix, Iy, Iz), attitude_wxyz=rotvec_to_quat([0, 0, theta0]))
    expected = W800 * np.sqrt(3 * (Iy - Ix) / Iz)
    dt = 2.0
    angles, times = [], []
    for k in range(int(3 * 2 * np.pi / expected / dt)):
        sim.step(np.zeros((1, 3)), np.zeros((1, 3)), dt)
        R = quat_to_matrix(sim.attitude_wxyz[0])
        angles.append(np.arctan2(R[1, 0], R[0, 0]))
        times.append((k + 1) * dt)
    angles = np.array(angles)
    # measure the period from the zero crossings going down
    s = np.sign(angles)
    crossings = np.nonzero((s[:-1] > 0) & (s[1:] <= 0))[0]
    t_cross = [
        times[i] + dt * angles[i] / (angles[i] - angles[i + 1]) for i in crossings
    ]
    measured = 2 * np.pi / np.mean(np.diff(t_cross))
    assert len(t_cross) >= 2
    assert measured == pytest.approx(expected, rel=0.01)
    assert np.max(np.abs(angles)) == pytest.approx(theta0, rel=0.02)


def _inertial_momentum(sim):
    """Angular momentum and kinetic energy in inertial space (R turns at W about z)."""
    W = sim.params.orbit_rate_radps
    I = sim.params.inertia_kgm2[0]
    w = sim.omega_inertial_radps[0]
    R_R_B = quat_to_matrix(sim.attitude_wxyz[0])
    a = W * sim.t_s
    R_I_R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    return R_I_R @ R_R_B @ (I * w), 0.5 * np.dot(I * w, w)


def test_torque_free_rotation_conserves_energy_and_momentum_and_unit_quaternion():
    sim = make_sim(
        gravity_gradient=False,
        inertia_kgm2=(0.02, 0.03, 0.045),
        attitude_wxyz=rotvec_to_quat([0.3, -0.5, 0.2]),
        omega_radps=(0.3, 0.05, -0.2),
    )
    L0, E0 = _inertial_momentum(sim)
    zero = np.zeros((1, 3))
    max_norm_err = 0.0
    for _ in range(100_000):
        sim.step(zero, zero, 0.002)
        max_norm_err = max(max_norm_err, abs(np.linalg.norm(sim.attitude_wxyz[0]) - 1.0))
    L1, E1 = _inertial_momentum(sim)
    assert abs(E1 - E0) / E0 < 1e-9
    assert np.linalg.norm(L1 - L0) / np.linalg.norm(L0) < 1e-9
    assert max_norm_err < 1e-12


def test_torque_scale_divides_torque():
    params = OdsParams(
        orbit_rate_radps=W800,
        mass_kg=np.array([1.0]),
        inertia_kgm2=np.array([[0.1, 0.1, 0.1]]),
        gravity_gradient=False,
        torque_scale=1 / 2000,
    )
    y = np.zeros((1, 13))
    y[0, 6] = 1.0
    y[0, 12] = W800
    y1 = rk4_step(params, y, np.zeros((1, 3)), np.array([[2000.0, 0, 0]]), 0.01)
    assert y1[0, 10] == pytest.approx(1.0 / 0.1 * 0.01, rel=1e-6)


def test_relative_angular_velocity_equals_the_closed_form():
    """omega_rel_radps (its kernel) against ``ω − Ω R_R_Bᵀ ẑ`` (tests/oracle.py, Pinocchio's
    quaternion) on three tumbling satellites over a long run; 1e-15 on rates of ~0.5 rad/s
    (same formula, a different rotation-matrix route: measured ≤ 1e-16)."""
    cfg = EmulatorConfig(
        orbit={"gravity_gradient": True, "torque_scale": 1.0},
        satellites=[
            SatelliteConfig(name="a", inertia_kgm2=(0.02, 0.03, 0.04),
                            attitude_wxyz=rotvec_to_quat([0.4, -1.2, 2.5]),
                            omega_radps=(0.3, -0.2, 0.5)),
            SatelliteConfig(name="b", attitude_wxyz=rotvec_to_quat([3.0, 0.1, 0.0]),
                            omega_radps=(0.0, 0.0, 0.0), position_m=(0.5, 0, 0)),
            SatelliteConfig(name="c", attitude_wxyz=rotvec_to_quat([0.0, -1.0, 1.0]),
                            omega_radps=(-0.4, 0.1, 0.05), position_m=(0, 0.5, 0)),
        ],
    )
    sim = OrbitalSimulator.from_config(cfg)
    W = sim.params.orbit_rate_radps
    # at the start it is what the configuration asked for
    np.testing.assert_allclose(sim.omega_rel_radps, [s.omega_radps for s in cfg.satellites],
                               rtol=0, atol=1e-15)
    torque = np.array([[0.0, 2.0, -1.0], [0.1, 0.0, 0.0], [0.0, 0.0, -0.3]])
    out = np.empty(9)
    for _ in range(300):
        sim.step(np.zeros((3, 3)), torque, 0.01)
        rel = sim.omega_rel_radps
        for i in range(3):
            want = oracle.omega_relative(sim.attitude_wxyz[i], sim.omega_inertial_radps[i], W)
            np.testing.assert_allclose(rel[i], want, rtol=0, atol=1e-15)
            omega_relative_into(sim.y, i, W, out, 3 * i)
        np.testing.assert_array_equal(out.reshape(3, 3), rel)
    assert np.abs(rel).max() > 0.1  # really tumbling


def test_inertial_and_relative_angular_velocity_convert_both_ways():
    rng = np.random.default_rng(0)
    q = np.array([rotvec_to_quat(v) for v in rng.normal(size=(50, 3))])
    rel = rng.normal(scale=0.3, size=(50, 3))
    omega = omega_inertial_from_relative(q, rel, W800)
    for i in range(50):
        np.testing.assert_allclose(oracle.omega_relative(q[i], omega[i], W800), rel[i],
                                   rtol=0, atol=1e-15)
    # at rest in R (identity attitude): inertially turning with R, at Ω about ẑ
    np.testing.assert_allclose(omega_inertial_from_relative([1.0, 0, 0, 0], [0, 0, 0], W800),
                               [[0.0, 0.0, W800]], rtol=0, atol=1e-18)


def test_cw_course_is_the_state_transition_at_every_time():
    """cw_course_m gives, for each time at once, the positions Phi(t) [p; v] gives."""
    p0, v0 = np.array([0.3, -0.2, 0.1]), np.array([0.01, -0.02, 0.005])
    t = np.array([0.0, 0.5, 600.0, 5000.0])
    course = cw_course_m(W800, p0, v0, t)
    for k, t_s in enumerate(t):
        np.testing.assert_allclose(course[k], (cw_state_transition(W800, t_s)
                                               @ np.concatenate([p0, v0]))[:3], atol=1e-9)


def test_a_replaced_or_copied_params_steps_with_its_own_values():
    """The kernels' arguments are kept on an OdsParams once made: a params made by
    dataclasses.replace (another mass) steps with its own mass, a deep copy as the
    original; equality still compares the fields only."""
    import copy
    import dataclasses

    p = OdsParams(0.0011, np.array([10.0, 20.0]), np.array([[1.0, 2.0, 3.0]] * 2))
    y = np.zeros((2, 13))
    y[:, 6] = 1.0
    force = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    torque = np.array([[0.0, 0.0, 0.1], [0.1, 0.0, 0.0]])
    first = rk4_step(p, y, force, torque, 0.002)
    heavier = dataclasses.replace(p, mass_kg=np.array([40.0, 20.0]))
    moved = rk4_step(heavier, y, force, torque, 0.002)
    np.testing.assert_allclose(moved[0, 3], first[0, 3] / 4.0, rtol=1e-12)
    assert moved[1].tobytes() == first[1].tobytes()
    assert rk4_step(copy.deepcopy(p), y, force, torque, 0.002).tobytes() == first.tobytes()
    assert rk4_step(p, y, force, torque, 0.002).tobytes() == first.tobytes()
    assert p == OdsParams(0.0011, p.mass_kg, p.inertia_kgm2)  # fields only, as before


def _rk4_in_numpy(params: OdsParams, y, force, torque, dt) -> np.ndarray:
    """The RK4 step as NumPy array expressions, in the order the kernel documents
    (``y + 0.5 dt k1``, ..., ``y + dt/6 (k1 + 2 k2 + 2 k3 + k4)``, the quaternion's norm
    a sum from 0 in order): the oracle the compiled step must equal to the last bit."""
    k1 = derivative(params, y, force, torque)
    k2 = derivative(params, y + 0.5 * dt * k1, force, torque)
    k3 = derivative(params, y + 0.5 * dt * k2, force, torque)
    k4 = derivative(params, y + dt * k3, force, torque)
    out = y + (dt / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    for row in out:
        q = row[6:10]
        sq = 0.0
        for v in q:
            sq += v * v
        row[6:10] = q * ((-1.0 if q[0] < 0.0 else 1.0) / np.sqrt(sq))
    return out


def test_the_compiled_steps_are_the_array_expressions_to_the_last_bit():
    """rk4_step and advance_and_ahead (the step, then the predictions from its state, in
    one call) against the NumPy RK4 on random states of one to four satellites, gravity
    gradient on and off, quaternions of either sign."""
    rng = np.random.default_rng(5)
    for _ in range(200):
        n = int(rng.integers(1, 5))
        p = OdsParams(float(rng.uniform(1e-4, 0.05)), rng.uniform(0.5, 50.0, n),
                      rng.uniform(0.01, 5.0, (n, 3)), bool(rng.integers(2)),
                      float(rng.uniform(0.001, 2.0)), float(rng.uniform(1e-4, 1.0)))
        y = rng.standard_normal((n, 13)) * rng.choice([1e-3, 1.0, 30.0])
        y[:, 6:10] /= np.linalg.norm(y[:, 6:10], axis=1)[:, None]
        force, torque = rng.normal(0, 20, (n, 3)), rng.normal(0, 2, (n, 3))
        dt, leads = 0.002, sorted(rng.uniform(0.001, 0.05, int(rng.integers(1, 3))))
        step = rk4_step(p, y, force, torque, dt)
        assert step.tobytes() == _rk4_in_numpy(p, y, force, torque, dt).tobytes()
        ods = OrbitalSimulator(p, y.copy())
        y_next, from_next = ods.advance_and_ahead(force, torque, dt, leads)
        assert y_next.tobytes() == step.tobytes()
        assert ods.y.tobytes() == y.tobytes()  # nothing committed
        for lead, state in zip(leads, from_next, strict=True):
            assert state.tobytes() == _rk4_in_numpy(p, step, force, torque, lead).tobytes()
