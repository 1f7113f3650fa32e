"""Robots on rails in the loop (app.sim.rail_rig), end to end: the rail scenarios
(free-flying-rails, rendezvous-rails) through the CLI (no stop, tracking, travel, posture,
the rail telemetry), the same scenarios without their rails refused by the pre-flight naming
the reach, and a stop of the carriage halting the arm.
"""

from __future__ import annotations

import json
import re
import subprocess

import numpy as np
import pytest

from app.config import merge_overrides
from app.scenarios import load_scenario
from app.sim.loop import Emulator
from app.sim.rail_rig import RailRig
from app.sim.rotations import make_transform, quat_to_matrix
from tests.test_cli import EXE

RAIL_SCENARIOS = {"free-flying-rails": ("ceiling",), "rendezvous-rails": ("ceiling", "floor")}
"""Each rail scenario and its robots, the first of which carries its satellite > 2 m."""


@pytest.fixture(scope="module", params=list(RAIL_SCENARIOS))
def rail_run(request, tmp_path_factory):
    out = tmp_path_factory.mktemp(request.param) / "out"
    proc = subprocess.run([EXE, "run", request.param, "--out", str(out), "--quiet"],
                          capture_output=True, text=True, timeout=600)
    return request.param, proc, out


def test_a_rail_scenario_runs_hil_to_the_end_on_its_rails(rail_run):
    """hil, no stop, its success criteria met; each mockup within 1 mm of its satellite all
    along while the first robot's carriage travels more than 2 m and every arm stays within
    0.5 rad of its posture."""
    name, proc, out = rail_run
    assert proc.returncode == 0, proc.stderr
    m = json.loads((out / "metrics.json").read_text())
    assert m["mode"] == "hil" and m["status"] == "finished" and m["safety_stop"] is None
    assert m["duration_s"] == pytest.approx(load_scenario(name).loop.duration_s)
    assert [r["name"] for r in m["robots"]] == list(RAIL_SCENARIOS[name])
    for rob in m["robots"]:
        sat = next(s for s in m["satellites"] if s["name"] == rob["satellite"])
        assert rob["position_error_max_m"] <= 1e-3
        assert rob["position_error_max_m"] == sat["position_error_max_m"]
        assert rob["posture_deviation_max_rad"] <= 0.5
    assert m["robots"][0]["rail_travel_m"] >= 2.0
    assert m["success"]["passed"] is True


def test_its_telemetry_has_the_carriage_and_the_mockup_rides_it(rail_run):
    """rob<k>_rail_s_m / _v_mps / _sp_m are recorded for each robot; the carriage's speed
    is its position's rate, and the first mockup's lab motion along the rail is the
    carriage's, give or take what the arm does (well under the travel)."""
    name, _, out = rail_run
    cfg = load_scenario(name)
    header = (out / "telemetry.csv").read_text().split("\n", 1)[0].split(",")
    rows = np.loadtxt(out / "telemetry.csv", delimiter=",", skiprows=1)
    col = {name: rows[:, k] for k, name in enumerate(header)}
    t = col["t_s"]
    for k in range(1, len(cfg.robots) + 1):
        s, v, sp = (col[f"rob{k}_rail_{f}"] for f in ("s_m", "v_mps", "sp_m"))
        np.testing.assert_allclose(np.gradient(s, t), v, atol=5e-3)
        assert np.abs(sp - s).max() < 2e-3  # a velocity-feedforward drive, one cycle's delay
    s = col["rob1_rail_s_m"]
    axis_W = np.array(cfg.robots[0].rail.axis_W)
    T_W_R = make_transform(quat_to_matrix(cfg.lab.r_attitude_wxyz), cfg.lab.r_origin_m)
    p_W = np.stack([col[f"rob1_{a}_m"] for a in "xyz"], 1) @ T_W_R[:3, :3].T
    along = p_W @ axis_W
    assert np.abs((along - along[0]) - (s - s[0])).max() < 0.1 * (s.max() - s.min())


