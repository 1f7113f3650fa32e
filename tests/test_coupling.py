"""ODS coupling (app/sim/coupling.py): measured wrench → ODS input, through passivity control."""

from __future__ import annotations

import numpy as np
import pytest

from app.config import EmulatorConfig, PassivityConfig, SatelliteConfig
from app.sim.coupling import OdsCoupling
from app.sim.ft_sensor import ProcessedWrench
from app.sim.orbital import OrbitalSimulator, omega_inertial_from_relative
from app.sim.rotations import quat_to_matrix, rotvec_to_matrix, rotvec_to_quat

DT = 0.002
R_W_R = rotvec_to_matrix([0.3, -0.6, 0.4])  # R turned in the lab: frames matter
Q_SAT = rotvec_to_quat(np.array([0.5, 0.1, -0.7]))  # attitude of both satellites in R
R_W_C = R_W_R @ quat_to_matrix(Q_SAT)
ZERO = np.zeros(3)


def _ods(v_R=(0.0, 0.0, 0.0), w_rel_B=(0.0, 0.0, 0.0)) -> OrbitalSimulator:
    """Two satellites; both with velocity v_R (in R) and angular velocity w_rel_B (relative
    to R, body axes)."""
    cfg = EmulatorConfig(satellites=[
        SatelliteConfig(name=n, velocity_mps=tuple(v_R), omega_radps=tuple(w_rel_B),
                        attitude_wxyz=tuple(Q_SAT))
        for n in ("a", "b")])
    ods = OrbitalSimulator.from_config(cfg)
    np.testing.assert_allclose(ods.omega_rel_radps, [w_rel_B] * 2, atol=1e-15)
    return ods


def _measured(force_R=ZERO, torque_B=ZERO) -> ProcessedWrench:
    f, t = np.array(force_R, dtype=float), np.array(torque_B, dtype=float)
    return ProcessedWrench(force_R_N=f, torque_B_Nm=t, wrench_S=np.concatenate([f, t]))


def _coupling(enabled=True, idle_reset_s=0.01, satellites=(0, 1)) -> OdsCoupling:
    return OdsCoupling(PassivityConfig(enabled=enabled, idle_reset_s=idle_reset_s), DT,
                       list(satellites))


def _pc(F, v_v, v_p, E=0.0):
    """The passivity controller's closed form for one step (app/sim/passivity.py: PO, PC)."""
    E = E + DT * F @ (v_p - v_v)
    if E >= 0 or F @ v_v <= 0:
        return F, E, 0.0
    vv = v_v @ v_v
    beta = min(-E / (vv * DT), (F @ v_v) / vv)
    return F - beta * v_v, E + beta * vv * DT, beta * vv * DT


def test_without_passivity_the_measured_wrench_passes_unchanged():
    ods = _ods(v_R=(0.1, 0.0, 0.0), w_rel_B=(0.0, 0.2, 0.0))
    c = _coupling(enabled=False)
    measured = _measured((2.0, -1.0, 0.5), (0.3, 0.0, -0.2))
    # the mockup far behind the satellite: passivity control would act, but it is off
    f, t = c.ods_input(0, measured, ods, ZERO, ZERO, R_W_C, R_W_R)
    np.testing.assert_array_equal(f, measured.force_R_N)
    np.testing.assert_array_equal(t, measured.torque_B_Nm)
    assert c.dissipated_J() is None


def test_an_arm_without_controllers_passes_unchanged():
    ods = _ods(v_R=(0.1, 0.0, 0.0))
    c = _coupling(satellites=(1,))  # only satellite 1's arm has controllers
    f, _ = c.ods_input(0, _measured((2.0, 0.0, 0.0)), ods, ZERO, ZERO, R_W_C, R_W_R)
    np.testing.assert_array_equal(f, [2.0, 0.0, 0.0])
    assert set(c.dissipated_J()) == {1}


def test_an_accelerating_force_is_trimmed_when_the_port_has_created_energy():
    v_v = np.array([0.1, 0.05, 0.0])  # virtual satellite, in R
    v_p = np.array([0.02, 0.01, 0.0])  # the mockup lags behind it, in R
    F = np.array([2.0, 0.5, -0.3])  # accelerates the satellite: F · v_v > 0
    ods = _ods(v_R=v_v)
    c = _coupling()
    f, t = c.ods_input(1, _measured(F), ods, R_W_R @ v_p, ZERO, R_W_C, R_W_R)
    expected, _, removed = _pc(F, v_v, v_p)
    assert removed > 0
    np.testing.assert_allclose(f, expected, rtol=1e-12, atol=1e-15)
    assert np.linalg.norm(f) <= np.linalg.norm(F)  # trimmed ...
    assert f @ v_v >= 0.0  # ... never reversed into a brake
    np.testing.assert_allclose(np.cross(F - f, v_v), 0.0, atol=1e-15)  # along v_v only
    np.testing.assert_array_equal(t, ZERO)
    d = c.dissipated_J()
    assert d[1]["force"] == pytest.approx(removed, rel=1e-12)
    assert d[1]["torque"] == 0.0
    assert d[0] == {"force": 0.0, "torque": 0.0}  # the other satellite's port is apart


