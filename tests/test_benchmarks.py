"""Smoke tests of the benchmark scripts (--quick): they run and print every table."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(module: str, timeout_s: float = 120) -> str:
    proc = subprocess.run(
        [sys.executable, "-m", module, "--quick"], cwd=ROOT, capture_output=True, text=True,
        timeout=timeout_s,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout


def test_loop_speed_quick():
    out = _run("benchmarks.loop_speed")
    for line in ("## Cycle breakdown: collision", "## Cycle breakdown: free-floating-scripted",
                 "| arm 1: target, VFDM, servo, FK |", "| arm 2: target, VFDM, servo, FK |",
                 "| ODS step |", "| contact (coal) |",
                 "| telemetry row |", "| F/T sensor + processing |",
                 "| actual mockups (arm FK + twist) |", "| ODS coupling (passivity) |",
                 "| rest (glue) |", "**total cycle**",
                 "## Real-time factor", "| collision |", "| free-floating-scripted |",
                 "## VFDM cost per arm per cycle", "| 10 |", "## Targets",
                 "VFDM <= 100", "collision hil realtime_factor >= 10"):
        assert line in out, line


def test_loop_speed_cold_row_takes_each_chunks_first_cycle_apart():
    """The cold-cycle row: per tree, the median of each chunk's first cycle and the p99 of
    the others (here every other cycle is 10 or 20 µs, every first 100 or 50 µs)."""
    from benchmarks.loop_speed import _cold_row

    this = [np.r_[100.0, np.full(99, 10.0)] for _ in range(5)]
    other = [np.r_[50.0, np.full(99, 20.0)] for _ in range(5)]
    assert _cold_row("collision", "hil", [this, other]) == (
        "| collision | hil | 100.0 / 50.0 (2.000) | 10.0 / 20.0 (0.500) |")


def test_ik_compare_quick():
    out = _run("benchmarks.ik_compare")
    assert "Pink" in out
    assert "| trajectory | method |" in out
    for name in ("VFDM", "pseudo-inverse", "DLS", "J transpose"):
        assert f"| {name}" in out, name
    for case in ("collision/ceiling 500 Hz", "held 10 Hz", "held 2 Hz",
                 "free-floating-scripted/ceiling", "singular/wrist", "singular/elbow",
                 "singular/shoulder"):
        assert case in out, case
    # the 7-joint chain (a UR10e on a rail): its table, after the others
    rail = out[out.index("## The 7-joint chain"):]
    assert "| path | method | protective stop |" in rail
    for case in ("singular/wrist q5=0", "singular/elbow stretched",
                 "singular/shoulder (over base)", "1.5 m along the rail and back"):
        for name in ("VFDM + posture (rail)", "DLS 7-joint (λ=0.05)", "DLS 7-joint + posture"):
            assert f"| {case} | {name} |" in rail, (case, name)
    ramp = next(line for line in rail.splitlines()
                if line.startswith("| 1.5 m along the rail and back | VFDM"))
    assert ramp.split("|")[3].strip() == "none"  # no protective stop
    assert float(ramp.split("|")[6]) > 1.45  # the rail carried the ramp


def test_contact_fidelity_quick():
    out = _run("benchmarks.contact_fidelity", timeout_s=400)
    for line in ("## Collision", "| sponge vs rigid (e_ideal", "| rigid vs rigid (e_ideal",
                 "| paper |", "| passivity |", "| compensated |", "| comp., no noise |",
                 "## Free-floating", "| chain | status | tracking max |"):
        assert line in out, line


def test_push_limit_quick():
    """A push at the limit with the hand at its cap, along the weight, stays below the
    sensor's range and the run goes on."""
    out = _run("benchmarks.push_limit")
    row = next(line for line in out.splitlines() if line.startswith("| free-floating |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    limit_N, range_N, peak_N = float(cells[1]), float(cells[2]), float(cells[3])
    assert limit_N + 20.0 < peak_N < range_N, row  # the push, the hand, the weight: below
    assert cells[5] == "0 of 1", row


def test_push_follow_quick():
    """The arm follows a push at the force limit in collision to a velocity change at
    least twice the web app's limit (the margin the limit claims), and the script says
    what it derives."""
    from app.backend.service import MAX_PUSH_DV_MPS, MOTION_MARGIN

    out = _run("benchmarks.push_follow")
    row = next(line for line in out.splitlines() if line.startswith("| collision |"))
    followed = float(row.strip("|").split("|")[-1])
    assert followed >= MAX_PUSH_DV_MPS / MOTION_MARGIN, row
    assert f"the web app's MAX_PUSH_DV_MPS = {MAX_PUSH_DV_MPS:g} m/s" in out


def test_the_rig_table_cell_reads_the_contact_measurement_metrics_when_present():
    """benchmarks.contact_fidelity --rig-table: interval coverage counts the runs whose
    restitution_interval_95 holds the ideal restitution, the forecast column is the mean
    forecast sd over the across-seed sd, the off-normal share is found by its name; all
    None while the metrics lack them (before the contact-measurement chain)."""
    from benchmarks.contact_fidelity import rig_cell

    ideal = {"restitution": 0.30}
    runs = [{"collision": {"restitution": e, "restitution_error": e / 0.30 - 1.0,
                           "restitution_interval_95": [e - 0.02, e + 0.02],
                           "off_normal_share": 0.1},
             "forecast": {"restitution_sd": 0.02}, "status": "finished"}
            for e in (0.29, 0.31, 0.35)]
    cell = rig_cell(runs, ideal)
    assert cell["covered"] == 2  # 0.35 ± 0.02 misses 0.30
    assert cell["forecast_ratio"] == pytest.approx(0.02 / np.std([0.29, 0.31, 0.35], ddof=1))
    assert cell["off_normal"] == pytest.approx(0.1)
    assert cell["stops"] == 0 and cell["refused"] is None
    bare = rig_cell([{"collision": {"restitution": 0.3, "restitution_error": 0.0},
                      "forecast": None, "status": "safety_stop"}], ideal)
    assert bare["covered"] is None and bare["forecast_ratio"] is None
    assert bare["off_normal"] is None and bare["stops"] == 1


def test_replicate_speed_quick():
    out = _run("benchmarks.replicate_speed")
    assert "## Replicates: 1 round(s)" in out
    for setting in ("collision (shipped, sponge 500 N/m)",
                    "stiff contact (sponge 8000 N/m, 3.5 s)"):
        for call, replicates in (("forecast", 6), ("interval", 4)):
            row = next(line for line in out.splitlines()
                       if line.startswith(f"| {setting} | {call} | this tree |"))
            cells = [c.strip() for c in row.split("|")[1:-1]]
            assert int(cells[4]) == replicates, row  # every replicate counted
            assert float(cells[5]) > 20, row  # each steps its contact window
            assert all(float(c) > 0 for c in cells[6:10]), row


@pytest.mark.parametrize("flag", ["--chunks", "--chunk-cycles"])
def test_loop_speed_refuses_chunks_of_nothing(flag):
    """--chunks / --chunk-cycles 0: argparse's usage error at once, not a division by
    zero after the emulators were built."""
    proc = subprocess.run([sys.executable, "-m", "benchmarks.loop_speed", "--against",
                           str(ROOT), flag, "0"], cwd=ROOT, capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 2
    assert f"argument {flag}: must be at least 1, got 0" in proc.stderr