WITHOUT_RAILS = {
    # scenario: (--set arguments, --duration, what the pre-flight says first)
    "free-flying-rails": (["robots.0.rail=null"], None,
                          r"robot 1 \(ceiling\): satellite 'freeflyer' leaves the arm's reach "
                          r"\(1\.200 m from its shoulder; limit 1\.2 m\) at t = 8\.\d\d s"),
    "rendezvous-rails": (["robots.0.rail=null", "robots.1.rail=null"], None,
                         r"robot 1 \(ceiling\): satellite 'chaser' leaves the arm's reach "
                         r"\(1\.641 m from its shoulder; limit 1\.2 m\) at t = 0\.00 s"),
    # the chaser passes under the fixed ceiling arm's shoulder (its 6 s are enough)
    "docking-rails": (["robots.0.rail=null", "robots.1.rail=null"], "6",
                      r"robot 1 \(ceiling\): satellite 'chaser' leaves the arm's reach \(its "
                      r"wrist would come within 0\.050 m of its base axis; inner limit "
                      r"0\.194 m, the shoulder singular at 0\.174 m\) at t = 3\.\d\d s"),
    # after the contact both satellites drift back under their fixed arms' shoulders
    "collision-rails": (["robots.0.rail=null", "robots.1.rail=null"], None,
                        r"robot 1 \(ceiling\): satellite 'cubesat' leaves the arm's reach "
                        r"\(its wrist would come within 0\.113 m of its base axis; inner "
                        r"limit 0\.194 m, the shoulder singular at 0\.174 m\) at t = 2\d\.\d\d s; "
                        r"robot 2 \(floor\): "
                        r"satellite 'sponge' leaves the arm's reach"),
}


@pytest.mark.parametrize("name", list(WITHOUT_RAILS))
def test_without_its_rails_the_cli_refuses_it_naming_the_reach(name, tmp_path):
    """`run SCENARIO --set robots.<i>.rail=null`: the pre-flight refuses the course the
    fixed arms cannot follow (exit 2, nothing written), naming the reach: its outer limit
    (the shoulder's 1.2 m) or its inner one (the cylinder around the base joint's axis
    that the wrist cannot enter). With the rails the same scenarios run (the tests above
    and below)."""
    sets, duration, said = WITHOUT_RAILS[name]
    out = tmp_path / "out"
    cmd = [EXE, "run", name, "--out", str(out), "--quiet"]
    cmd += [a for s in sets for a in ("--set", s)]
    cmd += ["--duration", duration] if duration else []
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.startswith("error: pre-flight: the ideal run predicts that "), proc.stderr
    assert re.search(said, proc.stderr), proc.stderr
    assert "The arms have not moved" in proc.stderr and not out.exists()


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


RAIL_VARIANTS = {"collision-rails": ("collision", 0.4), "docking-rails": ("docking", 1.0)}
"""Each rail variant: the scenario it extends, and the least travel of its first carriage."""


@pytest.mark.parametrize("name", list(RAIL_VARIANTS))
def test_the_collision_and_docking_rail_variants_run_hil_to_the_end(name, tmp_path):
    """collision-rails and docking-rails (the scenarios they extend, with both arms on
    rails along x): hil to the end, no stop, each mockup within 1 mm of its satellite while
    the first carriage travels; the contact happens (docking: the capture, its success)."""
    base, least_travel_m = RAIL_VARIANTS[name]
    cfg = load_scenario(name)
    assert [r.satellite for r in cfg.robots] == [r.satellite for r in load_scenario(base).robots]
    assert all(r.rail is not None for r in cfg.robots)
    out = tmp_path / "out"  # (no interval or forecast: tests/runs/test_uncertainty.py)
    proc = subprocess.run([EXE, "run", name, "--out", str(out), "--quiet",
                           "--set", "uncertainty.enabled=false"],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    m = json.loads((out / "metrics.json").read_text())
    assert m["mode"] == "hil" and m["status"] == "finished" and m["safety_stop"] is None
    assert m["duration_s"] == pytest.approx(cfg.loop.duration_s)
    for rob in m["robots"]:
        assert rob["position_error_max_m"] <= 1e-3, rob
        assert rob["posture_deviation_max_rad"] <= 0.5, rob
    assert m["robots"][0]["rail_travel_m"] >= least_travel_m
    if name == "docking-rails":
        assert m["capture"]["captured"] is True and m["success"]["passed"] is True
    else:
        assert m["collision"]["restitution"] > 0.1  # they met, and rebounded
