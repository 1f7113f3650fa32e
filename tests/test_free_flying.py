"""The free-flying scenario through the CLI: a satellite under its own GNC flies its
waypoints on the arm, is pushed off one and recovers; hil agrees with ideal; its thrust
stays within its limits and never passes the F/T sensor."""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest

from app.runs.report import gnc_success_lines
from app.runs.success import success_metrics
from app.scenarios import load_scenario
from app.sim.rotations import quat_to_matrix
from tests.test_cli import EXE

CFG = load_scenario("free-flying")
GNC = CFG.satellites[0].gnc
PULSE = CFG.pulses[0]


def _run(out, *args) -> tuple[subprocess.CompletedProcess, dict, np.ndarray, dict]:
    """(the process, metrics.json, telemetry rows, column index) of a CLI run into out."""
    proc = subprocess.run([EXE, "run", "free-flying", "--out", str(out), "--quiet", *args],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    lines = (out / "telemetry.csv").read_text().splitlines()
    index = {name: k for k, name in enumerate(lines[0].split(","))}
    return (proc, json.loads((out / "metrics.json").read_text()),
            np.loadtxt(lines[1:], delimiter=","), index)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    out = tmp_path_factory.mktemp("free_flying")
    return {"hil": _run(out / "hil", "--bag", "--bag-rate", "5"),
            "ideal": _run(out / "ideal", "--mode", "ideal"), "hil_bag": out / "hil" / "bag"}


def test_it_flies_its_waypoints_and_recovers_from_the_push_on_the_arm(runs):
    proc, m, _, _ = runs["hil"]
    assert m["status"] == "finished" and m["safety_stop"] is None
    s = m["success"]
    assert s["passed"], s
    assert s["waypoints"]["reached"] == s["waypoints"]["count"] == 3
    assert s["final_position"]["error_m"] < GNC.tolerance_m
    rec = s["recovery"]
    assert rec["waypoint"] == 2  # the push came while it held its second waypoint
    assert rec["excursion_max_m"] > 4 * GNC.tolerance_m  # a real disturbance ...
    assert 0.0 < rec["recovery_time_s"] <= 60.0  # ... from which it came back
    reached = s["waypoints"]["reached_at_s"]
    assert reached[0] < 10 * PULSE.start_s < reached[1]  # ... and then went on
    sat = m["satellites"][0]
    assert sat["position_error_max_m"] < 2e-3 and sat["attitude_error_max_rad"] < 0.01
    assert "success: passed" in proc.stdout
    assert "waypoints of freeflyer: 3 of 3 reached in order" in proc.stdout
    assert "recovery of freeflyer from the push ending at 113.0 s" in proc.stdout


def test_hil_and_ideal_agree_within_the_tracking_tolerance(runs):
    _, hil, rows_h, ix = runs["hil"]
    _, ideal, rows_i, _ = runs["ideal"]
    assert ideal["success"]["passed"]
    pos = [f"sat1_{a}_m" for a in "xyz"]
    gap = np.linalg.norm(rows_h[-1, [ix[c] for c in pos]] - rows_i[-1, [ix[c] for c in pos]])
    assert gap < CFG.loop.max_tracking_error_m / 50  # 1 mm; measured ~0.02 mm
    np.testing.assert_allclose(hil["success"]["waypoints"]["reached_at_s"],
                               ideal["success"]["waypoints"]["reached_at_s"], atol=2.0)
    assert hil["success"]["recovery"]["recovery_time_s"] == pytest.approx(
        ideal["success"]["recovery"]["recovery_time_s"], abs=2.0)


def test_its_thrust_keeps_its_limits_and_never_passes_the_sensor(runs):
    """Body axes: each thruster within ±1 N and, when it fires, at least the minimum
    impulse bit over the 1 s period; the wheels within ±0.1 N m. The F/T chain and the
    ODS's external input see the push and nothing of the thrust."""
    _, _, rows, ix = runs["hil"]
    cols = lambda names: rows[:, [ix[f"sat1_{n}"] for n in names]]  # noqa: E731
    force_R = cols(("gnc_fx_N", "gnc_fy_N", "gnc_fz_N"))
    force_B = np.einsum("kji,kj->ki", quat_to_matrix(cols(("qw", "qx", "qy", "qz"))), force_R)
    assert np.max(np.abs(force_B)) == pytest.approx(GNC.thrust_max_N, rel=1e-9)  # saturates
    fired = np.abs(force_B[np.abs(force_B) > 1e-9])  # (the CSV's 12 digits, turned)
    assert fired.size and fired.min() * GNC.period_s >= GNC.min_impulse_bit_Ns * (1 - 1e-6)
    torque = cols(("gnc_tx_Nm", "gnc_ty_Nm", "gnc_tz_Nm"))
    assert 0.0 < np.max(np.abs(torque)) <= GNC.torque_max_Nm
    t = rows[:, 0]
    outside = (t < PULSE.start_s) | (t > PULSE.end_s + 0.1)
    sensed = rows[:, [ix[f"rob1_pft_f{a}_N"] for a in "xyz"]]
    external = cols(("fx_N", "fy_N", "fz_N"))
    assert np.all(sensed[outside] == 0.0) and np.all(external[outside] == 0.0)
    assert np.max(np.abs(force_R[outside])) > 0.5  # while thrusting hard
    assert np.any(np.all(force_R == 0.0, axis=1))  # and coasting in the MIB's dead zone
    assert np.max(np.abs(external[~outside, 1])) > 10.0  # the push went through


def test_its_bag_carries_the_gnc_wrench(runs):
    """``/sat1/gnc_wrench``: the recorded GNC wrench, in the body frame, at the bag's 5 Hz."""
    pytest.importorskip("rosbags")
    from tests.runs.test_bag import _read

    _, _, rows, ix = runs["hil"]
    types, messages = _read(runs["hil_bag"])
    assert types["/sat1/gnc_wrench"] == "geometry_msgs/msg/WrenchStamped"
    kept = rows[::100]  # 5 Hz of 500
    assert len(messages["/sat1/gnc_wrench"]) == len(kept)
    k = int(np.argmax(np.abs(kept[:, ix["sat1_gnc_fx_N"]])))
    msg = messages["/sat1/gnc_wrench"][k][1]
    assert msg.header.frame_id == "sat1"
    R_R_B = quat_to_matrix(kept[k, [ix[f"sat1_q{a}"] for a in "wxyz"]])
    force_B = R_R_B.T @ kept[k, [ix[f"sat1_gnc_f{a}_N"] for a in "xyz"]]
    np.testing.assert_allclose([msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z],
                               force_B, rtol=1e-9, atol=1e-12)
    assert abs(force_B[0]) > 0.1


def test_a_run_that_stops_short_of_its_waypoints_does_not_pass(runs):
    """The ideal run's first 8 s: the first waypoint only, the push not yet over; the
    criteria say so, and so does the summary."""
    _, _, rows, index = runs["ideal"]
    s = success_metrics(CFG, rows[rows[:, 0] <= 8.0], index)
    assert s["passed"] is False and s["waypoints"]["reached"] == 1
    assert s["final_position"]["passed"] is False
    assert s["recovery"]["recovery_time_s"] is None and s["recovery"]["passed"] is False
    text = "\n".join(gnc_success_lines(s))
    assert "1 of 3 reached" in text and "the run ended before its push did (113.0 s" in text
