"""ODS coupling (app/sim/coupling.py): measured wrenches → ODS input, through the passivity
layer (force tank over all satellites, one torque controller per carried satellite)."""

from __future__ import annotations

import numpy as np
import pytest

from app.config import EmulatorConfig, PassivityConfig, SatelliteConfig
from app.sim.coupling import OdsCoupling
from app.sim.interaction import Bodies
from app.sim.orbital import OrbitalSimulator, omega_inertial_from_relative
from app.sim.passivity import PassivityController, TankPassivity
from app.sim.rotations import quat_to_matrix, rotvec_to_matrix, rotvec_to_quat

DT = 0.002
ZERO = np.zeros((2, 3))
MASSES = (1.0, 3.0)
R_W_R = rotvec_to_matrix([0.3, -0.6, 0.4])  # R turned in the lab: frames matter
Q_SAT = rotvec_to_quat(np.array([0.5, 0.1, -0.7]))  # attitude of both satellites in R
R_W_C = R_W_R @ quat_to_matrix(Q_SAT)


def _ods(v_R, w_rel_B) -> OrbitalSimulator:
    """Two satellites with velocities v_R (in R) and angular velocities w_rel_B (relative to
    R, body axes), both at attitude Q_SAT."""
    cfg = EmulatorConfig(satellites=[
        SatelliteConfig(name=n, mass_kg=m, attitude_wxyz=tuple(Q_SAT))
        for n, m in zip("ab", MASSES, strict=True)])
    ods = OrbitalSimulator.from_config(cfg)
    ods.y[:, 3:6] = v_R
    for i in range(2):
        ods.y[i, 10:13] = omega_inertial_from_relative(Q_SAT, w_rel_B[i],
                                                       ods.params.orbit_rate_radps)
    np.testing.assert_allclose(ods.omega_rel_radps, w_rel_B, atol=1e-15)
    return ods


def _input(c: OdsCoupling, F, T, v_v, v_p, w_v, w_p):
    """c.ods_input with satellites moving at v_v, w_v and the bodies at v_p, w_p (v in R,
    w in body axes), the lab turned by R_W_R."""
    T_W_C = np.tile(np.eye(4), (2, 1, 1))
    T_W_C[:, :3, :3] = R_W_C
    bodies = Bodies(T_W_C, np.asarray(v_p) @ R_W_R.T, np.asarray(w_p) @ R_W_C.T)
    return c.ods_input(np.asarray(F, dtype=float), np.asarray(T, dtype=float),
                       _ods(v_v, w_v), bodies, R_W_R)


def _coupling(enabled=True, idle_reset_s=0.01, tank_max_J=0.0, carried=(0, 1),
              force_scale=1.0, align_cycles=0) -> OdsCoupling:
    cfg = PassivityConfig(enabled=enabled, idle_reset_s=idle_reset_s, tank_max_J=tank_max_J)
    return OdsCoupling(cfg, DT, list(carried), MASSES, force_scale, align_cycles)


def _pc(F, v_v, v_p, E=0.0):
    """The single-port controller's closed form for one step (app/sim/passivity.py: PO, PC)."""
    E = E + DT * F @ (v_p - v_v)
    if E >= 0 or F @ v_v <= 0:
        return F, E, 0.0
    vv = v_v @ v_v
    beta = min(-E / (vv * DT), (F @ v_v) / vv)
    return F - beta * v_v, E + beta * vv * DT, beta * vv * DT


def _tank_step(F, v_v, v_p, tank, beta_max=np.inf):
    """Closed form of one tank step (module doc: tank, PC2) for two acted satellites."""
    m = np.array(MASSES)
    tank = tank + DT * np.sum(F * (v_p - v_v))
    if tank >= 0:
        return F, tank, 0.0
    v_cm = (m @ v_v) / m.sum()
    rel = v_v - v_cm
    w = float(np.sum(m * np.sum(rel * rel, axis=1)))
    d = m[:, None] * rel  # the damper's force per unit β
    no_pull = min((F[i] @ F[i]) / (d[i] @ F[i]) for i in range(2) if d[i] @ F[i] > 0)
    beta = min(-tank / (w * DT), beta_max, no_pull)
    return F - beta * d, tank + beta * w * DT, beta * w * DT


