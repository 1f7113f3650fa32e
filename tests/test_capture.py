"""Capture (app/sim/capture.py): a docked pair joins into one rigid body, conserving its
momenta; the compound's inertia, wrench and members' states against closed forms."""

import numpy as np
import pytest

from app.sim.capture import compound_wrench, join, relative_state, spread
from app.sim.orbital import OdsParams, box_inertia, rk4_step
from app.sim.rotations import quat_to_matrix, rotvec_to_quat

W = 1.0e-3
MASS = np.array([2.0, 3.0])
SIZE = [0.2, 0.2, 0.1]


def _pair(rng) -> np.ndarray:
    y = np.zeros((2, 13))
    y[:, :3] = [[0.0, 0.0, 0.0], [0.25, 0.03, -0.02]]
    y[:, 3:6] = rng.normal(0.0, 0.02, (2, 3))
    y[:, 6:10] = [rotvec_to_quat(rng.normal(0.0, 0.4, 3)) for _ in range(2)]
    y[:, 10:13] = rng.normal(0.0, 0.05, (2, 3))
    return y


def _momenta(y, mass_eq, inertia_eq, p0):
    """Linear momentum (R) and angular momentum about p0 (R), inertial velocities."""
    P, H = np.zeros(3), np.zeros(3)
    for i in range(len(y)):
        R = quat_to_matrix(y[i, 6:10])
        r = y[i, :3] - p0
        u = y[i, 3:6] + W * np.cross([0.0, 0.0, 1.0], y[i, :3])
        P += mass_eq[i] * y[i, 3:6]
        H += R @ (np.diag(inertia_eq[i]) @ y[i, 10:13]) + mass_eq[i] * np.cross(r, u)
    return P, H


def _energy(y, mass_eq, inertia_eq):
    """Kinetic energy, translation relative to the COM frame moving with R's origin plus
    rotation (the part a latch can change)."""
    e = 0.0
    for i in range(len(y)):
        e += 0.5 * mass_eq[i] * y[i, 3:6] @ y[i, 3:6]
        e += 0.5 * y[i, 10:13] @ (inertia_eq[i] * y[i, 10:13])
    return e


@pytest.mark.parametrize(("fs", "ts"), [(1.0, 1.0), (0.005, 0.0005), (3.0, 48.0)])
def test_join_conserves_momenta_and_never_adds_energy(fs, ts):
    rng = np.random.default_rng(3)
    y = _pair(rng)
    inertia = np.array([box_inertia(m, SIZE) for m in MASS])
    compound, row = join(y, (0, 1), MASS, inertia, fs, ts, W)
    m_eq, i_eq = MASS / fs, inertia / ts
    p_c = row[:3]
    after = np.zeros((2, 13))
    spread(compound, row, W, after)
    np.testing.assert_allclose(after[:, :3], y[:, :3], atol=1e-12)  # nobody jumps
    for a, b in zip(after[:, 6:10], y[:, 6:10], strict=True):  # nor turns
        np.testing.assert_allclose(quat_to_matrix(a), quat_to_matrix(b), atol=1e-12)
    P0, H0 = _momenta(y, m_eq, i_eq, p_c)
    P1, H1 = _momenta(after, m_eq, i_eq, p_c)
    np.testing.assert_allclose(P1, P0, atol=1e-12)
    np.testing.assert_allclose(H1, H0, atol=1e-12 * max(1.0, np.abs(H0).max()))
    assert _energy(after, m_eq, i_eq) <= _energy(y, m_eq, i_eq) + 1e-12
    assert compound.mass_kg == pytest.approx(MASS.sum())


def test_two_boxes_face_to_face_make_the_double_box():
    y = np.zeros((2, 13))
    y[:, 6] = 1.0
    y[1, 0] = 0.2  # touching along x
    m = np.array([1.0, 1.0])
    inertia = np.array([box_inertia(1.0, SIZE)] * 2)
    compound, row = join(y, (0, 1), m, inertia, 1.0, 1.0, W)
    expected = np.sort(box_inertia(2.0, [0.4, 0.2, 0.1]))
    np.testing.assert_allclose(np.sort(compound.inertia_kgm2), expected, rtol=1e-12)
    np.testing.assert_allclose(row[:3], [0.1, 0.0, 0.0], atol=1e-15)


