"""Pre-flight (app/runs/preflight.py): the ideal run's course against each arm's reach, safety
volume and speed, before the arms move."""

import math

import numpy as np
import pytest

from app.config import assignment_override, merge_overrides
from app.runs.headless import checked_reference, collision_of, headless_config
from app.runs.preflight import (
    DRIFT_SIGMAS,
    HOLD_RADIUS_M,
    INNER_RADIUS_M,
    MIN_WRIST_RADIUS_M,
    PreflightRefused,
    check_drift,
    predict,
    preflight,
    wrist_axis_distance,
)
from app.runs.uncertainty import forecast
from app.scenarios import load_scenario, scenario_names
from app.sim.loop import Emulator
from app.sim.rotations import make_transform, matrix_to_quat, quat_to_matrix
from app.sim.ur10e import (
    DH_D_M,
    SHOULDER_B_M,
    T_F_C_from_config,
    T_W_B_from_config,
    flange_pose_B,
)


@pytest.mark.parametrize("name", scenario_names())
def test_every_built_in_scenario_passes(name):
    cfg = load_scenario(name)
    em = preflight(cfg, cfg.loop.duration_s)
    assert em is not None and em.ods.t_s == pytest.approx(cfg.loop.duration_s, abs=0.011)


def _drifting(velocity_mps):
    return merge_overrides(load_scenario("free-floating"),
                           {"satellites": {"0": {"velocity_mps": velocity_mps}}})


def test_a_satellite_drifting_out_of_reach_is_refused_with_the_robot_time_and_limit():
    """0.05 m/s along y from 0.96 m off the shoulder: out of the 1.2 m reach after
    sqrt(1.2² - d0²) / 0.05 s (CW bends the line by Omega v t², 1 cm here)."""
    cfg = _drifting([0.0, 0.05, 0.0])
    T_W_B = T_W_B_from_config(cfg.robots[0])
    shoulder = T_W_B[:3, :3] @ np.asarray(SHOULDER_B_M) + T_W_B[:3, 3]
    d0 = np.linalg.norm(np.array([-0.35, 0.0, 1.0]) - shoulder)
    t_out = math.sqrt(HOLD_RADIUS_M**2 - d0**2) / 0.05
    with pytest.raises(PreflightRefused) as err:
        preflight(cfg, cfg.loop.duration_s)
    text = str(err.value)
    assert text.startswith("pre-flight: the ideal run predicts that robot 1 (ceiling): "
                           "satellite 'cubesat' leaves the arm's reach (1.200 m from its "
                           "shoulder; limit 1.2 m) at t = ")
    t_said = float(text.split("at t = ")[1].split(" s")[0])
    assert t_said == pytest.approx(t_out, rel=0.03)
    assert "leaves the safety volume (at (-0.303, 1.500, 1.000) m in W" in text  # 30 s
    assert text.endswith("The arms have not moved; change the scenario (or run it "
                         "--mode ideal)")


