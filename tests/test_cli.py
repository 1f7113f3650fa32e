"""The command line's answers to a user's mistakes: a message naming the argument, exit 2,
no traceback (and nothing run or written)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import pytest

EXE = shutil.which("orbit-emulator") or f"{sys.prefix}/bin/orbit-emulator"

MISTAKES = {
    "config is a directory": (["run", "collision", "--config", "/tmp"],
                              "/tmp: is a directory, not a TOML file"),
    "out cannot be created": (["run", "collision", "--out", "/dev/null/x", "--duration", "0.1"],
                              "--out: cannot create the directory '/dev/null/x'"),
    "propagate too long": (["propagate", "--duration", "1e9", "--dt", "1e-6"],
                           "--duration / --dt: 1e+09 s in steps of 1e-06 s is 1e+15 steps"),
    "run too long": (["run", "collision", "--duration", "1e9"],
                     "--duration: 1e+09 s at 500 Hz is 5e+11 cycles"),
    "robot index": (["run", "collision", "--set", "robots.5.q_home_rad=[0,0,0,0,0,0]"],
                    "robots.5: index out of range: the list has 2 item(s), indices 0..1"),
    "satellite index": (["run", "collision", "--set", "satellites.2.mass_kg=2"],
                        "satellites.2: index out of range"),
    "out of reach": (["run", "collision", "--set", "satellites.0.position_m=[3,0,0]",
                      "--duration", "1", "--out", "OUT"],
                     "pre-flight: the ideal run predicts that robot 1 (ceiling): satellite "
                     "'cubesat' leaves the safety volume (at (3.000, 0.000, 1.000) m in W"),
    "bad value": (["run", "collision", "--set", "compensation.lead_s=-1"],
                  "compensation.lead_s: Input should be greater than 0"),
}


@pytest.mark.parametrize("case", list(MISTAKES))
def test_a_mistake_is_named_with_exit_2_and_no_traceback(case, tmp_path):
    argv, message = MISTAKES[case]
    argv = [str(tmp_path / "out") if a == "OUT" else a for a in argv]
    proc = subprocess.run([EXE, *argv, *(["--quiet"] if argv[0] == "run" else [])],
                          capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr
    assert message in proc.stderr, proc.stderr
    assert not (tmp_path / "runs").exists()  # nothing ran to completion, nothing written
    assert not (tmp_path / "out").exists()


def test_scenarios_lists_every_scenario_with_its_description_in_one_column():
    from app.scenarios import scenario_descriptions

    proc = subprocess.run([EXE, "scenarios"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    described = scenario_descriptions()
    assert [line.split()[0] for line in lines] == list(described)
    columns = {line.index(desc) for line, desc in zip(lines, described.values(), strict=True)}
    assert len(columns) == 1 and min(columns) > max(map(len, described))


def test_an_empty_list_override_clears_the_list():
    from app.config import assignment_override, merge_overrides
    from app.scenarios import load_scenario

    cfg = load_scenario("free-floating-scripted")
    assert len(cfg.pulses) == 10
    assert merge_overrides(cfg, {"pulses": []}).pulses == []
    assert merge_overrides(cfg, assignment_override("pulses=[]")).pulses == []


def test_a_safety_stop_exits_3_and_names_the_collision_it_never_reached(tmp_path):
    """A run stopped before its collision: exit 3, files written, and the warning that the
    ideal run collides while this one had no contact (no silent `collision: null`)."""
    out = tmp_path / "out"
    proc = subprocess.run(
        [EXE, "run", "collision", "--duration", "4", "--out", str(out), "--quiet",
         "--set", "loop.max_tracking_error_m=1e-5"],
        capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert proc.returncode == 3, proc.stderr
    assert "Traceback" not in proc.stderr
    assert "error: the run ended in a safety stop at t = " in proc.stderr
    metrics = json.loads((out / "metrics.json").read_text())
    stop = metrics["safety_stop"]
    assert stop["reason"].startswith("tracking error ") and stop["t_s"] < 3.0
    assert metrics["collision"] is None
    [warning] = metrics["warnings"]
    assert warning.startswith("in the ideal run sat1 and sat2 collide at t = 3.1")
    assert warning.endswith(f"this run had no contact: it ended in a safety stop at t = "
                            f"{stop['t_s']:.3f} s")
    assert f"WARNING: {warning}" in proc.stdout
    assert (out / "telemetry.csv").exists()


def _strict_json(path) -> dict:
    """A JSON file read strictly: NaN and Infinity (not JSON) are refused."""
    def refuse(name):
        raise ValueError(f"{path}: {name} is not JSON")

    return json.loads(path.read_text(), parse_constant=refuse)


INFINITE_METRICS = {
    # a velocity past float range: the satellite's delta-v overflows
    "delta-v": (["collision", "--set", "satellites.0.velocity_mps=[1e300,0,0]"],
                ("satellites", 0, "delta_v_mps")),
}


@pytest.mark.parametrize("case", list(INFINITE_METRICS))
def test_an_infinite_metric_is_written_as_null(case, tmp_path):
    """metrics.json is written whatever its figures: a non-finite one is null (JSON has no
    Infinity), and the plots are written after it."""
    argv, path = INFINITE_METRICS[case]
    out = tmp_path / "out"
    proc = subprocess.run([EXE, "run", *argv, "--mode", "ideal", "--duration", "1",
                           "--out", str(out), "--quiet"],
                          capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    metrics = _strict_json(out / "metrics.json")
    value = metrics
    for key in path:
        value = value[key]
    assert value is None
    assert metrics["status"] == "finished"
    assert sorted(p.suffix for p in out.iterdir()).count(".png") >= 1


def test_a_run_that_raises_once_started_keeps_what_it_recorded_with_status_error(tmp_path):
    """No valid configuration is known to make a run raise once started (the last one, a
    CW transfer crossing half an orbit, is fixed), so the fault comes through the run's
    own progress callback, as an interrupted display's would: what it recorded up to then
    is written, and metrics.json says status "error" and why (the CLI then exits 4)."""
    from app.headless import RunFailed, run_scenario
    from app.scenarios import load_scenario

    def fail_at_1000(k, n):
        if k >= 1000:
            raise OSError("the display went away")

    out = tmp_path / "out"
    with pytest.raises(RunFailed) as err:
        run_scenario(load_scenario("collision"), mode="ideal", duration_s=4.0, out_dir=out,
                     progress=fail_at_1000)
    reason = "OSError: the display went away"
    assert str(err.value) == reason
    metrics = _strict_json(out / "metrics.json")
    assert (metrics["status"], metrics["error"]) == ("error", reason)
    rows = (out / "telemetry.csv").read_text().splitlines()
    assert len(rows) - 1 == metrics["cycles"] >= 1000


@pytest.mark.parametrize("setting", ['sensor.model="ati-gamma"', 'sensor.model="ati-mini45"',
                                     'sensor.model="robotiq-ft300s"',
                                     'sensor.placement="mockup"', 'servo.model="servoj"'])
def test_the_collision_runs_on_each_rig_without_a_stop(setting, tmp_path):
    """The shipped collision on the lab's rig of choice (docs/sensors.md), through the
    contact (which starts at 3.1 s): exit 0, status finished."""
    out = tmp_path / "out"
    proc = subprocess.run([EXE, "run", "collision", "--quiet", "--duration", "3.5",
                           "--set", setting, "--out", str(out)],
                          capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["status"] == "finished" and metrics["safety_stop"] is None
    assert metrics["collision"]["contact_start_s"] < 3.3