def test_the_compound_wrench_sums_forces_with_their_moments_and_cancels_internal_pairs():
    y = np.zeros((2, 13))
    y[:, 6] = 1.0
    y[1, 0] = 0.2
    inertia = np.array([box_inertia(1.0, SIZE)] * 2)
    compound, row = join(y, (0, 1), np.array([1.0, 1.0]), inertia, 1.0, 1.0, W)
    R_R_Bc = quat_to_matrix(row[6:10])
    force = np.array([[0.0, 2.0, 0.0], [0.0, 0.0, 0.0]])  # on the first member's COM
    F, tau = compound_wrench(compound, row, force, np.zeros((2, 3)))
    np.testing.assert_allclose(F, [0.0, 2.0, 0.0])
    np.testing.assert_allclose(R_R_Bc @ tau, np.cross([-0.1, 0.0, 0.0], [0.0, 2.0, 0.0]),
                               atol=1e-15)
    # a contact at x = 0.1: +F on the second, -F on the first, with their moments
    f = np.array([0.0, 1.0, 0.5])
    force = np.array([-f, f])
    torque = np.array([np.cross([0.1, 0.0, 0.0], -f), np.cross([-0.1, 0.0, 0.0], f)])
    F, tau = compound_wrench(compound, row, force, torque)
    np.testing.assert_allclose(F, 0.0, atol=1e-15)
    np.testing.assert_allclose(tau, 0.0, atol=1e-15)


def test_the_joined_pair_moves_as_one_rigid_body():
    """Integrate the compound (one ODS body) with gravity gradient and spread each step:
    the members keep their distance and relative attitude, and their velocities are the
    rigid field v_c + w_rel x r (finite differences of the spread positions)."""
    rng = np.random.default_rng(7)
    y = _pair(rng)
    inertia = np.array([box_inertia(m, SIZE) for m in MASS])
    compound, row = join(y, (0, 1), MASS, inertia, 1.0, 1.0, W)
    params = OdsParams(orbit_rate_radps=W, mass_kg=np.array([compound.mass_kg]),
                       inertia_kgm2=compound.inertia_kgm2[None, :], torque_scale=1.0)
    dt, rows = 0.01, []
    members = np.zeros((2, 13))
    for _ in range(200):
        row = rk4_step(params, row[None, :], np.zeros((1, 3)), np.zeros((1, 3)), dt)[0]
        spread(compound, row, W, members)
        rows.append(members.copy())
    rows = np.array(rows)
    d = np.linalg.norm(rows[:, 1, :3] - rows[:, 0, :3], axis=1)
    np.testing.assert_allclose(d, d[0], rtol=1e-12)
    fd = (rows[2:, :, :3] - rows[:-2, :, :3]) / (2 * dt)
    np.testing.assert_allclose(fd, rows[1:-1, :, 3:6], atol=1e-6)
    p_rel, v_rel, angle, rate = relative_state(rows[-1], 0, 1, W)
    p0, _, angle0, _ = relative_state(rows[0], 0, 1, W)
    np.testing.assert_allclose(p_rel, p0, atol=1e-12)
    assert np.linalg.norm(v_rel) < 1e-12 and rate < 1e-12 and angle == pytest.approx(angle0)


