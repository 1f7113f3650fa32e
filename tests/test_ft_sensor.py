"""Virtual F/T sensor and wrench processing (DESIGN.md: simulated UR10e F/T, the loop)."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from app.config import SensorConfig, WrenchProcessingConfig
from app.sim.ft_sensor import (
    NORMALS_BLOCK,
    Calibration,
    VirtualFTSensor,
    WrenchProcessor,
    _deadband,
    lowpass_alpha,
    point_force_wrench_W,
    process_step,
    sensor_step,
)
from app.sim.rotations import make_transform, rotvec_to_matrix
from tests import oracle

RATE_HZ = 500.0
G_W = np.array([0.0, 0.0, -9.81])
MASS_KG = 1.0
COM_F_M = np.array([0.0, 0.0, 0.07])
R_F_C = rotvec_to_matrix([0.0, 0.0, 0.6])  # mockup axes turned against the flange's
T_W_F = make_transform(rotvec_to_matrix([0.4, -2.2, 0.7]), [0.4, -0.3, 1.1])
T_W_C = T_W_F @ make_transform(R_F_C, COM_F_M)
R_W_R = rotvec_to_matrix([0.0, 0.0, 1.1]) @ rotvec_to_matrix([0.3, 0.0, 0.0])
DEFAULT_SENSOR = SensorConfig()
NOISELESS = SensorConfig(noise_force_N=0.0, noise_torque_Nm=0.0)
# the arm holds still in these tests: nothing inertial to compensate
QUIET = WrenchProcessingConfig(inertial_compensation=False)


def _sensor(config: SensorConfig = DEFAULT_SENSOR, seed: int = 0) -> VirtualFTSensor:
    return VirtualFTSensor(config, MASS_KG, G_W, np.random.default_rng(seed))


def _calibrated(sensor: VirtualFTSensor, config=QUIET, **kw) -> WrenchProcessor:
    """A processor calibrated from 1 s of readings at rest with no contact."""
    proc = WrenchProcessor(config, RATE_HZ, G_W, **kw)
    rest = [sensor.measure(np.zeros(6), T_W_C, T_W_F) for _ in range(500)]
    proc.calibrate(np.array(rest), T_W_F[:3, :3], mass_kg=MASS_KG, com_F_m=COM_F_M)
    return proc


def test_static_arm_without_contact_gives_exactly_zero():
    sensor = _sensor(seed=3)
    proc = _calibrated(sensor)
    raw_force = []
    for _ in range(1000):  # 2 s at 500 Hz
        raw = sensor.measure(np.zeros(6), T_W_C, T_W_F)
        raw_force.append(np.linalg.norm(raw[:3]))
        out = proc.process(raw, T_W_F, T_W_C, R_W_R)
        assert not out.force_R_N.any() and not out.torque_B_Nm.any() and not out.wrench_S.any()
    # the raw reading did carry the ~9.8 N weight: the chain removed it
    assert 5.0 < np.mean(raw_force) < 15.0


def test_constant_push_recovered_in_R_with_its_direction():
    sensor = _sensor(seed=7)
    proc = _calibrated(sensor)
    push_W = 20.0 * np.array([0.6, -0.48, 0.64])
    wrench = point_force_wrench_W(push_W, T_W_C[:3, 3], T_W_C[:3, 3])  # through the COM
    expected_R = R_W_R.T @ push_W
    outs = [
        proc.process(sensor.measure(wrench, T_W_C, T_W_F), T_W_F, T_W_C, R_W_R)
        for _ in range(1000)
    ]
    for out in outs[250:]:  # after 0.5 s of settling
        assert np.linalg.norm(out.force_R_N - expected_R) < 5.5  # data-sheet accuracy
        assert np.linalg.norm(out.torque_B_Nm) < 0.5  # no moment at C
    mean_R = np.mean([o.force_R_N for o in outs[250:]], axis=0)
    assert mean_R @ expected_R / (np.linalg.norm(mean_R) * 20.0) > 0.999
    assert np.linalg.norm(mean_R - expected_R) < 0.5


def test_off_centre_push_gives_r_cross_f_about_com_in_body_axes():
    sensor = _sensor(NOISELESS)
    proc = _calibrated(sensor)
    r_W = np.array([0.08, -0.05, 0.03])
    f_W = np.array([-12.0, 20.0, 5.0])
    wrench = point_force_wrench_W(f_W, T_W_C[:3, 3] + r_W, T_W_C[:3, 3])
    for _ in range(500):
        out = proc.process(sensor.measure(wrench, T_W_C, T_W_F), T_W_F, T_W_C, R_W_R)
    expected_B = T_W_C[:3, :3].T @ np.array(
        [r_W[1] * f_W[2] - r_W[2] * f_W[1],
         r_W[2] * f_W[0] - r_W[0] * f_W[2],
         r_W[0] * f_W[1] - r_W[1] * f_W[0]]
    )
    np.testing.assert_allclose(out.torque_B_Nm, expected_B, atol=1e-9)
    np.testing.assert_allclose(out.force_R_N, R_W_R.T @ f_W, atol=1e-9)


def test_raw_reading_is_load_on_sensor_about_its_origin():
    """Noise-free physics: f = F_ext + m (g − a), moment about S includes r_FC × f, in S."""
    clean = SensorConfig(noise_force_N=0.0, noise_torque_Nm=0.0, bias_force_N=(0, 0, 0),
                         bias_torque_Nm=(0, 0, 0), delay_cycles=0)
    sensor = VirtualFTSensor(clean, 2.0, G_W, np.random.default_rng(0))
    f_W, t_W = np.array([3.0, 0.0, -4.0]), np.array([0.2, -0.1, 0.3])
    a_W = np.array([0.5, 1.0, 2.0])
    load = sensor.measure(np.concatenate([f_W, t_W]), T_W_C, T_W_F, a_W)
    f_tot_W = f_W + 2.0 * (G_W - a_W)
    r_W = T_W_C[:3, 3] - T_W_F[:3, 3]
    np.testing.assert_allclose(T_W_F[:3, :3] @ load[:3], f_tot_W, rtol=0, atol=1e-12)
    np.testing.assert_allclose(T_W_F[:3, :3] @ load[3:], t_W + np.cross(r_W, f_tot_W),
                               rtol=0, atol=1e-12)
    at_rest = sensor.measure(np.zeros(6), T_W_C, T_W_F)  # no acceleration given: at rest
    np.testing.assert_allclose(T_W_F[:3, :3] @ at_rest[:3], 2.0 * G_W, rtol=0, atol=1e-12)


def test_point_force_wrench_is_force_and_moment_about_the_com():
    f, p, c = np.array([1.0, -2.0, 3.0]), np.array([0.4, 0.1, -0.2]), np.array([0.1, 0.3, 0.2])
    w = point_force_wrench_W(f, p, c)
    np.testing.assert_array_equal(w[:3], f)
    np.testing.assert_allclose(w[3:], np.cross(p - c, f), rtol=0, atol=1e-15)
    assert not point_force_wrench_W(f, c, c)[3:].any()


def test_lowpass_alpha_is_the_exact_discretisation():
    """The sampled step response of 1/(1 + s/ω_c) is 1 − exp(−ω_c t); y += α (1 − y) gives
    1 − (1 − α)^n, the same at t = n / rate."""
    fc, rate = 30.0, 500.0
    alpha = lowpass_alpha(fc, rate)
    y = 0.0
    for n in range(1, 200):
        y += alpha * (1.0 - y)
        assert y == pytest.approx(1.0 - np.exp(-2 * np.pi * fc * n / rate), abs=1e-14)
    assert lowpass_alpha(1e9, rate) == 1.0


def test_inertial_compensation_removes_m_a():
    a_W = np.array([0.0, 3.0, -1.0])
    f_W = np.array([0.0, 0.0, 10.0])
    wrench = np.concatenate([f_W, np.zeros(3)])
    results = {}
    for inertial in (False, True):
        sensor = _sensor(NOISELESS)
        cfg = WrenchProcessingConfig(inertial_compensation=inertial, deadband_force_N=0.0)
        proc = _calibrated(sensor, cfg)
        for _ in range(500):
            raw = sensor.measure(wrench, T_W_C, T_W_F, a_W)
            out = proc.process(raw, T_W_F, T_W_C, np.eye(3), a_W)
        results[inertial] = out.force_R_N
    np.testing.assert_allclose(results[True], f_W, atol=1e-9)
    np.testing.assert_allclose(results[False], f_W - MASS_KG * a_W, atol=1e-9)


def test_delay_shifts_signal_by_exactly_delay_cycles():
    cfg = SensorConfig(delay_cycles=3)
    delayed, direct = _sensor(cfg, seed=11), _sensor(cfg.model_copy(update={"delay_cycles": 0}), 11)
    t = np.arange(50) / RATE_HZ
    out_d, out_0 = [], []
    for tk in t:
        wrench = np.array([30.0 * np.sin(20.0 * tk), 5.0 * tk, 0.0, 0.0, 0.0, 0.0])
        out_d.append(delayed.measure(wrench, T_W_C, T_W_F))
        out_0.append(direct.measure(wrench, T_W_C, T_W_F))
    out_d, out_0 = np.array(out_d), np.array(out_0)
    np.testing.assert_array_equal(out_d[3:], out_0[:-3])
    np.testing.assert_array_equal(out_d[:3], np.repeat(out_0[:1], 3, axis=0))
    assert not np.array_equal(out_d[3:], out_0[3:])


def test_saturation_at_range():
    sensor = _sensor(SensorConfig())
    T_W_F0 = make_transform(np.eye(3), [0.0, 0.0, 1.0])
    T_W_C0 = T_W_F0 @ make_transform(np.eye(3), COM_F_M)
    wrench = np.array([300.0, -250.0, 0.0, 40.0, 0.0, -0.5])
    r = sensor.measure(wrench, T_W_C0, T_W_F0)
    assert r[0] == 100.0 and r[1] == -100.0 and r[3] == 10.0
    assert abs(r[2]) < 100.0 and abs(r[5]) < 10.0  # unsaturated channels untouched


def test_same_seed_same_readings_and_different_seed_differs():
    def run(seed):
        s = _sensor(seed=seed)
        return np.array([s.measure(np.zeros(6), T_W_C, T_W_F) for _ in range(100)])

    np.testing.assert_array_equal(run(5), run(5))
    assert not np.array_equal(run(5), run(6))


def test_the_noise_drawn_in_blocks_is_the_stream_of_six_draws_a_call():
    """The sensor draws its normals NORMALS_BLOCK rows at a time; call after call they
    are bit for bit ``rng.standard_normal(6)`` of a twin generator, over several blocks,
    through a reset, in a deep copy taken mid-block (as copy_state takes one: copy and
    original go on alike and apart), and after a new generator is assigned mid-block (a
    replicate's reseeding); the readings carry exactly these draws."""
    sensor, ref = _sensor(seed=11), np.random.default_rng(11)

    def same(s, r, calls):
        for _ in range(calls):
            np.testing.assert_array_equal(s.next_normals(), r.standard_normal(6))

    same(sensor, ref, NORMALS_BLOCK + 100)
    twin, twin_ref = copy.deepcopy(sensor), copy.deepcopy(ref)
    sensor.reset()
    same(sensor, ref, 2 * NORMALS_BLOCK)
    same(twin, twin_ref, NORMALS_BLOCK + 7)
    same(sensor, ref, 3)
    sensor.rng, ref = np.random.default_rng(12), np.random.default_rng(12)
    same(sensor, ref, NORMALS_BLOCK + 1)
    # the readings: the noiseless reading plus σ times the draws, to the last bit
    cfg = SensorConfig(delay_cycles=0)
    noisy = VirtualFTSensor(cfg, MASS_KG, G_W, np.random.default_rng(3))
    quiet = VirtualFTSensor(cfg.model_copy(update={"noise_force_N": 0.0,
                                                   "noise_torque_Nm": 0.0}),
                            MASS_KG, G_W, np.random.default_rng(3))
    ref = np.random.default_rng(3)
    for k in range(NORMALS_BLOCK + 20):
        if k == 300:
            noisy.reset()
            quiet.reset()
        expected = quiet.measure(np.zeros(6), T_W_C, T_W_F) + noisy.noise_std_S * \
            ref.standard_normal(6)
        np.testing.assert_array_equal(noisy.measure(np.zeros(6), T_W_C, T_W_F), expected)


def test_calibration_estimates_bias_mass_and_com_from_several_poses():
    cfg = SensorConfig(bias_force_N=(2.0, -3.0, 1.0), bias_torque_Nm=(0.1, 0.2, -0.05))
    sensor = VirtualFTSensor(cfg, 1.7, G_W, np.random.default_rng(1))
    com_F = np.array([0.01, -0.02, 0.09])
    readings, rotations = [], []
    for rv in ([0.0, 0.0, 0.0], [1.5, 0.0, 0.0], [0.0, -1.5, 0.0], [2.5, 1.0, 0.3]):
        T_F = make_transform(rotvec_to_matrix(rv), [0.3, 0.0, 1.0])
        T_C = T_F @ make_transform(np.eye(3), com_F)
        for _ in range(500):
            readings.append(sensor.measure(np.zeros(6), T_C, T_F))
            rotations.append(T_F[:3, :3])
    proc = WrenchProcessor(WrenchProcessingConfig(), RATE_HZ, G_W)
    cal = proc.calibrate(np.array(readings), np.array(rotations))
    assert cal.mass_kg == pytest.approx(1.7, abs=0.02)
    np.testing.assert_allclose(cal.com_F_m, com_F, atol=0.005)
    np.testing.assert_allclose(cal.bias_S[:3], cfg.bias_force_N, atol=0.15)
    np.testing.assert_allclose(cal.bias_S[3:], cfg.bias_torque_Nm, atol=0.02)
    with pytest.raises(ValueError, match="orientations"):
        proc.calibrate(np.array(readings[:500]), np.array(rotations[:500]))


@pytest.mark.parametrize("force_N", [3.6, 3.99, 4.5, 20.0])
def test_a_push_through_the_com_gives_no_torque_on_either_side_of_the_force_deadband(force_N):
    """The moment is shifted to the COM by the whole force before any deadband: a push
    through the COM just under the 4 N force deadband gives neither force nor torque (the
    lever arm's r × F, 0.26 N·m here, is not handed on as a torque); above it, the force
    alone."""
    sensor = _sensor(NOISELESS)
    proc = _calibrated(sensor, WrenchProcessingConfig(inertial_compensation=False,
                                                      deadband_force_N=4.0,
                                                      deadband_torque_Nm=0.25))
    direction_W = T_W_F[:3, :3] @ np.array([1.0, 0.0, 0.0])  # across the 0.07 m lever arm
    wrench = point_force_wrench_W(force_N * direction_W, T_W_C[:3, 3], T_W_C[:3, 3])
    lever_Nm = np.linalg.norm(np.cross(COM_F_M, [force_N, 0.0, 0.0]))
    for _ in range(500):
        out = proc.process(sensor.measure(wrench, T_W_C, T_W_F), T_W_F, T_W_C, R_W_R)
    assert not out.torque_B_Nm.any()
    if force_N < 4.0:
        assert lever_Nm > 0.25  # what a shift by the passed force alone would have given
        assert not out.force_R_N.any()
    else:
        np.testing.assert_allclose(out.force_R_N, R_W_R.T @ (force_N * direction_W),
                                   atol=1e-9)


def test_deadband_hard_and_soft():
    """On the magnitude: 0 at or below the threshold; above it 'hard' passes the vector
    unchanged and 'soft' takes the threshold off its magnitude."""
    def db(v, threshold, soft):
        out = np.array(v, dtype=float)
        _deadband(out, threshold, soft)
        return out

    v = np.array([3.0, 0.0, 4.0])  # |v| = 5 exactly
    assert not db(v, 5.0, False).any() and not db(v, 5.0, True).any()  # at the edge: 0
    np.testing.assert_array_equal(db(v, 4.9, False), v)
    np.testing.assert_allclose(db(v, 4.0, True), v / 5.0, rtol=0, atol=1e-15)
    assert not db(v, 6.0, True).any() and not db(v, 6.0, False).any()
    above = np.array([0.0, 0.0, np.nextafter(5.0, 6.0)])  # one ulp over the edge
    np.testing.assert_array_equal(db(above, 5.0, False), above)
    assert 0.0 < db(above, 5.0, True)[2] < 1e-15
    assert not db(-above, 5.0, False)[:2].any() and db(-above, 5.0, False)[2] == -above[2]


def test_inertial_compensation_removes_the_load_of_an_accelerating_mockup():
    """The arm accelerates the mockup at a_W while a 15 N push acts: F_ext is recovered."""
    sensor = _sensor(NOISELESS)
    proc = _calibrated(sensor, WrenchProcessingConfig(inertial_compensation=True, lowpass_hz=1e3))
    plain = _calibrated(sensor, WrenchProcessingConfig(inertial_compensation=False, lowpass_hz=1e3))
    accel_W = np.array([3.0, -2.0, 1.0])
    push_W = np.array([0.0, 15.0, 0.0])
    wrench = point_force_wrench_W(push_W, T_W_C[:3, 3], T_W_C[:3, 3])
    for _ in range(50):
        raw = sensor.measure(wrench, T_W_C, T_W_F, accel_W)
        out = proc.process(raw, T_W_F, T_W_C, R_W_R, accel_W)
        out_plain = plain.process(raw, T_W_F, T_W_C, R_W_R, accel_W)
    np.testing.assert_allclose(out.force_R_N, R_W_R.T @ push_W, atol=1e-6)
    # without the stage, the m a load stays in the reading
    np.testing.assert_allclose(
        out_plain.force_R_N, R_W_R.T @ (push_W - MASS_KG * accel_W), atol=1e-6
    )




# --- the compiled sensor and chain against the NumPy reference (tests/oracle.py) --------------
#
# Same formulas; the kernels spell the rotations and cross products out term by term, so
# results differ by rounding only: 1e-12 on forces up to the 100 N range (measured ≤ 6e-14).

ATOL = 1e-12


def _twins(sensor_cfg, proc_cfg, seed=21):
    """(app sensor, app processor, reference sensor, reference processor), both sensors on
    generators of the same seed and calibrated (app calibration) from 1 s at rest."""
    sensor = _sensor(sensor_cfg, seed)
    ref_sensor = oracle.RefSensor(sensor_cfg, MASS_KG, G_W, np.random.default_rng(seed))
    rest = []
    for _ in range(500):
        rest.append(sensor.measure(np.zeros(6), T_W_C, T_W_F))
        np.testing.assert_allclose(rest[-1], ref_sensor.measure(np.zeros(6), T_W_C, T_W_F),
                                   rtol=0, atol=ATOL)
    proc = WrenchProcessor(proc_cfg, RATE_HZ, G_W, sensor_cfg.delay_cycles)
    proc.calibrate(np.array(rest), T_W_F[:3, :3], mass_kg=MASS_KG, com_F_m=COM_F_M)
    alpha = 1.0 - np.exp(-2.0 * np.pi * proc_cfg.lowpass_hz / RATE_HZ)
    assert proc.alpha == pytest.approx(alpha, rel=1e-15)
    ref_proc = oracle.RefProcessor(proc_cfg, alpha, G_W, proc.calibration,
                                   sensor_cfg.delay_cycles)
    return sensor, proc, ref_sensor, ref_proc


CHAIN_CASES = {
    "defaults": (DEFAULT_SENSOR, WrenchProcessingConfig()),
    "no delay, soft deadband": (SensorConfig(delay_cycles=0),
                                WrenchProcessingConfig(deadband_mode="soft")),
    "delay 3, no inertial stage": (SensorConfig(delay_cycles=3), QUIET),
    "noiseless, no payload stage": (NOISELESS, WrenchProcessingConfig(
        payload_compensation=False, lowpass_hz=200.0)),
    "no compensation, no deadband": (SensorConfig(delay_cycles=2), WrenchProcessingConfig(
        payload_compensation=False, inertial_compensation=False, deadband_force_N=0.0,
        deadband_torque_Nm=0.0)),
}


@pytest.mark.parametrize("case", list(CHAIN_CASES))
def test_sensor_and_chain_equal_the_reference(case):
    """Same readings (the same noise draws from the same seed) and the same processed
    wrenches over 1500 cycles of random poses, wrenches and accelerations: saturated
    channels, both sides of the deadbands, the delay ring wrapping round, and a reset of
    sensor and filter half-way."""
    sensor_cfg, proc_cfg = CHAIN_CASES[case]
    sensor, proc, ref_sensor, ref_proc = _twins(sensor_cfg, proc_cfg)
    rng = np.random.default_rng(5)
    saturated = deadbanded = passed = 0
    for k in range(1500):
        if k == 750:
            sensor.reset()
            ref_sensor.reset()
            proc.reset()
            ref_proc.reset()
        T_F = make_transform(rotvec_to_matrix(rng.normal(size=3)), rng.normal(size=3))
        T_C = T_F @ make_transform(rotvec_to_matrix(0.2 * rng.normal(size=3)), COM_F_M)
        # blocks of 50 cycles: no contact (the deadband's side), pushes, saturating pushes
        scale = (k // 50) % 3
        wrench = rng.normal(size=6) * ([80.0] * 3 + [9.0] * 3) * scale
        accel = None if k % 5 == 0 and not proc_cfg.inertial_compensation else rng.normal(size=3)
        raw = sensor.measure(wrench, T_C, T_F, accel)
        np.testing.assert_allclose(raw, ref_sensor.measure(wrench, T_C, T_F, accel),
                                   rtol=0, atol=ATOL)
        gate = k % 7 == 0  # now and then the contact gate lifts the deadbands
        out = proc.process(raw, T_F, T_C, R_W_R, accel, gate)
        force_R, torque_B, wrench_S = ref_proc.process(raw, T_F, T_C, R_W_R, accel, gate)
        np.testing.assert_allclose(out.force_R_N, force_R, rtol=0, atol=ATOL)
        np.testing.assert_allclose(out.torque_B_Nm, torque_B, rtol=0, atol=ATOL)
        np.testing.assert_allclose(out.wrench_S, wrench_S, rtol=0, atol=ATOL)
        saturated += int(np.any(np.abs(raw) == ref_sensor.range))
        deadbanded += int(not out.wrench_S[:3].any())
        passed += int(out.wrench_S[:3].any())
    assert saturated > 50  # the saturation really happened
    assert passed > 100
    if proc_cfg.deadband_force_N > 0 and proc_cfg.payload_compensation:
        assert deadbanded > 100


def test_sensor_step_kernel_fills_the_delay_ring():
    """sensor_step alone: ``fill`` writes every row, then row ``head`` takes the new
    reading and the oldest row comes out."""
    cfg = NOISELESS.model_copy(update={"delay_cycles": 2})
    ref = oracle.RefSensor(cfg, MASS_KG, G_W, np.random.default_rng(0))
    ring, out = np.zeros((3, 6)), np.empty(6)
    args = (MASS_KG, G_W, np.zeros(3), np.zeros(6), ref.bias, ref.std, ref.range)
    for k in range(10):
        wrench = np.array([float(k), 0.0, 0.0, 0.0, 0.0, 0.0])
        sensor_step(wrench, T_W_C, T_W_F, *args, ring, k % 3, k == 0, out)
        np.testing.assert_allclose(out, ref.measure(wrench, T_W_C, T_W_F), rtol=0, atol=ATOL)
        if k == 0:
            assert np.all(ring == ring[0])


@pytest.mark.parametrize("mode", ["hard", "soft"])
def test_deadband_edges_equal_the_reference(mode):
    """Filtered force and torque exactly at, one ulp below and above, well below and well
    above the thresholds: same zeros and same values as the reference, through the whole
    chain (alpha = 1: the filtered wrench is the reading itself; the COM at the sensor, so
    that the torque about it is the reading's) and the bare kernel."""
    cfg = WrenchProcessingConfig(deadband_mode=mode, lowpass_hz=1e9,  # alpha = 1
                                 deadband_force_N=5.0, deadband_torque_Nm=0.625,
                                 inertial_compensation=False, payload_compensation=False)
    proc = WrenchProcessor(cfg, RATE_HZ, G_W)
    assert proc.alpha == 1.0
    ref = oracle.RefProcessor(cfg, 1.0, G_W, proc.calibration)
    up, down = np.nextafter(1.0, 2.0), np.nextafter(1.0, 0.0)
    forces = [np.array([3.0, 0.0, 4.0]), np.array([0.0, 0.0, 5.0 * up]),
              np.array([0.0, -5.0 * down, 0.0]), np.array([0.3, 0.0, 0.4]),
              np.array([30.0, 0.0, -40.0])]
    torques = [np.array([0.375, 0.0, 0.5]), np.array([0.0, 0.0, -0.625 * up]),
               np.array([0.625 * down, 0.0, 0.0]), np.zeros(3), np.array([3.0, 4.0, 0.0])]
    expect_zero = [True, False, True, True, False]
    for f, t, zero in zip(forces, torques, expect_zero, strict=True):
        proc.reset()
        ref.reset()
        raw = np.concatenate([f, t])
        out = proc.process(raw, T_W_F, T_W_F, R_W_R)
        force_R, torque_B, wrench_S = ref.process(raw, T_W_F, T_W_F, R_W_R)
        assert (not out.wrench_S[:3].any()) == zero == (not wrench_S[:3].any())
        assert (not out.wrench_S[3:].any()) == zero == (not wrench_S[3:].any())
        np.testing.assert_array_equal(out.wrench_S == 0.0, wrench_S == 0.0)
        np.testing.assert_allclose(out.wrench_S, wrench_S, rtol=0, atol=ATOL)
        np.testing.assert_allclose(out.force_R_N, force_R, rtol=0, atol=ATOL)
        np.testing.assert_allclose(out.torque_B_Nm, torque_B, rtol=0, atol=ATOL)
        if mode == "hard" and not zero:
            np.testing.assert_array_equal(out.wrench_S, raw)  # real pushes pass unchanged
        for v, threshold in ((f, 5.0), (t, 0.625)):
            got = v.copy()
            _deadband(got, threshold, mode == "soft")
            np.testing.assert_allclose(got, oracle.deadband(v, threshold, mode), rtol=0,
                                       atol=ATOL)


def test_process_step_kernel_equals_the_reference():
    """process_step called directly with random calibrations, accelerations and stages."""
    rng = np.random.default_rng(9)
    out = np.empty(12)
    for k in range(1000):
        payload, inertial, soft = bool(k & 1), bool(k & 2), bool(k & 4)
        cfg = WrenchProcessingConfig(payload_compensation=payload,
                                     inertial_compensation=inertial,
                                     deadband_mode="soft" if soft else "hard",
                                     deadband_force_N=rng.uniform(0, 5),
                                     deadband_torque_Nm=rng.uniform(0, 0.3))
        cal = Calibration(rng.normal(size=6), rng.uniform(0.5, 3.0),
                          rng.normal(scale=0.1, size=3))
        alpha = rng.uniform(0.01, 1.0)
        state = rng.normal(size=6)
        ref = oracle.RefProcessor(cfg, alpha, G_W, cal)
        ref.state = state.copy()
        T_F = make_transform(rotvec_to_matrix(rng.normal(size=3)), rng.normal(size=3))
        T_C = T_F @ make_transform(rotvec_to_matrix(0.3 * rng.normal(size=3)),
                                   rng.normal(scale=0.1, size=3))
        R_W_R_k = rotvec_to_matrix(rng.normal(size=3))
        raw, accel = rng.normal(size=6) * [20, 20, 20, 2, 2, 2], rng.normal(size=3)
        process_step(raw, T_F, T_C, R_W_R_k, G_W, payload, accel, inertial, cal.bias_S,
                     cal.mass_kg, cal.com_F_m, alpha, state, cfg.deadband_force_N,
                     cfg.deadband_torque_Nm, soft, out)
        force_R, torque_B, wrench_S = ref.process(raw, T_F, T_C, R_W_R_k, accel)
        np.testing.assert_allclose(out[:3], force_R, rtol=0, atol=ATOL)
        np.testing.assert_allclose(out[3:6], torque_B, rtol=0, atol=ATOL)
        np.testing.assert_allclose(out[6:], wrench_S, rtol=0, atol=ATOL)
        np.testing.assert_allclose(state, ref.state, rtol=0, atol=ATOL)


def test_inertial_compensation_without_an_acceleration_is_refused():
    proc = WrenchProcessor(WrenchProcessingConfig(inertial_compensation=True), RATE_HZ, G_W)
    with pytest.raises(ValueError, match="acceleration"):
        proc.process(np.zeros(6), T_W_F, T_W_C, R_W_R)


def test_the_calibration_measures_the_noise_the_gate_open_chain_passes():
    """The rest readings' scatter is the sensor's noise (σ 1.67 N per axis: within the
    sampling error of 500 readings); the covariance of the filtered force it predicts
    (α/(2 − α) of it, rotated) is what the chain puts out with the gate open, at the
    30 Hz filter and with the filter bypassed in contact."""
    sigma = DEFAULT_SENSOR.noise_force_N
    for contact_hz in (None, 1000.0):
        cfg = WrenchProcessingConfig(inertial_compensation=False, contact_lowpass_hz=contact_hz)
        sensor = _sensor(seed=5)
        proc = _calibrated(sensor, cfg)
        cov = proc.calibration.force_noise_cov_S
        np.testing.assert_allclose(np.diag(cov), sigma**2, rtol=4 * np.sqrt(2 / 500))
        predicted_R = proc.filtered_force_cov(R_W_R.T @ T_W_F[:3, :3])
        out = np.array([proc.process(sensor.measure(np.zeros(6), T_W_C, T_W_F), T_W_F, T_W_C,
                                     R_W_R, gate_open=True).force_R_N for _ in range(20000)])
        measured = np.cov(out[100:].T)
        np.testing.assert_allclose(np.diag(measured), np.diag(predicted_R), rtol=0.1)


def test_the_filtered_force_covariance_is_matmul_s_to_the_last_bit():
    """filtered_force_cov rotates the kept covariance with ndarray.dot (less overhead than
    `@`, the same BLAS calls): on rotations such as the loop hands it (R_W_R.T times a
    pose's rotation), R K Rᵀ to the last bit of the `@` form."""
    proc = _calibrated(_sensor(seed=5), WrenchProcessingConfig(inertial_compensation=False))
    K = proc.calibration.force_noise_cov_S * (proc.contact_alpha / (2.0 - proc.contact_alpha))
    rng = np.random.default_rng(17)
    for _ in range(2000):
        T = rng.standard_normal((4, 4)) * 10.0 ** rng.uniform(-2, 2)
        R_X_S = R_W_R.T.dot(T[:3, :3])
        assert proc.filtered_force_cov(R_X_S).tobytes() == (R_X_S @ K @ R_X_S.T).tobytes()


def test_the_deadbands_are_six_sigma_of_the_filtered_noise_the_calibration_measured():
    """The calibration raises each deadband to 6 times the largest principal standard
    deviation of the noise the chain passes at rest (the force; the torque about the COM,
    sensor torque noise and the force noise's lever arm): checked against that spread
    measured on the chain's own output at rest, deadbands lifted, over 20,000 cycles
    (the sd of correlated samples known to about 2 %: within 6 %)."""
    T_W_F = make_transform(np.eye(3), [0.3, 0.1, 1.2])
    T_W_C = T_W_F @ make_transform(np.eye(3), COM_F_M)
    sensor = _sensor(DEFAULT_SENSOR, seed=7)
    rest = np.array([sensor.measure(np.zeros(6), T_W_C, T_W_F) for _ in range(1000)])
    proc = WrenchProcessor(WrenchProcessingConfig(), RATE_HZ, G_W, DEFAULT_SENSOR.delay_cycles)
    proc.calibrate(rest, T_W_F[:3, :3], mass_kg=MASS_KG, com_F_m=COM_F_M)
    out = np.array([proc.process(sensor.measure(np.zeros(6), T_W_C, T_W_F), T_W_F, T_W_C,
                                 np.eye(3), np.zeros(3), gate_open=True).wrench_S
                    for _ in range(20_000)])[50:]
    # the gate lifts the deadbands and filters at lowpass_hz (no contact_lowpass_hz)
    sd_f = np.sqrt(np.linalg.eigvalsh(np.cov(out[:, :3].T))[-1])
    sd_t = np.sqrt(np.linalg.eigvalsh(np.cov(out[:, 3:].T))[-1])
    assert proc.deadband_force_N == pytest.approx(6.0 * sd_f, rel=0.06)
    assert proc.deadband_torque_Nm == pytest.approx(6.0 * sd_t, rel=0.06)
    assert proc.deadband_force_N > 4.0 and proc.deadband_torque_Nm > 0.25  # raised
    proc = WrenchProcessor(WrenchProcessingConfig(deadband_noise_sigmas=0.0), RATE_HZ, G_W)
    proc.calibrate(rest, T_W_F[:3, :3], mass_kg=MASS_KG, com_F_m=COM_F_M)
    assert (proc.deadband_force_N, proc.deadband_torque_Nm) == (4.0, 0.25)


def test_a_calibration_is_changed_whole_never_in_place():
    """The chain keeps its calibration's arrays read-only (the compiled path reads a packed
    copy, so an in-place change would reach only the stages): changing one in place is
    refused; a new Calibration is what the packed buffer follows; one of the wrong shape
    is refused and changes nothing."""
    proc = _calibrated(_sensor(NOISELESS))
    cal = proc.calibration
    packed = proc.constants.copy()
    with pytest.raises(ValueError, match="read-only"):
        proc.calibration.bias_S[:] += 5.0
    with pytest.raises(ValueError, match="read-only"):
        proc.calibration.com_F_m[0] = 0.1
    with pytest.raises(ValueError, match=r"expected shape \(3,\), got shape \(2,\)"):
        proc.calibration = Calibration(np.zeros(6), 1.0, np.zeros(2))
    assert proc.calibration is cal and np.array_equal(proc.constants, packed)
    proc.calibration = Calibration(cal.bias_S + 1.0, 2.0, cal.com_F_m)
    assert np.array_equal(proc.constants[5:11], cal.bias_S + 1.0)
    assert proc.constants[11] == 2.0
