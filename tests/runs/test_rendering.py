"""How well the arms rendered a contact (app/runs/rendering.py, Eq. R1): the formula on
telemetry whose answer is known, and through `orbit-emulator run` the physics it tells
apart: a rigid contact the arms cannot follow at the shipped approach speed, and the same
contact at half the speed, which they can."""

import json
import shutil
import subprocess
import sys

import numpy as np
import pytest

from app.runs.rendering import RENDERING_TOLERANCE, rendering_error, rendering_warning
from app.runs.report import forecast_text

EXE = shutil.which("orbit-emulator") or f"{sys.prefix}/bin/orbit-emulator"
DT_S = 0.002
POS = ("x_m", "y_m", "z_m")


def _telemetry(sat_b_x, mock_b_xyz):
    """Rows t, sat1 (at rest at the origin), sat2 (x from sat_b_x(t)), rob1 (sat1's mockup,
    at the origin), rob2 (sat2's mockup at mock_b_xyz(t)); its index."""
    t = np.arange(200) * DT_S
    names = ["t_s", *(f"sat{i}_{p}" for i in (1, 2) for p in POS),
             *(f"rob{i}_{p}" for i in (1, 2) for p in POS)]
    rows = np.zeros((len(t), len(names)))
    rows[:, 0] = t
    rows[:, 4] = sat_b_x(t)
    rows[:, 10:13] = mock_b_xyz(t)
    return rows, {name: k for k, name in enumerate(names)}


COLL = {"pair": ["sat1", "sat2"], "normal": [1.0, 0.0, 0.0],
        "contact_start_s": 0.1, "contact_end_s": 0.2}
BODIES = {1: "rob1", 2: "rob2"}


def _separation(t):
    """sat2's x: 0.30 m less a half sine of 0.8 mm between 0.1 and 0.2 s."""
    dip = np.where((t >= 0.1) & (t <= 0.2), 8e-4 * np.sin(np.pi * (t - 0.1) / 0.1), 0.0)
    return 0.30 - dip


def test_mockups_where_the_satellites_will_be_one_force_lag_later_render_exactly():
    lag_s = 2 * DT_S
    rows, index = _telemetry(_separation,
                             lambda t: np.c_[_separation(t + lag_s), 0 * t, 0 * t])
    got = rendering_error(rows, index, COLL, BODIES, lag_s)
    assert got["rendering_error_m"] == pytest.approx(0.0, abs=1e-12)
    assert got["rendering_error_max_m"] == pytest.approx(0.0, abs=1e-12)
    t = rows[:, 0][(rows[:, 0] >= 0.1 - 1e-9) & (rows[:, 0] <= 0.2 + 1e-9)]
    shifted = _separation(t + lag_s)
    assert got["approach_depth_m"] == pytest.approx(shifted.max() - shifted.min(), rel=1e-12)
    assert got["approach_depth_m"] == pytest.approx(8e-4, rel=0.01)


def test_an_offset_along_the_normal_is_the_error_and_one_across_it_is_not():
    """40 µm short along n while touching, and 1 mm aside (across n), everywhere: rms and
    largest error are the 40 µm; the same mockups one lag late are off by the lag times
    the approach's speed, where it moves."""
    def mock(t):
        touching = (t >= 0.1 - 1e-9) & (t <= 0.2 + 1e-9)
        return np.c_[_separation(t) + np.where(touching, 40e-6, 0.0), 0 * t + 1e-3, 0 * t]

    rows, index = _telemetry(_separation, mock)
    got = rendering_error(rows, index, COLL, BODIES, 0.0)
    assert got["rendering_error_m"] == pytest.approx(40e-6, rel=1e-9)
    assert got["rendering_error_max_m"] == pytest.approx(40e-6, rel=1e-9)
    late = rendering_error(rows, index, COLL, BODIES, 0.01)
    speed = 8e-4 * np.pi / 0.1  # the dip's largest rate
    assert late["rendering_error_max_m"] > 40e-6 + 0.5 * 0.01 * speed


def test_the_warning_is_said_beyond_a_tenth_of_the_approach_depth():
    depth = 800e-6
    assert rendering_warning({"rendering_error_m": 0.99 * RENDERING_TOLERANCE * depth,
                              "approach_depth_m": depth}) is None
    assert rendering_warning({"rendering_error_m": 0.2 * depth, "approach_depth_m": depth}) == (
        "the arms did not render this contact: its rendering error (Eq. R1) is 20 % of the "
        "approach depth, beyond 10 %; this restitution is the arms' as much as the contact "
        "law's, and can match the ideal one only by chance")
    assert rendering_warning({"rendering_error_m": None, "approach_depth_m": depth}) is None


def test_the_forecast_line_says_when_the_twin_s_arms_will_not_render_the_contact():
    fc = {"restitution_sd": 0.001, "peak_force_N": 11.0, "noise_force_N": 0.025,
          "peak_to_noise": 440.0, "restitution_error_mean": -0.227,
          "rendering_error_m": 157e-6, "approach_depth_m": 769e-6}
    assert forecast_text(fc).endswith(
        "the chain's predicted mean error -23 %; the arms will not render this contact "
        "(the noise-free twin's rendering error is 20 % of the approach depth)")
    assert forecast_text({**fc, "rendering_error_m": 26e-6}).endswith("error -23 %")


def _rigid_run(tmp_path, speed_mps: float, duration_s: float) -> tuple[dict, str]:
    out = tmp_path / f"v{speed_mps}"
    proc = subprocess.run(
        [EXE, "run", "collision", "--quiet", "--duration", str(duration_s),
         "--set", 'satellites.1.material="rigid"', "--set", 'sensor.model="ati-gamma"',
         "--set", "sensor.noise_force_N=0", "--set", "sensor.noise_torque_Nm=0",
         "--set", f"satellites.0.velocity_mps=[{speed_mps},0,0]",
         "--set", f"satellites.1.velocity_mps=[{-speed_mps},0,0]",
         "--set", "uncertainty.enabled=false", "--out", str(out)],
        capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    return json.loads((out / "metrics.json").read_text())["collision"], proc.stdout


def test_a_rigid_contact_the_arms_cannot_follow_is_said_and_a_slower_one_is_rendered(
        tmp_path):
    """Rigid vs rigid with the ATI Gamma (noise off): at the shipped 0.08 m/s the contact
    asks the arms for about their acceleration limit, they round it off (a fifth of the
    approach depth) and the run says so; at 0.04 m/s they render it to a twentieth, and the
    restitution is within 10 % of the ideal."""
    fast, stdout = _rigid_run(tmp_path, 0.08, 3.4)
    assert fast["rendering_error_m"] > 0.15 * fast["approach_depth_m"]
    assert "WARNING: the arms did not render this contact" in stdout
    slow, stdout = _rigid_run(tmp_path, 0.04, 6.6)
    assert slow["rendering_error_m"] < 0.07 * slow["approach_depth_m"]
    assert "did not render" not in stdout
    assert abs(slow["restitution_error"]) < 0.10
    assert abs(fast["restitution_error"]) > 0.15
