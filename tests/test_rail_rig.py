"""A robot on a rail in the loop (app.sim.rail_rig), end to end: the free-flying-rails
scenario through the CLI (no stop, tracking, travel, posture), the same scenario without its
rail refused by the pre-flight naming the reach, and a stop of the carriage halting the arm.
"""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest

from app.config import merge_overrides
from app.runs.preflight import PreflightRefused, preflight
from app.scenarios import load_scenario
from app.sim.loop import Emulator
from app.sim.rail_rig import RailRig
from tests.test_cli import EXE


@pytest.fixture(scope="module")
def free_flying_rails(tmp_path_factory):
    out = tmp_path_factory.mktemp("ffr") / "out"
    proc = subprocess.run([EXE, "run", "free-flying-rails", "--out", str(out), "--quiet"],
                          capture_output=True, text=True, timeout=600)
    return proc, out


def test_free_flying_rails_runs_hil_to_the_end_on_its_rail(free_flying_rails):
    """hil, no stop; the mockup within 1 mm of its satellite all along while the carriage
    travels more than 2 m and the arm stays within 0.5 rad of its posture."""
    proc, out = free_flying_rails
    assert proc.returncode == 0, proc.stderr
    m = json.loads((out / "metrics.json").read_text())
    assert m["mode"] == "hil" and m["status"] == "finished" and m["safety_stop"] is None
    assert m["duration_s"] == pytest.approx(load_scenario("free-flying-rails").loop.duration_s)
    (rob,) = m["robots"]
    assert rob["name"] == "ceiling" and rob["satellite"] == "freeflyer"
    assert rob["position_error_max_m"] <= 1e-3
    assert rob["position_error_max_m"] == m["satellites"][0]["position_error_max_m"]
    assert rob["rail_travel_m"] >= 2.0
    assert rob["posture_deviation_max_rad"] <= 0.5
    assert m["success"]["passed"] is True


def test_its_telemetry_has_the_carriage_and_the_mockup_rides_it(free_flying_rails):
    """rob1_rail_s_m / _v_mps / _sp_m are recorded; the carriage's speed is its position's
    rate, and the mockup's lab motion along the rail is the carriage's, give or take what
    the arm does (well under the travel)."""
    _, out = free_flying_rails
    header = (out / "telemetry.csv").read_text().split("\n", 1)[0].split(",")
    rows = np.loadtxt(out / "telemetry.csv", delimiter=",", skiprows=1)
    col = {name: rows[:, k] for k, name in enumerate(header)}
    s, v, sp, t = col["rob1_rail_s_m"], col["rob1_rail_v_mps"], col["rob1_rail_sp_m"], col["t_s"]
    np.testing.assert_allclose(np.gradient(s, t), v, atol=5e-3)
    assert np.abs(sp - s).max() < 2e-3  # a velocity-feedforward drive, one cycle of delay
    y = col["rob1_y_m"]  # R's y is the rail's axis (lab y) in this scenario
    assert np.abs((y - y[0]) - (s - s[0])).max() < 0.1 * (s.max() - s.min())


def test_without_its_rail_the_pre_flight_refuses_it_naming_the_reach():
    cfg = merge_overrides(load_scenario("free-flying-rails"), {"robots": {"0": {"rail": None}}})
    assert cfg.robots[0].rail is None
    with pytest.raises(PreflightRefused, match=r"robot 1 \(ceiling\): satellite 'freeflyer' "
                                               r"leaves the arm's reach \(1\.200 m from its "
                                               r"shoulder; limit 1\.2 m\)"):
        preflight(cfg, cfg.loop.duration_s)
    preflight(load_scenario("free-flying-rails"), cfg.loop.duration_s)  # with it: accepted


def test_a_stop_of_the_carriage_halts_the_arm_and_the_loop_says_why():
    cfg = merge_overrides(load_scenario("free-flying-rails"),
                          {"wrench": {"calibration_s": 0.1}})
    em = Emulator(cfg)
    em.prepare()
    rig = em.arms[0]
    assert isinstance(rig, RailRig) and em.status == "running"
    em.step()
    rig.rail_servo.step(5.0)  # a set-point beyond the travel, as a fault would send
    em.step()
    assert em.status == "safety_stop"
    assert em.safety_stop["reason"] == "rail travel end" and em.safety_stop["robot"] == 1
    assert rig.servo.stopped and rig.servo.reason == "rail travel end"
