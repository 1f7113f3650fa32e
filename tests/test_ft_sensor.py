"""Virtual F/T sensor and wrench processing (DESIGN.md: simulated UR10e F/T, the loop)."""

from __future__ import annotations

import numpy as np
import pytest

from app.config import SensorConfig, WrenchProcessingConfig
from app.sim.ft_sensor import (
    VirtualFTSensor,
    WrenchProcessor,
    apply_deadband,
    point_force_wrench_W,
    sensor_load_S,
)
from app.sim.rotations import make_transform, rotvec_to_matrix

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
# Defaults except a 10 Hz filter: at the default 20 Hz the filtered noise (σ ≈ 0.6 N per
# axis) crosses the 2.5 N deadband about once a second; at 10 Hz it is a 6-sigma event.
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
    """Noise-free physics: f = F_ext + m (g − a), moment about S includes r_FC × f."""
    f_W, a_W = np.array([3.0, 0.0, -4.0]), np.array([0.5, 1.0, 2.0])
    load = sensor_load_S(np.concatenate([f_W, np.zeros(3)]), T_W_C, T_W_F, 2.0, G_W, a_W)
    f_tot_W = f_W + 2.0 * (G_W - a_W)
    r_W = T_W_C[:3, 3] - T_W_F[:3, 3]
    np.testing.assert_allclose(T_W_F[:3, :3] @ load[:3], f_tot_W, atol=1e-12)
    np.testing.assert_allclose(T_W_F[:3, :3] @ load[3:], np.cross(r_W, f_tot_W), atol=1e-12)


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


def test_deadband_hard_and_soft():
    v = np.array([3.0, 0.0, 4.0])  # |v| = 5
    assert not apply_deadband(v, 5.0, "hard").any()
    np.testing.assert_array_equal(apply_deadband(v, 4.9, "hard"), v)
    np.testing.assert_allclose(apply_deadband(v, 4.0, "soft"), v / 5.0)
    assert not apply_deadband(v, 6.0, "soft").any()


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


# --- the compiled chain (app.sim.ft_kernel) equals the Python reference ---------------------


@pytest.mark.parametrize(
    ("sensor_cfg", "proc_cfg"),
    [
        (DEFAULT_SENSOR, WrenchProcessingConfig()),
        (SensorConfig(delay_cycles=0), WrenchProcessingConfig(deadband_mode="soft")),
        (SensorConfig(delay_cycles=3), QUIET),
        (NOISELESS, WrenchProcessingConfig(payload_compensation=False, lowpass_hz=200.0)),
    ],
)
def test_compiled_chain_equals_python_reference(sensor_cfg, proc_cfg):
    """Same readings (same noise draws from the same seed) and same processed wrenches
    over many cycles with saturated channels, deadband edges and a wrapping delay ring."""
    chains = []
    for compiled in (False, True):
        sensor = _sensor(sensor_cfg, seed=21)
        proc = _calibrated(sensor, proc_cfg)
        sensor.use_kernel = proc.use_kernel = compiled
        chains.append((sensor, proc))
    rng = np.random.default_rng(5)
    edges = 0
    for k in range(1500):
        T_F = make_transform(rotvec_to_matrix(rng.normal(size=3)), rng.normal(size=3))
        T_C = T_F @ make_transform(rotvec_to_matrix(0.2 * rng.normal(size=3)), COM_F_M)
        wrench = rng.normal(size=6) * ([80.0] * 3 + [9.0] * 3) * (k % 3)  # some saturate
        accel = None if k % 5 == 0 and not proc_cfg.inertial_compensation else rng.normal(size=3)
        outs = []
        for sensor, proc in chains:
            raw = sensor.measure(wrench, T_C, T_F, accel)
            outs.append((raw, proc.process(raw, T_F, T_C, R_W_R, accel)))
        (raw_a, out_a), (raw_b, out_b) = outs
        np.testing.assert_allclose(raw_b, raw_a, rtol=0, atol=1e-12)
        for name in ("force_R_N", "torque_B_Nm", "wrench_S"):
            np.testing.assert_allclose(getattr(out_b, name), getattr(out_a, name), rtol=0,
                                       atol=1e-12)
        edges += int(np.any(np.abs(raw_a) == sensor_cfg.range_force_N))
    assert edges > 50  # the saturation really happened
    np.testing.assert_allclose(chains[1][1]._state_S, chains[0][1]._state_S, rtol=0, atol=1e-12)


def test_compiled_deadband_edges_equal_reference():
    """Filtered force right at, just below and just above the thresholds (hard and soft)."""
    for mode in ("hard", "soft"):
        cfg = WrenchProcessingConfig(deadband_mode=mode, lowpass_hz=1e9,  # alpha = 1
                                     inertial_compensation=False, payload_compensation=False)
        procs = [WrenchProcessor(cfg, RATE_HZ, G_W) for _ in range(2)]
        procs[0].use_kernel = False
        for scale in (1.0 - 1e-12, 1.0, 1.0 + 1e-12, 0.0, 3.0):
            f = np.array([3.0, 0.0, 4.0]) / 5.0 * cfg.deadband_force_N * scale
            t = np.array([0.0, 0.6, 0.8]) * cfg.deadband_torque_Nm * scale
            raw = np.concatenate([f, t])
            for p in procs:
                p.reset()  # with alpha = 1 the filtered wrench is then exactly raw
            a, b = (p.process(raw, T_W_F, T_W_C, R_W_R) for p in procs)
            np.testing.assert_array_equal(b.wrench_S == 0.0, a.wrench_S == 0.0)
            np.testing.assert_allclose(b.wrench_S, a.wrench_S, rtol=0, atol=1e-12)
            np.testing.assert_allclose(b.force_R_N, a.force_R_N, rtol=0, atol=1e-12)
            np.testing.assert_allclose(b.torque_B_Nm, a.torque_B_Nm, rtol=0, atol=1e-12)