def test_the_mockup_velocity_is_taken_from_the_lab_into_R():
    """The same physical situation with the lab velocity not rotated would create no debt."""
    v_v = np.array([0.1, 0.0, 0.0])
    F = np.array([1.0, 0.0, 0.0])
    ods = _ods(v_R=v_v)
    c = _coupling()
    v_W = R_W_R @ v_v  # the mockup moves exactly with the satellite: nothing to trim
    f, _ = c.ods_input(0, _measured(F), ods, v_W, ZERO, R_W_C, R_W_R)
    np.testing.assert_array_equal(f, F)
    assert c.dissipated_J()[0]["force"] == 0.0


def test_a_decelerating_force_passes():
    v_v = np.array([0.1, 0.0, 0.0])
    ods = _ods(v_R=v_v)
    c = _coupling()
    for _ in range(20):  # even while the observer's balance goes ever more negative
        F = np.array([-3.0, 1.0, 0.0])  # F · v_v < 0
        f, _ = c.ods_input(0, _measured(F), ods, R_W_R @ [0.3, 0.0, 0.0], ZERO, R_W_C,
                           R_W_R)
        np.testing.assert_array_equal(f, F)
    assert c.dissipated_J()[0] == {"force": 0.0, "torque": 0.0}


def test_the_torque_port_uses_body_axes_and_books_separately():
    w_v = np.array([0.0, 0.0, 0.2])  # satellite's angular velocity relative to R, body axes
    w_p = np.array([0.0, 0.0, 0.05])  # the mockup's, body axes: it lags
    T = np.array([0.1, 0.0, 0.4])
    ods = _ods(w_rel_B=w_v)
    c = _coupling()
    f, t = c.ods_input(0, _measured(ZERO, T), ods, ZERO, R_W_C @ w_p, R_W_C, R_W_R)
    expected, _, removed = _pc(T, w_v, w_p)
    assert removed > 0
    np.testing.assert_allclose(t, expected, rtol=1e-12, atol=1e-15)
    assert np.linalg.norm(t) <= np.linalg.norm(T) and t @ w_v >= 0.0
    np.testing.assert_array_equal(f, ZERO)
    d = c.dissipated_J()
    assert d[0]["torque"] == pytest.approx(removed, rel=1e-12) and d[0]["force"] == 0.0


def test_dissipated_energy_accumulates_per_satellite_and_port():
    v_v, v_p = np.array([0.1, 0.0, 0.0]), np.array([0.0, 0.0, 0.0])
    w_v, w_p = np.array([0.2, 0.0, 0.0]), np.array([0.0, 0.0, 0.0])
    ods = _ods(v_R=v_v, w_rel_B=w_v)
    assert np.allclose(
        omega_inertial_from_relative(Q_SAT, w_v, ods.params.orbit_rate_radps), ods.y[0, 10:])
    c = _coupling()
    F, T = np.array([1.0, 0.0, 0.0]), np.array([0.05, 0.0, 0.0])
    E_f = E_t = total_f = total_t = 0.0
    for _ in range(10):
        f, t = c.ods_input(0, _measured(F, T), ods, R_W_R @ v_p, R_W_C @ w_p, R_W_C, R_W_R)
        ef, E_f, rf = _pc(F, v_v, v_p, E_f)
        et, E_t, rt = _pc(T, w_v, w_p, E_t)
        total_f, total_t = total_f + rf, total_t + rt
        np.testing.assert_allclose(f, ef, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(t, et, rtol=1e-12, atol=1e-15)
        c.ods_input(1, _measured(F), ods, R_W_R @ v_v, ZERO, R_W_C, R_W_R)  # no lag on 1
    d = c.dissipated_J()
    assert d[0]["force"] == pytest.approx(total_f, rel=1e-12) and total_f > 0
    assert d[0]["torque"] == pytest.approx(total_t, rel=1e-12) and total_t > 0
    assert d[1] == {"force": 0.0, "torque": 0.0}


@pytest.mark.parametrize(("idle_cycles", "forgotten"), [(4, False), (5, True)])
def test_an_idle_port_forgets_its_debt(idle_cycles, forgotten):
    """idle_reset_s = 10 ms = 5 cycles of zero measured force reset the balance."""
    v_v = np.array([0.1, 0.0, 0.0])
    ods = _ods(v_R=v_v)
    c = _coupling(idle_reset_s=0.01)
    # a braking force while the mockup runs ahead: passes, leaves a debt of -1.2 mJ
    c.ods_input(0, _measured((-3.0, 0.0, 0.0)), ods, R_W_R @ [0.3, 0.0, 0.0], ZERO, R_W_C,
                R_W_R)
    for _ in range(idle_cycles):
        c.ods_input(0, _measured(), ods, R_W_R @ [0.3, 0.0, 0.0], ZERO, R_W_C, R_W_R)
    # then a push with the mockup moving with the satellite (no new energy either way)
    F = np.array([1.0, 0.0, 0.0])
    f, _ = c.ods_input(0, _measured(F), ods, R_W_R @ v_v, ZERO, R_W_C, R_W_R)
    if forgotten:
        np.testing.assert_array_equal(f, F)
    else:  # the debt (1.2 mJ) exceeds what one step can remove: the push is cancelled
        np.testing.assert_allclose(f, 0.0, atol=1e-15)
        assert c.dissipated_J()[0]["force"] == pytest.approx(DT * F @ v_v)
