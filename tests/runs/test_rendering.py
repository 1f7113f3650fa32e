"""How well the mockups rendered a contact (app/runs/rendering.py, Eq. R1): the formula on
telemetry whose answer is known, and through `orbit-emulator run` the physics it tells
apart: a rigid contact the arms cannot follow at the shipped approach speed, and the same
contact at half the speed, which they can."""

import json
import shutil
import subprocess
import sys

import numpy as np
import pytest

from app.runs.rendering import (
    RENDERING_TOLERANCE,
    contact_geometry,
    rendering_error,
    rendering_warning,
)
from app.runs.report import forecast_text
from app.scenarios import load_scenario

EXE = shutil.which("orbit-emulator") or f"{sys.prefix}/bin/orbit-emulator"
DT_S = 0.002
MODEL = contact_geometry(load_scenario("collision"))
"""The collision's boxes: 0.2 m along x each, face to face along x at 0.2 m apart."""


def _telemetry(sat2_x, rob2_xyz):
    """Rows t, sat1 (at rest at the origin), sat2 (x from sat2_x(t)), rob1 (sat1's mockup,
    at the origin), rob2 (sat2's mockup at rob2_xyz(t)), all unrotated; its index."""
    t = np.arange(200) * DT_S
    fields = ("x_m", "y_m", "z_m", "qw", "qx", "qy", "qz")
    names = ["t_s", *(f"{p}{i}_{f}" for p in ("sat", "rob") for i in (1, 2) for f in fields)]
    index = {name: k for k, name in enumerate(names)}
    rows = np.zeros((len(t), len(names)))
    rows[:, 0] = t
    for p in ("sat1", "sat2", "rob1", "rob2"):
        rows[:, index[f"{p}_qw"]] = 1.0
    rows[:, index["sat2_x_m"]] = sat2_x(t)
    rows[:, [index[f"rob2_{a}_m"] for a in "xyz"]] = rob2_xyz(t)
    return rows, index


COLL = {"pair": ["sat1", "sat2"], "contact_start_s": 0.1, "contact_end_s": 0.2, "dt_s": DT_S}
BODIES = {1: "rob1", 2: "rob2"}


def _sat2_x(t):
    """sat2 0.8 mm into sat1 at the deepest, a half sine between 0.1 and 0.2 s."""
    return 0.2 - np.where((t >= 0.1) & (t <= 0.2), 8e-4 * np.sin(np.pi * (t - 0.1) / 0.1), 0.0)


def test_mockups_that_overlap_as_the_satellites_will_one_force_lag_later_render_exactly():
    lag_s = 2 * DT_S
    rows, index = _telemetry(_sat2_x, lambda t: np.c_[_sat2_x(t + lag_s), 0 * t, 0 * t])
    got = rendering_error(rows, index, COLL, BODIES, lag_s, MODEL)
    assert got["rendering_error_m"] == pytest.approx(0.0, abs=1e-9)
    assert got["rendering_error_max_m"] == pytest.approx(0.0, abs=1e-9)
    assert got["contact_depth_m"] == pytest.approx(8e-4, rel=1e-6)  # its deepest sample


def test_mockups_short_of_the_overlap_are_the_error_and_a_shift_across_is_not():
    """40 µm less deep while touching, and 1 mm aside (across the normal): the error is the
    40 µm; the same mockups one lag late are off by about the lag times the overlap's
    rate, where it changes fastest."""
    def rob2(t):
        touching = (t >= 0.1 - 1e-9) & (t <= 0.2 + 1e-9)
        return np.c_[_sat2_x(t) + np.where(touching, 40e-6, 0.0), 0 * t + 1e-3, 0 * t]

    rows, index = _telemetry(_sat2_x, rob2)
    got = rendering_error(rows, index, COLL, BODIES, 0.0, MODEL)
    assert got["rendering_error_max_m"] == pytest.approx(40e-6, rel=1e-6)
    # (at the touch's first and last samples the mockups, 40 µm short, are apart: less)
    assert 0.95 * 40e-6 < got["rendering_error_m"] < 40e-6
    late = rendering_error(rows, index, COLL, BODIES, 0.01, MODEL)
    rate = 8e-4 * np.pi / 0.1
    assert late["rendering_error_max_m"] > 40e-6 + 0.5 * 0.01 * rate


def test_the_warning_is_said_beyond_a_twentieth_of_the_contact_depth():
    depth = 800e-6
    within = {"rendering_error_m": 0.99 * RENDERING_TOLERANCE * depth,
              "contact_depth_m": depth, "restitution": 0.9}
    assert rendering_warning(within) is None
    beyond = {**within, "rendering_error_m": 0.2 * depth}
    assert rendering_warning(beyond) == (
        "the mockups did not render this contact: their rendering error (Eq. R1) is 20.0 % "
        "of the satellites' 800 µm contact depth, beyond 5 %; this restitution is the "
        "mockups' motion's as much as the contact law's, and can match the ideal one only "
        "by chance")
    assert rendering_warning({**beyond, "restitution": None}).endswith(
        "beyond 5 %; what the contact gave the satellites is the mockups' motion's as much "
        "as the contact law's")
    assert rendering_warning({**within, "rendering_error_m": None}) is None


def test_the_forecast_line_says_when_the_twin_s_arms_will_not_render_the_contact():
    fc = {"restitution_sd": 0.001, "peak_force_N": 11.0, "noise_force_N": 0.025,
          "peak_to_noise": 440.0, "restitution_error_mean": -0.227,
          "rendering_error_m": 157e-6, "contact_depth_m": 1088e-6}
    assert forecast_text(fc).endswith(
        "the chain's predicted mean error -23 %; the mockups will not render this contact "
        "(the noise-free twin's rendering error is 14 % of the contact depth)")
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
    asks the arms for about their acceleration limit, they round it off (a seventh of the
    contact depth), the restitution is off by a fifth and the run says why; at 0.04 m/s
    (half the acceleration) they render it to a twentieth, and the restitution is within
    10 % of the ideal."""
    fast, stdout = _rigid_run(tmp_path, 0.08, 3.4)
    assert fast["rendering_error_m"] > 0.1 * fast["contact_depth_m"]
    assert "WARNING: the mockups did not render this contact" in stdout
    assert abs(fast["restitution_error"]) > 0.15
    slow, _ = _rigid_run(tmp_path, 0.04, 6.6)
    assert slow["rendering_error_m"] < 0.06 * slow["contact_depth_m"]
    assert abs(slow["restitution_error"]) < 0.10
