"""The flying start (app/sim/run_up.py): the run-up's closed form, and the arms carrying
their satellites at the initial velocity from the first cycle."""

from __future__ import annotations

import numpy as np
import pytest

from app.config import merge_overrides
from app.scenarios import load_scenario
from app.sim.loop import Emulator
from app.sim.orbital import POS, QUAT, VEL
from app.sim.rotations import quat_mul, quat_to_rotvec, rotvec_to_quat
from app.sim.run_up import relative_rates, run_up_state, runs_up


def _y0() -> np.ndarray:
    y = np.zeros((2, 13))
    y[:, QUAT] = [[1.0, 0, 0, 0], rotvec_to_quat([0.1, -0.2, 0.3])]
    y[0, POS], y[0, VEL] = [0.3, -0.1, 0.8], [0.08, 0.0, -0.02]
    return y


def test_the_run_up_starts_at_rest_and_reaches_the_initial_pose_and_velocity():
    """S(x) = x³ − x⁴/2: at τ = −T the pose v0·T/2 back at rest; at τ = 0 the initial pose
    and velocity; the rate in between is the derivative of the pose (finite difference)
    and never exceeds v0; the acceleration peaks at 1.5·|v0|/T."""
    y0, T = _y0(), 1.2
    omega = np.array([[0.0, 0.0, 0.05], [0.02, 0.0, 0.0]])
    start, end = run_up_state(y0, omega, T, -T), run_up_state(y0, omega, T, 0.0)
    np.testing.assert_allclose(start[:, POS], y0[:, POS] - 0.5 * T * y0[:, VEL], atol=1e-15)
    np.testing.assert_allclose(start[:, VEL], 0.0, atol=1e-15)
    np.testing.assert_allclose(end, y0, atol=1e-14)
    angle = quat_to_rotvec(start[0, QUAT])  # q0 is the identity: the turn itself
    np.testing.assert_allclose(angle, -0.5 * T * omega[0], atol=1e-12)
    tau = np.linspace(-T, 0.0, 601)
    p = np.array([run_up_state(y0, omega, T, t)[0, POS] for t in tau])
    v = np.array([run_up_state(y0, omega, T, t)[0, VEL] for t in tau])
    np.testing.assert_allclose(np.gradient(p, tau, axis=0), v, atol=2e-6)
    assert np.all(np.abs(v) <= np.abs(y0[0, VEL]) + 1e-15)
    accel = np.abs(np.gradient(v[:, 0], tau))
    assert accel.max() == pytest.approx(1.5 * 0.08 / T, rel=1e-3)
    assert accel[0] < 1e-3 and accel[-1] < 1e-3  # smooth at both ends


def test_the_relative_rate_is_read_from_two_states_and_a_body_at_rest_needs_no_run_up():
    y0 = _y0()
    np.testing.assert_allclose(relative_rates(y0, y0, 0.002), 0.0, atol=1e-12)
    moved = y0.copy()
    moved[1, QUAT] = quat_mul(y0[1, QUAT], rotvec_to_quat([0.0, 0.3 * 0.002, 0.0]))
    np.testing.assert_allclose(relative_rates(y0, moved, 0.002)[1], [0.0, 0.3, 0.0],
                               atol=1e-9)
    rest = y0.copy()
    rest[:, VEL] = 0.0
    assert not runs_up(rest, np.zeros((2, 3)))
    assert runs_up(rest, np.array([[0, 0, 0], [0, 0, 1e-6]]))


@pytest.mark.parametrize("run_up_s", [0.0, 1.0])
def test_the_collision_s_mockups_move_with_their_satellites_from_the_first_cycle(run_up_s):
    """hil collision, satellites at ±0.08 m/s: with the run-up (default 1 s) every
    mockup's velocity equals its satellite's within 2 % from the first cycle (no jolt at
    t = 0); started at rest (run_up_s = 0) it begins at 0 and overshoots past 0.12 m/s."""
    cfg = merge_overrides(load_scenario("collision"),
                          {"loop": {"run_up_s": run_up_s, "seed": 0}})
    em = Emulator(cfg)
    em.prepare()
    for _ in range(60):
        em.step()
    rows, cols = em.telemetry.rows(), em.columns
    for k in (1, 2):
        rob, sat = rows[:, cols.index(f"rob{k}_vx_mps")], rows[:, cols.index(f"sat{k}_vx_mps")]
        if run_up_s > 0:
            np.testing.assert_allclose(rob, sat, rtol=0.02)
        else:
            assert abs(rob[0]) < 1e-9 and np.max(np.abs(rob)) > 1.5 * abs(sat[0])