def test_the_wrist_s_distance_from_the_base_axis_is_the_arm_s_own_and_never_inside():
    """For random postures of collision's ceiling arm, the distance the pre-flight derives
    from the mockup's pose (position and attitude in R) is the one of the wrist point (the
    flange less d6 along its axis) that the forward kinematics puts there, and it is never
    under the inner limit d4 (which is why a course inside it is refused). On a rail along
    x the carriage can take the base away from a point under the shoulder."""
    cfg = load_scenario("collision")
    robot = cfg.robots[0]
    T_W_R = make_transform(quat_to_matrix(cfg.lab.r_attitude_wxyz), cfg.lab.r_origin_m)
    T_W_B, T_F_C = T_W_B_from_config(robot), T_F_C_from_config(robot)
    qs = np.random.default_rng(7).uniform(-math.pi, math.pi, (200, 6))
    T_B_F = np.stack([flange_pose_B(q) for q in qs])
    wrist_B = T_B_F[:, :3, 3] - DH_D_M[5] * T_B_F[:, :3, 2]
    T_R_C = np.linalg.inv(T_W_R) @ T_W_B @ T_B_F @ T_F_C
    p_W = (T_W_R @ T_R_C)[:, :3, 3]
    quats = np.stack([matrix_to_quat(T[:3, :3]) for T in T_R_C])
    got = wrist_axis_distance(robot, T_W_R, p_W, quats)
    np.testing.assert_allclose(got, np.hypot(wrist_B[:, 0], wrist_B[:, 1]), atol=1e-9)
    assert got.min() >= INNER_RADIUS_M - 1e-9
    # a mockup right under the shoulder, flange down: fixed, the wrist is on the axis; on a
    # rail along x (travel ±1 m) the carriage can stand as far off as the reach allows,
    # sqrt(1.2² − h²) with h the shoulder's height over the mockup
    below = np.array([[robot.base_position_m[0], 0.0, 1.0]])
    down = matrix_to_quat(np.linalg.inv(T_W_R[:3, :3]) @ T_W_B[:3, :3]
                          @ T_F_C[:3, :3])[None]
    assert wrist_axis_distance(robot, T_W_R, below, down)[0] == pytest.approx(0.0, abs=1e-9)
    on_rail = robot.model_copy(update={"rail": _rail_x()})
    h = robot.base_position_m[2] - DH_D_M[0] - 1.0
    assert wrist_axis_distance(on_rail, T_W_R, below, down)[0] == pytest.approx(
        math.sqrt(HOLD_RADIUS_M**2 - h * h))


def _rail_x():
    from app.config import RailConfig

    return RailConfig(axis_W=(1.0, 0.0, 0.0), travel_m=(-1.0, 1.0))


def test_a_satellite_faster_than_the_arm_is_refused_at_once():
    with pytest.raises(PreflightRefused,
                       match=r"moves faster than the arm's TCP \(1\.5 m/s; limit 1 m/s\) "
                             r"at t = 0\.00 s"):
        preflight(_drifting([1.5, 0.0, 0.0]), 5.0)


def test_a_spin_faster_than_the_wrist_is_refused():
    cfg = merge_overrides(load_scenario("free-floating"),
                          {"satellites": {"0": {"omega_radps": [0.0, 0.0, 4.0]}}})
    with pytest.raises(PreflightRefused, match=r"turns faster than the arm's wrist \(4 rad/s"):
        preflight(cfg, 1.0)


def test_a_pulse_shorter_than_the_coarse_prediction_s_step_is_not_missed():
    """A 4 ms, 90 N push off the 100 Hz grid (force scale 1: 0.36 m/s on 1 kg) throws the
    satellite out of reach in about 3 s: the prediction runs at the loop's rate then (at
    100 Hz it fell between two samples and predicted no motion at all)."""
    cfg = merge_overrides(load_scenario("free-floating"), {
        "orbit": {"force_scale": 1.0},
        "pulses": [{"satellite": "cubesat", "start_s": 1.001, "end_s": 1.005,
                    "force_N": [0.0, 90.0, 0.0]}]})
    with pytest.raises(PreflightRefused, match="leaves the arm's reach"):
        preflight(cfg, 6.0)


def test_a_refusal_names_the_contact_that_came_before_it():
    """A rendezvous whose last transfer runs the chaser through the target: the spin it
    is refused for follows a predicted contact, which the message names."""
    cfg = merge_overrides(load_scenario("rendezvous"), {"satellites": {"0": {"gnc": {
        "waypoints": {"2": {"position_m": [150.0, -50.0, 0.0]}}}}}})
    with pytest.raises(PreflightRefused) as err:
        preflight(cfg, cfg.loop.duration_s)
    text = str(err.value)
    assert "turns faster than the arm's wrist" in text
    note = text.split("; and before any of that, at t = ")[1]
    t_touch = float(note.split(" s,")[0])
    t_first = float(text.split(" at t = ")[1].split(" s")[0])
    assert t_touch <= t_first
    assert "the mockups of 'chaser' and 'target' touch (up to " in note


def test_an_ideal_only_layout_has_nothing_to_check():
    cfg = merge_overrides(_drifting([1.5, 0.0, 0.0]), {"robots": []})
    assert preflight(cfg, 5.0) is None


