"""The rendezvous scenario through the CLI: a chaser flies two CW two-impulse transfers
along V-bar between hold points, on the arms as in the ideal run, and ends at its last
hold point; a course out of the arm's reach is refused before the arms move."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest

from app.scenarios import load_scenario
from app.sim.guidance import two_impulse_transfer
from app.sim.orbital import cw_state_transition, orbit_rate
from tests.test_cli import EXE

CFG = load_scenario("rendezvous")
GNC = CFG.satellites[0].gnc


def _run(out, *args) -> tuple[subprocess.CompletedProcess, dict, np.ndarray, dict]:
    proc = subprocess.run([EXE, "run", "rendezvous", "--out", str(out), "--quiet", *args],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    lines = (out / "telemetry.csv").read_text().splitlines()
    index = {name: k for k, name in enumerate(lines[0].split(","))}
    return (proc, json.loads((out / "metrics.json").read_text()),
            np.loadtxt(lines[1:], delimiter=","), index)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    out = tmp_path_factory.mktemp("rendezvous")
    return {"hil": _run(out / "hil"), "ideal": _run(out / "ideal", "--mode", "ideal")}


def test_the_chaser_reaches_its_hold_points_and_ends_within_tolerance_on_the_arms(runs):
    proc, m, _, _ = runs["hil"]
    assert m["status"] == "finished" and m["safety_stop"] is None
    s = m["success"]
    assert s["passed"], s
    assert s["waypoints"]["reached"] == 3
    assert s["final_position"]["error_m"] <= GNC.tolerance_m == 0.5
    # each transfer arrives when due within 5 cm of its hold point (of 25 m flown)
    transfers = s["waypoints"]["transfers"]
    assert [leg["waypoint"] for leg in transfers] == [2, 3]
    assert all(leg["miss_m"] < 0.05 for leg in transfers), transfers
    for leg, wp in zip(transfers, GNC.waypoints[1:], strict=True):
        assert leg["due_s"] == pytest.approx(leg["start_s"] + wp.transfer_s)
    for sat in m["satellites"]:
        assert sat["position_error_max_m"] < 1e-3 and sat["attitude_error_max_rad"] < 0.01
    assert "success: passed" in proc.stdout
    assert "CW transfer to waypoint 2: due at" in proc.stdout


def test_the_course_is_the_cw_transfer_s_bulging_below_v_bar(runs):
    """Between S1 and S2 the chaser leaves V-bar radially by the closed form's ~5.75 m
    (the CW two-impulse transfer of 25 m in 1200 s) and its first burn is the closed-form
    Δv1 in orbit units (k_L/k_T = 1 here): 100 s on, the velocity is the closed form's
    of a Δv1 given at the burn's middle (3 s in)."""
    _, m, rows, ix = runs["ideal"]
    t_orbit = CFG.scaling.time * rows[:, 0]
    start = m["success"]["waypoints"]["reached_at_s"][0]
    leg = (t_orbit > start) & (t_orbit < start + 1200.0)
    x = CFG.scaling.length * rows[leg, ix["sat1_x_m"]]
    assert x.min() == pytest.approx(-5.75, abs=0.1)
    W = orbit_rate(CFG.orbit.altitude_m)
    dv1, _ = two_impulse_transfer([0, -100, 0], [0, 0, 0], [0, -75, 0], [0, 0, 0], 1200.0, W)
    after = np.argmax(t_orbit >= start + 100.0)
    expected = cw_state_transition(W, t_orbit[after] - start - 3.0) @ np.r_[0, -100, 0, dv1]
    v = rows[after, [ix[f"sat1_v{a}_mps"] for a in "xyz"]]  # k_L / k_T = 1
    np.testing.assert_allclose(v, expected[3:], atol=1e-4)  # 0.5 % of |Δv1|


def test_hil_and_ideal_agree_within_the_tracking_tolerance(runs):
    _, hil, rows_h, ix = runs["hil"]
    _, ideal, rows_i, _ = runs["ideal"]
    assert ideal["success"]["passed"]
    pos = [ix[f"sat1_{a}_m"] for a in "xyz"]
    gap = np.max(np.linalg.norm(rows_h[:, pos] - rows_i[:, pos], axis=1))
    assert gap < CFG.loop.max_tracking_error_m / 50  # 1 mm in the lab (0.2 m of orbit)
    np.testing.assert_allclose(hil["success"]["waypoints"]["reached_at_s"],
                               ideal["success"]["waypoints"]["reached_at_s"], atol=10.0)


def test_a_hold_point_out_of_the_arm_s_reach_is_refused_before_the_arms_move(tmp_path):
    """S2 150 m above V-bar (radially) is 0.75 m sideways in the lab: out of the ceiling
    arm's reach. The pre-flight names the robot, the satellite, the limit and the time,
    and nothing is written."""
    out = tmp_path / "far"
    proc = subprocess.run([EXE, "run", "rendezvous", "--out", str(out), "--quiet", "--set",
                           "satellites.0.gnc.waypoints.1.position_m=[150.0, -75.0, 0.0]"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode != 0
    assert ("pre-flight: the ideal run predicts that robot 1 (ceiling): satellite 'chaser' "
            "leaves the arm's reach") in proc.stderr, proc.stderr
    assert "The arms have not moved" in proc.stderr
    assert not out.exists()
