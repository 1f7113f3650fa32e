"""`orbit-emulator propagate` end to end through the installed console script."""

import csv
import shutil
import subprocess
import sys

import numpy as np
import pytest

from app.sim.orbital import cw_state_transition, orbit_rate

EXE = shutil.which("orbit-emulator") or f"{sys.prefix}/bin/orbit-emulator"

SAT_COLUMNS = [
    "x_m", "y_m", "z_m", "vx_mps", "vy_mps", "vz_mps", "qw", "qx", "qy", "qz",
    "wx_radps", "wy_radps", "wz_radps", "fx_N", "fy_N", "fz_N", "tx_Nm", "ty_Nm", "tz_Nm",
]


def run_cli(*args):
    return subprocess.run([EXE, *args], capture_output=True, text=True, timeout=120)


def read_csv(path):
    with open(path) as fh:
        reader = csv.reader(fh)
        header = next(reader)
        rows = np.array([[float(x) for x in r] for r in reader])
    return header, rows


def test_writes_every_column_and_the_pulse_changes_velocity(tmp_path):
    cfg = tmp_path / "two.toml"
    cfg.write_text(
        """
[[satellites]]
name = "a"
position_m = [0.2, 0.0, 0.0]
velocity_mps = [0.0, 0.001, 0.0]

[[satellites]]
name = "b"
mass_kg = 2.0

[[pulses]]
satellite = "b"
start_s = 1.0
end_s = 1.5
force_N = [0.0, 4.0, 0.0]
torque_Nm = [0.0, 0.0, 0.5]
"""
    )
    result = run_cli("propagate", "--config", str(cfg), "--duration", "10", "--dt", "0.01",
                     "--out", str(tmp_path / "out"))
    assert result.returncode == 0, result.stderr
    header, rows = read_csv(tmp_path / "out" / "telemetry.csv")
    assert header == ["t_s"] + [f"sat{i}_{c}" for i in (1, 2) for c in SAT_COLUMNS]
    assert len(rows) == 1001
    col = {name: k for k, name in enumerate(header)}
    # the pulse is recorded while active and gives impulse / mass = 2 N s / 2 kg
    active = (rows[:, 0] >= 1.0) & (rows[:, 0] < 1.5 - 1e-9)
    assert np.all(rows[active, col["sat2_fy_N"]] == 4.0)
    assert np.all(rows[~active, col["sat2_fy_N"]] == 0.0)
    assert rows[-1, col["sat2_vy_mps"]] == pytest.approx(1.0, rel=1e-3)
    # satellite 1 follows the closed-form CW solution
    x0 = np.array([0.2, 0, 0, 0, 0.001, 0])
    expected = cw_state_transition(orbit_rate(800e3), 10.0) @ x0
    got = [rows[-1, col[f"sat1_{c}"]] for c in SAT_COLUMNS[:6]]
    np.testing.assert_allclose(got, expected, atol=1e-9)


def test_defaults_without_config(tmp_path):
    result = run_cli("propagate", "--duration", "1", "--dt", "0.1", "--out", str(tmp_path))
    assert result.returncode == 0, result.stderr
    header, rows = read_csv(tmp_path / "telemetry.csv")
    assert len(rows) == 11 and header[1] == "sat1_x_m"


@pytest.mark.parametrize(
    "toml, message",
    [
        ('[[satellites]]\nname = "a"\nmass_kg = -1\n', "satellites.0.mass_kg"),
        ('[orbit]\naltitude = 1\n', "orbit.altitude: Extra inputs are not permitted"),
        ('[[satellites]]\nname = "a"\nattitude_wxyz = [0, 0, 0, 0]\n',
         "satellites.0.attitude_wxyz: quaternion must be non-zero"),
    ],
)
def test_bad_config_exits_nonzero_naming_the_field(tmp_path, toml, message):
    cfg = tmp_path / "bad.toml"
    cfg.write_text(toml)
    result = run_cli("propagate", "--config", str(cfg), "--duration", "1", "--out", str(tmp_path))
    assert result.returncode == 2
    assert message in result.stderr
    assert not (tmp_path / "telemetry.csv").exists()


def test_bad_numbers_on_the_command_line(tmp_path):
    result = run_cli("propagate", "--dt", "nan", "--out", str(tmp_path))
    assert result.returncode == 2 and "must be a positive finite number" in result.stderr