def test_without_passivity_the_measured_wrenches_pass_unchanged():
    c = _coupling(enabled=False)
    F = np.array([[2.0, -1.0, 0.5], [-2.0, 1.0, -0.5]])
    T = np.array([[0.3, 0.0, -0.2], [0.0, 0.1, 0.0]])
    # the mockups far behind their satellites: passivity control would act, but it is off
    v_v = np.array([[0.1, 0.0, 0.0], [-0.1, 0.0, 0.0]])
    f, t = _input(c, F, T, v_v, ZERO, v_v, ZERO)
    np.testing.assert_array_equal(f, F)
    np.testing.assert_array_equal(t, T)
    assert c.dissipated_J() is None


def test_a_created_energy_is_removed_by_internal_forces_only():
    """One step: the mockups lag their satellites into a contact, so the port power says the
    satellites would gain energy; the correction is a damper between them: the momentum
    they receive is the measured one, the energy removed is booked."""
    c = _coupling()
    F = np.array([[-3.0, 0.2, 0.0], [3.0, -0.2, 0.1]])  # equal and opposite, as measured
    v_v = np.array([[-0.05, 0.0, 0.0], [0.04, 0.01, 0.0]])  # moving apart: F accelerates
    v_p = np.array([[-0.01, 0.0, 0.0], [0.01, 0.0, 0.0]])   # the mockups lag behind
    f, _ = _input(c, F, ZERO, v_v, v_p, ZERO, ZERO)
    expected, tank, removed = _tank_step(F, v_v, v_p, 0.0)
    assert removed > 0 and tank == pytest.approx(0.0, abs=1e-15)
    np.testing.assert_allclose(f, expected, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(f.sum(axis=0), F.sum(axis=0), atol=1e-15)  # momentum kept
    # the energy the satellites receive is what the mockups received
    assert np.sum(f * v_v) == pytest.approx(np.sum(F * v_p), rel=1e-12)
    assert c.dissipated_J()["force"] == pytest.approx(removed, rel=1e-12)


def test_energy_the_contact_took_is_not_handed_back_beyond_the_cap():
    """Compression with the mockups ahead stores energy in the tank only up to tank_max_J."""
    c = _coupling(tank_max_J=1e-4)
    F = np.array([[-3.0, 0.0, 0.0], [3.0, 0.0, 0.0]])
    v_v = np.array([[0.05, 0.0, 0.0], [-0.05, 0.0, 0.0]])
    v_p = 0.5 * v_v  # the mockups close in slower than the satellites: the tank fills
    for _ in range(20):
        _input(c, F, ZERO, v_v, v_p, ZERO, ZERO)
    assert c.tank.tank_J == pytest.approx(1e-4)


def test_the_physical_velocity_is_the_one_of_the_measured_instant():
    """align_cycles = 2: the power of cycle k uses the mockups' velocity of cycle k − 2."""
    c = _coupling(tank_max_J=1.0, align_cycles=2)
    c.tank.tank_J = 0.5
    F = np.array([[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    v_v = np.zeros((2, 3))
    history = [np.array([[-0.1 * k, 0.0, 0.0], [0.1 * k, 0.0, 0.0]]) for k in range(1, 6)]
    tanks = []
    for v_p in history:
        _input(c, F, ZERO, v_v, v_p, ZERO, ZERO)
        tanks.append(c.tank.tank_J)
    power = [np.sum(F * v) for v in history]  # 0.2 k W
    # first three cycles: the oldest velocity kept (cycle 1's); then cycles 2 and 3's
    expected = 0.5 + DT * np.cumsum([power[0], power[0], power[0], power[1], power[2]])
    np.testing.assert_allclose(tanks, expected, rtol=1e-12)


def test_a_single_acted_satellite_has_no_partner_to_trade_with():
    c = _coupling()
    F = np.array([[2.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    v_v = np.array([[0.1, 0.0, 0.0], [0.0, 0.0, 0.0]])
    f, _ = _input(c, F, ZERO, v_v, ZERO, ZERO, ZERO)  # a debt, but nobody to balance it
    np.testing.assert_array_equal(f, F)
    assert c.dissipated_J()["force"] == 0.0


def test_the_damper_never_does_more_than_halve_the_relative_velocity():
    """With force_scale s the ODS applies s·F: β is capped at 1 / (2 s dt)."""
    s = 0.005
    c = _coupling(force_scale=s)
    F = np.array([[-100.0, 0.0, 0.0], [100.0, 0.0, 0.0]])  # strong: no pull before the cap
    v_v = np.array([[-1e-3, 0.0, 0.0], [1e-3, 0.0, 0.0]])  # slow: a huge β would be needed
    v_p = np.array([[0.5, 0.0, 0.0], [-0.5, 0.0, 0.0]])
    f, _ = _input(c, F, ZERO, v_v, v_p, ZERO, ZERO)
    expected, tank, _ = _tank_step(F, v_v, v_p, 0.0, beta_max=0.5 / (s * DT))
    np.testing.assert_allclose(f, expected, rtol=1e-12)
    assert tank < 0  # the rest of the deficit waits for the next cycles
    dv_rel = s * DT * (f[1] / MASSES[1] - f[0] / MASSES[0]) - s * DT * (
        F[1] / MASSES[1] - F[0] / MASSES[0])
    assert abs(dv_rel[0]) == pytest.approx(0.5 * (v_v[1, 0] - v_v[0, 0]), rel=1e-12)


def test_the_damper_never_turns_a_push_into_a_pull():
    """A weak push and a large deficit: β stops where the first satellite's force reaches
    zero along itself; momentum stays balanced and the rest of the deficit is carried."""
    c = _coupling()
    F = np.array([[-0.2, 0.0, 0.0], [0.2, 0.0, 0.0]])
    v_v = np.array([[-0.1, 0.0, 0.0], [0.1, 0.0, 0.0]])  # moving apart fast
    v_p = np.array([[0.1, 0.0, 0.0], [-0.1, 0.0, 0.0]])  # the mockups still pressing in
    f, _ = _input(c, F, ZERO, v_v, v_p, ZERO, ZERO)
    expected, tank, _ = _tank_step(F, v_v, v_p, 0.0)
    np.testing.assert_allclose(f, expected, rtol=1e-12, atol=1e-15)
    assert np.all(np.einsum("ij,ij->i", f, F) >= -1e-15)  # nobody pulled
    assert min(np.linalg.norm(f, axis=1)) == pytest.approx(0.0, abs=1e-12)  # one push gone
    np.testing.assert_allclose(f.sum(axis=0), F.sum(axis=0), atol=1e-15)
    assert c.tank.tank_J == pytest.approx(tank) and tank < 0.0  # carried


def test_at_force_scale_zero_the_tank_has_no_damper_limit():
    """force_scale = 0: the ODS ignores forces, so no β is too strong (no division by 0)."""
    c = _coupling(force_scale=0.0)
    assert c.tank.beta_max == np.inf
    F = np.array([[-3.0, 0.2, 0.0], [3.0, -0.2, 0.1]])
    v_v = np.array([[-0.05, 0.0, 0.0], [0.04, 0.01, 0.0]])
    v_p = np.array([[-0.01, 0.0, 0.0], [0.01, 0.0, 0.0]])
    f, _ = _input(c, F, ZERO, v_v, v_p, ZERO, ZERO)
    np.testing.assert_allclose(f, _tank_step(F, v_v, v_p, 0.0)[0], rtol=1e-12, atol=1e-15)
    assert _coupling(enabled=False, force_scale=0.0).tank is None  # off: nothing built


@pytest.mark.parametrize(("idle_cycles", "refilled"), [(4, False), (5, True)])
def test_an_idle_port_refills_its_tank(idle_cycles, refilled):
    """idle_reset_s = 10 ms = 5 cycles of zero force: the tank is back at tank_max_J."""
    c = _coupling(idle_reset_s=0.01, tank_max_J=2e-4)
    F = np.array([[-3.0, 0.0, 0.0], [3.0, 0.0, 0.0]])
    v_v = np.array([[0.05, 0.0, 0.0], [-0.05, 0.0, 0.0]])
    _input(c, F, ZERO, v_v, 2.0 * v_v, ZERO, ZERO)  # the mockups took more: tank drops
    assert c.tank.tank_J < 2e-4
    for _ in range(idle_cycles):
        _input(c, np.zeros((2, 3)), ZERO, v_v, v_v, ZERO, ZERO)
    assert (c.tank.tank_J == 2e-4) == refilled


def test_the_torque_port_of_each_carried_satellite_is_its_own():
    w_v = np.array([[0.0, 0.0, 0.2], [0.0, 0.0, 0.0]])  # satellite 0 turns, body axes
    w_p = np.array([[0.0, 0.0, 0.05], [0.0, 0.0, 0.0]])  # its mockup lags
    T = np.array([[0.1, 0.0, 0.4], [0.0, 0.0, 0.0]])
    c = _coupling(carried=(0,))
    f, t = _input(c, np.zeros((2, 3)), T, ZERO, ZERO, w_v, w_p)
    expected, _, removed = _pc(T[0], w_v[0], w_p[0])
    assert removed > 0
    np.testing.assert_allclose(t[0], expected, rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(t[1], 0.0)
    assert c.dissipated_J()["torque"] == {0: pytest.approx(removed, rel=1e-12)}


def test_cycles_without_force_or_torque_take_the_short_way_to_the_same_state():
    """OdsCoupling.ods_input skips the tank's step (TankPassivity.idle) when no force
    acts and tests the torques on plain floats: through cycles with forces only, torques
    only, both and neither, its outputs and its tank's and torque ports' state are those
    of the parts called in full (tank.step every cycle, each PassivityController.step)."""
    rng = np.random.default_rng(12)
    coupling = _coupling(tank_max_J=0.002, align_cycles=1, idle_reset_s=0.004)
    tank = TankPassivity(DT, np.array(MASSES), 1.0, 1, 0.004, 0.002)
    ports = [PassivityController(DT, 0.004) for _ in range(2)]
    kinds = set()
    for k in range(240):
        pushes, twists = (k // 6) % 2 == 1, (k // 5) % 3 == 2
        kinds.add((pushes, twists))
        F = rng.normal(0, 5, (2, 3)) * pushes
        T = rng.normal(0, 0.5, (2, 3)) * twists
        v_v, v_p = rng.normal(0, 0.2, (2, 3)), rng.normal(0, 0.2, (2, 3))
        w_v, w_p = rng.normal(0, 0.5, (2, 3)), rng.normal(0, 0.5, (2, 3))
        force_R, torque_B = _input(coupling, F, T, v_v, v_p, w_v, w_p)
        ods = _ods(v_v, w_v)
        expected_F = tank.step(F, ods.velocity_mps, np.asarray(v_p) @ R_W_R.T, R_W_R)
        w_p_W = np.asarray(w_p) @ R_W_C.T  # as the coupling sees it: in the lab
        expected_T = np.array([ports[s].step(T[s], ods.omega_rel_radps[s], R_W_C.T @ w_p_W[s])
                               for s in range(2)])
        assert force_R.tobytes() == expected_F.tobytes(), k
        assert torque_B.tobytes() == expected_T.tobytes(), k
        assert coupling.tank.tank_J == tank.tank_J, k
        assert [p.energy_J for p in coupling.torque_pcs.values()] == \
            [p.energy_J for p in ports], k
    assert kinds == {(False, False), (False, True), (True, False), (True, True)}
    assert tank.dissipated_J > 0.0 and sum(p.dissipated_J for p in ports) > 0.0