def test_a_sweep_run_the_pre_flight_refuses_is_a_row_refused_and_nothing_runs():
    """The sweep's shared reference carries the pre-flight: a refused configuration is
    the outcome "refused" with the reason, for every seed, and no run starts."""
    from app.campaign.sweep import compute_ideal, execute_run
    from app.runs.run_config import finish_run_config

    base = merge_overrides(load_scenario("collision"),
                           {"satellites": {"0": {"velocity_mps": [0.6, 0.0, 0.0]}}})
    config = finish_run_config(base, mode="hil", duration_s=4.0)
    reference = compute_ideal(config)
    assert reference[0] == "refused" and reference[1].startswith(
        "pre-flight: the ideal run predicts that robot 1 (ceiling)")
    outcome = execute_run(config, reference, "none", None)
    assert (outcome["status"], outcome["reason"], outcome["metrics"]) == (
        "refused", reference[1], None)
    assert outcome["wall_s"] < 0.5
    # a single-satellite run has no shared reference: it checks itself
    single = finish_run_config(_drifting([0.0, 0.05, 0.0]), mode="hil", duration_s=30.0)
    outcome = execute_run(single, None, "none", None)
    assert outcome["status"] == "refused" and "leaves the arm's reach" in outcome["reason"]


@pytest.mark.parametrize(("scenario", "setting", "robot"), [
    # R's origin 0.6 m further from the ceiling arm: the satellite starts out of reach
    ("gravity-stabilised", "lab.r_origin_m=[0.25, 0.0, 1.0]", "robot 1 (ceiling): satellite 'sat'"),
    # a third waypoint 5 m (1 m in the lab) beyond the second
    ("free-flying", "satellites.0.gnc.waypoints.2.position_m=[5.0, 0.25, 0.25]",
     "robot 1 (ceiling): satellite 'freeflyer'"),
    # a docking port 0.9 m below the target: the chaser dives for it, out of reach
    ("docking", "satellites.0.gnc.waypoints.0.position_m=[-0.2, 0.0, -0.9]",
     "robot 1 (ceiling): satellite 'chaser' leaves the arm's reach"),
])
def test_run_refuses_an_unreachable_variant_of_each_scenario_before_the_arms_move(
        tmp_path, scenario, setting, robot):
    """Through the CLI, as a user meets it: the pre-flight names the robot, the satellite
    and the limit, exits non-zero, and writes nothing (rendezvous and tumbling-target:
    their own test files)."""
    import subprocess

    from tests.test_cli import EXE

    out = tmp_path / "out"
    proc = subprocess.run([EXE, "run", scenario, "--out", str(out), "--quiet", "--set", setting],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode != 0
    assert "pre-flight: the ideal run predicts that" in proc.stderr, proc.stderr
    assert robot in proc.stderr and "The arms have not moved" in proc.stderr, proc.stderr
    assert not out.exists()


def _rigid_collision(*extra: str):
    config = load_scenario("collision")
    for a in ['satellites.1.material="rigid"', *extra]:
        config = merge_overrides(config, assignment_override(a))
    return headless_config(config, config.loop.duration_s)


def test_the_wrist_radius_from_the_course_is_the_arms_own():
    """The wrist's distance from joint 1's axis, from a satellite's pose and the mockup's
    mounting, is the one the arm's forward kinematics gives from its joint angles while
    it holds that satellite (to its tracking error, here well under a millimetre)."""
    config = _rigid_collision("loop.duration_s=0.2")
    em = Emulator(config)
    em.run(0.2)
    rows, index = em.telemetry.rows(), em.telemetry.index
    T_W_R = make_transform(quat_to_matrix(config.lab.r_attitude_wxyz), config.lab.r_origin_m)
    for k, robot in enumerate(config.robots):
        s = config.satellite_index(robot.satellite) + 1
        p_W = rows[-1:, [index[f"sat{s}_{a}_m"] for a in "xyz"]] @ T_W_R[:3, :3].T \
            + T_W_R[:3, 3]
        quat = rows[-1:, [index[f"sat{s}_q{a}"] for a in "wxyz"]]
        predicted = wrist_axis_distance(robot, T_W_R, p_W, quat)[0]
        q = rows[-1, [index[f"rob{k + 1}_q{j}_rad"] for j in range(1, 7)]]
        T_B_F = flange_pose_B(q)
        wrist = T_B_F[:3, 3] - DH_D_M[5] * T_B_F[:3, 2]
        assert predicted == pytest.approx(np.hypot(wrist[0], wrist[1]), abs=1e-3)
        assert predicted > MIN_WRIST_RADIUS_M


def test_the_noise_drift_after_a_contact_is_refused_with_a_duration_that_fits():
    """Rigid vs rigid for 10 s: the ideal course keeps the wrists clear of the shoulder
    singularity (it reaches it at 10.47 s), but a satellite leaving the contact 3 sd
    faster than the ideal does not: refused (as checked_reference does it), naming the
    drift, the limit and a duration that passes with the same forecast."""
    config = _rigid_collision("loop.duration_s=10", "uncertainty.forecast_replicates=4")
    prediction = preflight(config, 10.0)  # the ideal course alone passes
    reference = collision_of(prediction)
    reference["forecast"] = forecast(config, reference)
    with pytest.raises(PreflightRefused) as err:
        check_drift(config, prediction, reference)
    text = str(err.value)
    rate = DRIFT_SIGMAS * np.linalg.norm(reference["forecast"]["velocity_sd_mps"]["sat1"])
    assert text.startswith(f"pre-flight: after the contact (t = 3.15 s) the sensor's noise "
                           f"scatters the satellites' velocities (the forecast: 3 sd = "
                           f"{rate:.3g} m/s); with that drift, robot 1 (ceiling): satellite "
                           f"'cubesat' leaves the arm's reach (its wrist would come within ")
    assert (f"m of its base axis; inner limit {MIN_WRIST_RADIUS_M:.3f} m, the shoulder "
            f"singular at {INNER_RADIUS_M:.3f} m) at t = ") in text
    said = float(text.split("loop.duration_s = ")[1].split(" ")[0])
    assert 3.2 < said < 10.0
    assert text.endswith(f"The arms have not moved; shorten the run (loop.duration_s = "
                         f"{said:g} keeps it within every limit) or change the scenario")
    check_drift(config, predict(config, said), reference)  # (the duration it names passes)


def test_on_rails_the_drift_along_the_rail_is_the_carriage_s_to_carry():
    """collision-rails (30 s, both arms on rails along x): after the contact the noise
    scatters the satellites' velocities almost all along x, the rail's axis; the carriage
    carries that drift within its travel, so the pre-flight with its forecast passes (the
    isotropic widening once refused the shipped scenario at 19.7 s), while the same
    drift on fixed arms is refused."""
    config = load_scenario("collision-rails")
    config = headless_config(merge_overrides(
        config, assignment_override("uncertainty.forecast_replicates=8")), 30.0)
    reference = checked_reference(config, 30.0)
    sd = reference["forecast"]["velocity_sd_mps"]["sat1"]
    assert sd[0] > 10 * max(sd[1], sd[2])  # along the rail
    prediction = predict(config, 30.0)
    fixed = merge_overrides(config, {"robots": {"0": {"rail": None}, "1": {"rail": None}}})
    with pytest.raises(PreflightRefused, match="leaves the arm's reach"):
        check_drift(fixed, prediction, reference)


def test_a_drift_that_could_take_the_wrist_past_the_base_axis_is_said_so():
    """A wide drift (the sensor's spread twenty times the forecast's) widens the wrist's
    distance from the base axis past zero: the refusal says the wrist could cross the
    axis, never a negative distance."""
    config = _rigid_collision("loop.duration_s=10", "uncertainty.forecast_replicates=4")
    prediction = preflight(config, 10.0)
    reference = collision_of(prediction)
    reference["forecast"] = forecast(config, reference)
    sd = reference["forecast"]["velocity_sd_mps"]
    reference["forecast"]["velocity_sd_mps"] = {k: [20.0 * x for x in v] for k, v in sd.items()}
    with pytest.raises(PreflightRefused) as err:
        check_drift(config, prediction, reference)
    text = str(err.value)
    assert "its wrist could cross its base axis; inner limit" in text
    assert "within -" not in text
