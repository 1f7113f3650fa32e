"""The tumbling-target scenario through the CLI: a chaser synchronises with a target
spinning about its major axis and holds the capture point that turns with it, on the
arms as in the ideal run; a capture point out of the arm's reach is refused."""

from __future__ import annotations

import json
import math
import subprocess

import numpy as np
import pytest

from app.runs.success import success_metrics
from app.scenarios import load_scenario
from tests.test_cli import EXE

CFG = load_scenario("tumbling-target")
GNC = CFG.satellites[0].gnc


def _run(out, *args) -> tuple[subprocess.CompletedProcess, dict, np.ndarray, dict]:
    proc = subprocess.run([EXE, "run", "tumbling-target", "--out", str(out), "--quiet", *args],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    lines = (out / "telemetry.csv").read_text().splitlines()
    index = {name: k for k, name in enumerate(lines[0].split(","))}
    return (proc, json.loads((out / "metrics.json").read_text()),
            np.loadtxt(lines[1:], delimiter=","), index)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    out = tmp_path_factory.mktemp("tumbling")
    return {"hil": _run(out / "hil"), "ideal": _run(out / "ideal", "--mode", "ideal")}


def test_the_chaser_holds_the_capture_point_synchronised_on_the_arms(runs):
    proc, m, rows, ix = runs["hil"]
    assert m["status"] == "finished" and m["safety_stop"] is None
    s = m["success"]
    assert s["passed"], s
    sync = s["synchronisation"]
    assert sync["target"] == "target" and sync["waypoint"] == 2
    assert sync["hold_s"] == pytest.approx(GNC.waypoints[-1].hold_s, abs=0.01)
    assert sync["position_error_max_m"] <= 0.01
    assert sync["attitude_error_max_rad"] <= math.radians(1.0)
    assert sync["rate_error_max_radps"] < math.radians(0.1)
    # the target kept spinning at its 2 deg/s about z, and the chaser turned with it
    w_t = rows[:, ix["sat2_wz_radps"]]
    assert np.all(np.abs(w_t - math.radians(2.0)) < 1e-4)
    at = np.argmin(np.abs(rows[:, 0] - sync["at_s"]))
    w_c = rows[at, [ix[f"sat1_w{a}_radps"] for a in "xyz"]]
    np.testing.assert_allclose(w_c, [0.0, 0.0, math.radians(2.0)], atol=math.radians(0.1))
    for sat in m["satellites"]:
        assert sat["position_error_max_m"] < 1e-3 and sat["attitude_error_max_rad"] < 0.01
    assert "synchronisation of chaser with target at its capture point" in proc.stdout


def test_hil_and_ideal_agree_within_the_tracking_tolerance(runs):
    _, hil, rows_h, ix = runs["hil"]
    _, ideal, rows_i, _ = runs["ideal"]
    assert ideal["success"]["passed"]
    pos = [ix[f"sat1_{a}_m"] for a in "xyz"]
    gap = np.max(np.linalg.norm(rows_h[:, pos] - rows_i[:, pos], axis=1))
    assert gap < CFG.loop.max_tracking_error_m / 50  # 1 mm
    a, b = hil["success"]["synchronisation"], ideal["success"]["synchronisation"]
    assert a["at_s"] == pytest.approx(b["at_s"], abs=0.5)
    assert a["attitude_error_max_rad"] == pytest.approx(b["attitude_error_max_rad"],
                                                        abs=math.radians(0.1))


def test_a_run_that_ends_before_the_capture_point_does_not_pass(runs):
    """The ideal run's first 20 s: synchronised at 0.5 m, not yet at the capture point."""
    _, _, rows, index = runs["ideal"]
    s = success_metrics(CFG, rows[rows[:, 0] <= 20.0], index)
    assert s["passed"] is False and s["waypoints"]["reached"] == 1
    assert s["synchronisation"]["at_s"] is None and s["synchronisation"]["passed"] is False


def test_a_capture_point_out_of_the_arm_s_reach_is_refused_before_the_arms_move(tmp_path):
    """The target turned half a turn: its -x face, and the capture point with it, on the
    floor arm's side, beyond the ceiling arm's reach."""
    out = tmp_path / "far"
    proc = subprocess.run([EXE, "run", "tumbling-target", "--out", str(out), "--quiet",
                           "--duration", "15",  # it leaves the reach at 11.7 s
                           "--set", "satellites.1.attitude_wxyz=[0.3420201, 0, 0, 0.9396926]"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode != 0
    assert ("pre-flight: the ideal run predicts that robot 1 (ceiling): satellite 'chaser' "
            "leaves the arm's reach") in proc.stderr, proc.stderr
    assert not out.exists()