def _docking(tmp_path, name, *args):
    import json
    import subprocess

    from tests.test_cli import EXE

    out = tmp_path / name
    proc = subprocess.run([EXE, "run", "docking", "--out", str(out), "--quiet", *args],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    lines = (out / "telemetry.csv").read_text().splitlines()
    index = {c: k for k, c in enumerate(lines[0].split(","))}
    rows = np.array([[float(x) for x in line.split(",")] for line in lines[1:]])
    return proc, json.loads((out / "metrics.json").read_text()), rows, index


@pytest.fixture(scope="module")
def docking_ideal(tmp_path_factory):
    """The docking's ideal run through the CLI, shared by the tests that compare with it."""
    return _docking(tmp_path_factory.mktemp("docking"), "ideal", "--mode", "ideal")


def test_docking_captures_on_the_arms_as_in_the_ideal_run_and_then_moves_as_one(
        tmp_path, docking_ideal):
    proc, hil, rows, index = _docking(tmp_path, "hil")
    cap = hil["capture"]
    assert hil["safety_stop"] is None and hil["success"]["passed"] and cap["captured"]
    assert "captured at" in proc.stdout and "success: passed" in proc.stdout
    assert "latched: no rebound, no restitution" in proc.stdout  # not a collision's line
    assert cap["position_miss_m"] <= 0.005 and cap["relative_speed_mps"] <= 0.01
    # momentum: two equal 100 kg bodies, one drifting at 2 cm/s: the compound goes on at
    # 1 cm/s
    assert cap["residual_speed_mps"] == pytest.approx(0.01, rel=0.05)
    after = rows[:, 0] > cap["t_s"] + 0.01
    gap = np.linalg.norm(rows[after][:, [index[f"sat2_{a}_m"] for a in "xyz"]]
                         - rows[after][:, [index[f"sat1_{a}_m"] for a in "xyz"]], axis=1)
    assert np.ptp(gap) < 1e-9  # one rigid body in the ODS
    # the chaser's own GNC flew the approach from rest, met the interface at 1-3 cm/s and
    # kept pushing through the contact until the latch, then stopped
    col = lambda name: rows[:, index[name]]  # noqa: E731
    assert col("sat1_vx_mps")[0] == 0.0  # from rest: the GNC brought it to speed
    touching = np.flatnonzero(np.abs(col("sat1_true_fx_N")) > 0.0)
    closing = col("sat1_vx_mps")[touching[0]] - col("sat2_vx_mps")[touching[0]]
    assert 0.01 <= closing <= 0.03
    t = rows[:, 0]
    pressing = (t >= t[touching[0]]) & (t < cap["t_s"])
    assert np.any(col("sat1_gnc_fx_N")[pressing] > 0.0)  # thrust towards the target
    assert np.all(col("sat1_gnc_fx_N")[t > cap["t_s"] + 0.01] == 0.0)
    assert cap["t_s"] >= t[touching[0]]  # the latch closed on a touching pair
    _, ideal, _, _ = docking_ideal
    assert ideal["capture"]["captured"]
    assert cap["t_s"] == pytest.approx(ideal["capture"]["t_s"], abs=0.1)
    assert cap["peak_contact_force_N"] == pytest.approx(ideal["capture"]["peak_contact_force_N"],
                                                        rel=0.2)


DRIFT_IN = ("--set", "satellites.0.gnc.waypoints.0.position_m=[-0.2, 0, 0]",
            "--set", "satellites.0.gnc.waypoints.0.free_drift_m=0.05")
"""The other way to dock: aimed at the port itself, the chaser stops firing 5 cm before it
and drifts into the interface."""


def test_a_latch_that_needs_1_mm_s_captures_only_a_chaser_that_presses_home(tmp_path):
    """Under 1 mm/s: a chaser that drifts in bounces off the sponge before the relative
    speed falls that low (not captured, success not met); one that keeps thrusting holds
    the interface compressed until the pair is nearly at rest, and is captured."""
    strict = ("--mode", "ideal", "--set", "capture.velocity_tolerance_mps=0.001")
    _, drifting, _, _ = _docking(tmp_path, "strict-drift", *strict, *DRIFT_IN)
    assert drifting["capture"]["captured"] is False
    assert drifting["capture"]["peak_contact_force_N"] > 1.0  # it did touch
    assert drifting["success"]["passed"] is False
    _, pressing, _, _ = _docking(tmp_path, "strict-press", *strict)
    assert pressing["capture"]["captured"] and pressing["success"]["passed"]
    assert pressing["capture"]["relative_speed_mps"] <= 0.001


def test_the_docking_s_excess_residual_rate_on_the_arms_is_the_sensor_s_noise(tmp_path,
                                                                              docking_ideal):
    """With the F/T noise at zero, the hil compound's residual rate and capture time are
    the ideal run's: what the arms add with noise (README: 0.68 against 0.01 mrad/s) comes
    from the noise passing the lifted deadbands during the gated contact."""
    quiet = ("--set", "sensor.noise_force_N=0", "--set", "sensor.noise_torque_Nm=0")
    _, hil, _, _ = _docking(tmp_path, "quiet", *quiet)
    _, ideal, _, _ = docking_ideal
    assert hil["capture"]["residual_rate_radps"] == pytest.approx(
        ideal["capture"]["residual_rate_radps"], abs=2e-5)
    assert hil["capture"]["t_s"] == pytest.approx(ideal["capture"]["t_s"], abs=0.004)


def test_the_compound_coasts_once_the_latch_stops_the_chaser_s_thrusters(docking_ideal):
    """The chaser presses the interface home under thrust; from the capture on its
    thrusters are quiet (its reference, the port, is part of its own body now) and the
    compound keeps its momentum."""
    _, m, rows, index = docking_ideal
    t_cap = m["capture"]["t_s"]
    col = lambda name: rows[:, index[name]]  # noqa: E731
    before = (rows[:, 0] > t_cap - 0.2) & (rows[:, 0] < t_cap)
    after = rows[:, 0] > t_cap + 0.01
    assert np.any(col("sat1_gnc_fx_N")[before] != 0.0)  # it was firing
    assert np.all(col("sat1_gnc_fx_N")[after] == 0.0)
    # (only CW drift, under 1e-5 m/s: the thrust it was firing would add mm/s)
    assert np.ptp(col("sat1_vx_mps")[after]) < 1e-5


def test_a_chaser_in_free_drift_coasts_into_the_interface_and_is_captured(tmp_path):
    """Drifting in (DRIFT_IN), the chaser is quiet from more than a second before contact
    and is still captured."""
    _, m, rows, index = _docking(tmp_path, "drift", "--mode", "ideal", "--duration", "13",
                                 *DRIFT_IN)
    col = lambda name: rows[:, index[name]]  # noqa: E731
    fired = np.flatnonzero(np.abs(col("sat1_gnc_fx_N")) > 0.0)
    touching = np.flatnonzero(np.abs(col("sat1_true_fx_N")) > 0.0)
    assert rows[fired[-1], 0] < rows[touching[0], 0] - 1.0
    assert 0.01 <= col("sat1_vx_mps")[touching[0]] - col("sat2_vx_mps")[touching[0]] <= 0.03
    assert m["capture"]["captured"] and m["success"]["passed"]


@pytest.mark.parametrize("require_contact", [True, False])
def test_the_latch_closes_only_on_a_touching_pair_unless_told_otherwise(tmp_path,
                                                                        require_contact):
    """An envelope reaching 3 cm short of the port, at up to 3 cm/s: a latch that needs
    contact (the default) waits for the touch; a virtual capture closes on the envelope
    alone, before any contact."""
    _, m, rows, index = _docking(
        tmp_path, "loose", "--mode", "ideal", "--duration", "12",
        "--set", "capture.position_tolerance_m=0.03",
        "--set", "capture.velocity_tolerance_mps=0.03",
        "--set", f"capture.require_contact={str(require_contact).lower()}")
    cap = m["capture"]
    touching = np.flatnonzero(np.abs(rows[:, index["sat1_true_fx_N"]]) > 0.0)
    assert cap["captured"]
    if require_contact:
        assert len(touching) and cap["t_s"] >= rows[touching[0], 0]
        assert cap["position_miss_m"] < 0.005  # at the port, not 3 cm short of it
    else:
        assert not len(touching) and cap["peak_contact_force_N"] == 0.0
        assert cap["position_miss_m"] == pytest.approx(0.03, abs=0.001)


@pytest.mark.parametrize(("knob", "value"), [("force_scale", 0.0), ("torque_scale", 0.0),
                                             ("force_scale", 1e-308)])
def test_a_capture_under_a_zero_or_tiny_knob_is_refused(knob, value):
    """The paper's law joins lab-equivalent bodies (m / force_scale, I / torque_scale):
    a zero knob makes them infinite (it ended a run in NaNs), a tiny one overflows their
    sum (1e-308: the pair's momentum was lost without an error)."""
    from app.config import ConfigError, parse_config

    with pytest.raises(ConfigError) as err:
        parse_config({"orbit": {"force_scale": 1.0, "torque_scale": 1.0, knob: value},
                      "satellites": [{"name": "a"}, {"name": "b", "position_m": [1, 0, 0]}],
                      "capture": {"chaser": "a", "target": "b",
                                  "mated_offset_m": [0.2, 0.0, 0.0]}})
    knobs = {"force_scale": 1.0, "torque_scale": 1.0, knob: value}
    assert str(err.value) == (
        f"invalid configuration: capture: [orbit] force_scale {knobs['force_scale']:g} and "
        f"torque_scale {knobs['torque_scale']:g} make a satellite's lab-equivalent mass or "
        f"inertia (mass / force_scale, inertia / torque_scale) infinite or over 1e+30; no "
        f"compound can be formed")
