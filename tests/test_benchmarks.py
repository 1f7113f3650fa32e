"""Smoke tests of the benchmark scripts (--quick) and the compiled VFDM kernel's equality."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from app.scenarios import load_scenario
from app.sim import vfdm as vfdm_module
from app.sim.rotations import make_transform, rotvec_to_matrix
from app.sim.ur10e import T_F_C_from_config
from app.sim.vfdm import Vfdm

ROOT = Path(__file__).resolve().parents[1]


def _run(module: str) -> str:
    proc = subprocess.run(
        [sys.executable, "-m", module, "--quick"], cwd=ROOT, capture_output=True, text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout


def test_loop_speed_quick():
    out = _run("benchmarks.loop_speed")
    for line in ("## Cycle breakdown", "| VFDM arm 1 |", "| servo arm 2 |", "| ODS step |",
                 "| contact |", "| telemetry (_record) |", "**total cycle**",
                 "| stage | reference µs / cycle | compiled µs / cycle | speed-up |",
                 "| F/T chain (sensor+processing) |", "| bookkeeping (rest) |",
                 "## Whole cycle by switch", "| every switch off (Python reference) |",
                 "| only the VFDM kernel on", "| all on but servo (UR10eServo.use_kernel) |",
                 "| every switch on (default) |",
                 "## Real-time factor", "| collision |", "| free-floating |",
                 "| compiled (run_scenario) |", "| reference |",
                 "## VFDM cost per arm per cycle", "| 10 |", "## Targets",
                 "VFDM <= 100", "collision hil realtime_factor >= 10"):
        assert line in out, line


def test_ik_compare_quick():
    out = _run("benchmarks.ik_compare")
    assert "Pink" in out
    assert "| trajectory | method |" in out
    for name in ("VFDM", "pseudo-inverse", "DLS", "J transpose"):
        assert f"| {name}" in out, name
    for case in ("collision/ceiling 500 Hz", "held 10 Hz", "held 2 Hz", "free-floating/ceiling",
                 "singular/wrist", "singular/elbow", "singular/shoulder"):
        assert case in out, case


@pytest.mark.skipif(vfdm_module._solve_compiled is None, reason="numba missing")
@pytest.mark.parametrize(
    "update", [{}, {"velocity_mode": "reset"}, {"kd_lin": 5.0, "kd_rot": 1.0}, {"iterations": 50}]
)
def test_kernel_equals_python_reference(update):
    """The compiled path gives the Python/pinocchio path's results to 1e-9, over a long run
    that reaches the error clamps and (first joint) the position limit."""
    cfg = load_scenario("collision")
    robot = cfg.robots[1]
    vcfg = cfg.vfdm.model_copy(update=update)
    T_F_C = T_F_C_from_config(robot)
    q0 = np.array(robot.q_home_rad)
    q0[0] = 2 * np.pi - 0.05
    ref, fast = Vfdm(vcfg, T_F_C, q0), Vfdm(vcfg, T_F_C, q0)
    ref.use_kernel, fast.use_kernel = False, True
    T0 = ref.tcp_pose().copy()
    for k in range(600):
        w = np.array([0.0, 0.3 * np.sin(k / 60), 2.0 * k / 100])
        T = T0 @ make_transform(rotvec_to_matrix(w), np.zeros(3))
        T[:3, 3] = T0[:3, 3] + np.array([0.3 * np.sin(k / 40), 0.2 * np.sin(k / 25), 0.1])
        np.testing.assert_allclose(fast.solve(T), ref.solve(T), rtol=0, atol=1e-9)
        np.testing.assert_allclose(fast.qd_radps, ref.qd_radps, rtol=0, atol=1e-9)
        np.testing.assert_allclose(fast.last_error, ref.last_error, rtol=0, atol=1e-9)
