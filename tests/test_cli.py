"""The command line's answers to a user's mistakes: a message naming the argument, exit 2,
no traceback (and nothing run or written)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

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
    "one replicate": (["run", "collision", "--set", "uncertainty.replicates=1"],
                      "uncertainty.replicates: must be 2 or more (a standard deviation needs "
                      "two replicates), got 1"),
    "shoulder singularity": (["run", "collision", "--set", "loop.duration_s=12", "--set",
                              'satellites.1.material="rigid"', "--set", "loop.seed=9001"],
                             "pre-flight: the ideal run predicts that robot 1 (ceiling): "
                             "satellite 'cubesat' leaves the arm's reach (its wrist would come "
                             "within 0.078 m of its base axis; inner limit 0.194 m, the "
                             "shoulder singular "
                             "at 0.174 m) at t = 10.47 s; robot 2 (floor): satellite 'sponge' "
                             "leaves the arm's reach (its wrist would come within 0.078 m of its "
                             "base axis; inner limit 0.194 m, the shoulder singular at "
                             "0.174 m) at "
                             "t = 10.47 s; and before "
                             "any of that, at t = 3.12 s, the mockups of 'cubesat' and "
                             "'sponge' touch (up to 11 N). The arms have not moved"),
    "uncertainty keys while off": (["run", "collision", "--set", "uncertainty.enabled=false",
                                    "--set", "uncertainty.replicates=8"],
                                   "uncertainty: replicates is set but enabled is false: it "
                                   "would have no effect (set enabled = true, or leave it "
                                   "out)"),
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
    assert stop["reason"].startswith("tracking error: position ") and stop["t_s"] < 3.0
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
    from app.runs.headless import RunFailed, run_scenario
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


# --- file inputs: a regular file under a cap, never a device or a FIFO --------------------

TOML_RULE = "a TOML file must be a regular file of at most 1 MiB"


def _inputs(tmp_path):
    """A FIFO, a directory, a file one byte over the cap and a link to /dev/zero, all
    named *.toml beside each other."""
    os.mkfifo(tmp_path / "fifo.toml")
    (tmp_path / "dir.toml").mkdir()
    with open(tmp_path / "big.toml", "wb") as f:
        f.truncate((1 << 20) + 1)
    (tmp_path / "zero.toml").symlink_to("/dev/zero")


FILE_INPUTS = {
    "/dev/zero": ("/dev/zero", f"error: /dev/zero: is a character device; {TOML_RULE}"),
    "link to /dev/zero": ("zero.toml", f"error: zero.toml: is a character device; {TOML_RULE}"),
    "FIFO": ("fifo.toml", f"error: fifo.toml: is a FIFO (named pipe); {TOML_RULE}"),
    "directory": ("dir.toml", "error: dir.toml: is a directory, not a TOML file"),
    "oversize": ("big.toml", f"error: big.toml: is 1,048,577 bytes; {TOML_RULE}"),
}


@pytest.mark.parametrize("case", list(FILE_INPUTS))
def test_run_config_must_be_a_regular_file_under_1_mib(case, tmp_path):
    """`--config /dev/zero` once grew to 23.5 GB; a FIFO hung: both are refused by their
    type before being opened (the timeout fails the test should one hang)."""
    _inputs(tmp_path)
    path, message = FILE_INPUTS[case]
    proc = subprocess.run([EXE, "run", "collision", "--config", path, "--quiet"],
                          capture_output=True, text=True, timeout=30, cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr == message + "\n"
    assert not (tmp_path / "runs").exists()


@pytest.mark.parametrize("case", ["link to /dev/zero", "FIFO", "directory", "oversize"])
def test_a_scenario_file_extends_only_a_regular_file_under_1_mib(case, tmp_path):
    _inputs(tmp_path)
    path, message = FILE_INPUTS[case]
    (tmp_path / "mine.toml").write_text(f'extends = "{path}"\n')
    proc = subprocess.run([EXE, "run", "collision", "--config", "mine.toml", "--quiet"],
                          capture_output=True, text=True, timeout=30, cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr == message + "\n"


# --- list indices: ASCII digits, at most 6 --------------------------------------------------

INDEX_RULE = "a list item's index is written in 1 to 6 ASCII digits (0-9), got"


@pytest.mark.parametrize("index, shown", [
    ("1" * 4301, "'111111111111'... (4301 characters)"),  # past int()'s digit limit
    ("\u0661", "'\u0661'"),  # ARABIC-INDIC DIGIT ONE: str.isdigit() says yes
    ("0000001", "'0000001'"),
])
def test_a_list_index_is_a_short_ascii_number_named_with_its_setting(index, shown):
    proc = subprocess.run([EXE, "run", "collision", "--set", f"satellites.{index}.mass_kg=2",
                           "--quiet"], capture_output=True, text=True, timeout=30)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr == f"error: satellites: {INDEX_RULE} {shown}\n"


# --- output files: checked before the run, never lost after it ------------------------------

def test_an_output_file_that_is_a_directory_is_refused_before_the_run(tmp_path):
    out = tmp_path / "out"
    (out / "telemetry.csv").mkdir(parents=True)
    t0 = time.perf_counter()
    proc = subprocess.run([EXE, "run", "collision", "--mode", "ideal", "--out", str(out),
                           "--quiet"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr == (f"error: {out}/telemetry.csv: exists and is a directory; the run "
                           f"writes a file there: move it away or choose another --out\n")
    assert sorted(p.name for p in out.iterdir()) == ["telemetry.csv"]  # nothing written
    assert time.perf_counter() - t0 < 15  # the 12 s scenario did not run


def test_a_file_that_cannot_be_written_after_the_run_goes_elsewhere_and_exits_5(
        tmp_path, capsys):
    """The output becomes unwritable while the run goes on (a directory appears where
    telemetry.csv goes): the other files are written, telemetry.csv is written to a fresh
    temporary folder, and `run` says so on stderr and exits 5."""
    from app.cli import EXIT_NOT_WRITTEN, _report_run
    from app.runs.headless import run_scenario
    from app.scenarios import load_scenario

    out = tmp_path / "out"

    def block_at_500(k, n):  # (called every 500 cycles)
        if k >= 500 and not (out / "telemetry.csv").exists():
            (out / "telemetry.csv").mkdir(parents=True)

    result = run_scenario(load_scenario("collision"), mode="ideal", duration_s=1.5,
                          out_dir=out, progress=block_at_500)
    assert (out / "metrics.json").is_file() and (out / "telemetry.csv").is_dir()
    fallback = result.unwritten.fallback
    assert fallback.parent == Path(tempfile.gettempdir())
    written = (fallback / "telemetry.csv").read_text().splitlines()
    assert len(written) - 1 == len(result.emulator.telemetry.rows()) > 750  # every row
    assert fallback / "telemetry.csv" in result.files
    assert _report_run(result) == EXIT_NOT_WRITTEN
    err = capsys.readouterr().err
    assert err.startswith(f"error: {out}/telemetry.csv: could not be written (Is a directory); "
                          f"written to {fallback}/telemetry.csv instead\n")
    shutil.rmtree(fallback)


def test_a_collision_run_prints_its_forecast_before_and_its_interval_after(tmp_path):
    """The pre-flight's forecast is printed before the run starts (first line), the
    interval in the summary, and both are in metrics.json."""
    argv = ["run", "collision", "--quiet", "--duration", "1.2", "--out", str(tmp_path / "o"),
            "--set", "satellites.0.position_m=[-0.16,0,0]",
            "--set", "satellites.1.position_m=[0.16,0,0]", "--set", "uncertainty.replicates=4",
            "--set", "uncertainty.forecast_replicates=4"]
    proc = subprocess.run([EXE, *argv], capture_output=True, text=True, timeout=300,
                          cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    metrics = json.loads((tmp_path / "o" / "metrics.json").read_text())
    forecast, coll = metrics["collision_forecast"], metrics["collision"]
    first = proc.stdout.splitlines()[0]
    assert first == (f"forecast before the run: restitution sd {forecast['restitution_sd']:.3f} "
                     f"(contact peak {forecast['peak_force_N']:.2f} N against the sensor's "
                     f"1.67 N noise per sample: ratio {forecast['peak_to_noise']:.2g}); the "
                     f"chain's predicted mean error "
                     f"{100 * forecast['restitution_error_mean']:+.0f} %")
    lo, hi = coll["restitution_interval_95"]
    assert (f"restitution 95 % interval [{lo:.3f}, {hi:.3f}] (sd {coll['restitution_sd']:.3f}, "
            f"4 replicates of the contact with the noise measured at calibration") in proc.stdout


@pytest.mark.parametrize("setting", ['sensor.model="ati-gamma"', 'sensor.model="ati-mini45"',
                                     'sensor.model="robotiq-ft300s"',
                                     'sensor.placement="mockup"', 'servo.model="servoj"'])
def test_the_collision_runs_on_each_rig_without_a_stop(setting, tmp_path):
    """The shipped collision on the lab's rig of choice (docs/sensors.md), through the
    contact (which starts at 3.1 s): exit 0, status finished. (Without the restitution's
    interval and forecast: tests/runs/test_uncertainty.py has them.)"""
    out = tmp_path / "out"
    proc = subprocess.run([EXE, "run", "collision", "--quiet", "--duration", "3.5",
                           "--set", setting, "--set", "uncertainty.enabled=false",
                           "--out", str(out)],
                          capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["status"] == "finished" and metrics["safety_stop"] is None
    assert metrics["collision"]["contact_start_s"] < 3.3


def test_an_extends_longer_than_a_file_name_is_an_error_line_not_a_traceback(tmp_path):
    """A 5,000-character `extends` once ended in an OSError traceback (exit 1)."""
    (tmp_path / "mine.toml").write_text(f'extends = "{"x" * 5000}"\n')
    proc = subprocess.run([EXE, "run", "collision", "--config", "mine.toml", "--quiet"],
                          capture_output=True, text=True, timeout=30, cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr == (f"error: mine.toml: extends: not a scenario's file name: "
                           f"{'x' * 60!r}... (5000 characters)\n")


def test_a_run_with_nothing_to_show_says_why_it_wrote_no_figure(tmp_path):
    """free-floating at rest (ideal, untouched): no figure is written, and the run says
    why rather than leaving the folder without one silently."""
    proc = subprocess.run([EXE, "run", "free-floating", "--mode", "ideal", "--duration", "1",
                           "--out", str(tmp_path / "o")], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "no figure: nothing in this run moved" in proc.stdout
    assert not list((tmp_path / "o").glob("*.png"))


def test_a_file_cut_short_by_a_full_disk_is_not_left_behind(tmp_path):
    """`run` whose files no longer fit (the process's file size limit, so that a write
    fails part-way with EFBIG, as a full disk fails with ENOSPC): exit 5 and the message,
    and neither --out nor the fallback folder keeps a truncated telemetry.csv."""
    import re
    import resource
    import signal

    def small_files():  # (SIGXFSZ ignored: the write fails instead of killing)
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (60_000, 60_000))

    out = tmp_path / "out"
    proc = subprocess.run([EXE, "run", "collision", "--mode", "ideal", "--duration", "1",
                           "--out", str(out), "--quiet"], preexec_fn=small_files,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 5, proc.stderr
    match = re.search(r"error: (\S+)/telemetry\.csv: could not be written \(File too large\), "
                      r"nor in (\S+): File too large", proc.stderr)
    assert match and match.group(1) == str(out), proc.stderr
    fallback = Path(match.group(2))
    assert not (out / "telemetry.csv").exists() and not fallback.exists()
    assert json.loads((out / "metrics.json").read_text())["status"] == "finished"
    for png in out.glob("*.png"):  # the plots that fitted, whole
        assert png.read_bytes().endswith(b"IEND\xaeB`\x82")


TIMINGS = ("realtime_factor", "cycle_time_us")
"""metrics.json's fields that time the run (they differ between two runs of a setting)."""


def test_a_run_writes_the_same_files_with_its_setting_kept_or_computed(tmp_path):
    """A first run of a setting computes its pre-flight reference and forecast and keeps
    them; a second reads them back: the same telemetry.csv bytes, the same metrics but
    the timings, the same figures, each on disk when `run` returns (the plots are drawn
    in a process of their own)."""
    env = dict(os.environ, ORBIT_EMULATOR_CACHE=str(tmp_path / "cache"))
    argv = ["run", "collision", "--quiet", "--duration", "4", "--set",
            "uncertainty.replicates=4", "--set", "uncertainty.forecast_replicates=8"]
    for n in (1, 2):
        proc = subprocess.run([EXE, *argv, "--out", str(tmp_path / f"run{n}")], env=env,
                              capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr
        figures = json.loads((tmp_path / f"run{n}" / "figures.json").read_text())
        assert [f["name"] for f in figures] == ["forces", "contact_closeup", "velocity",
                                                "position", "tracking_error"]
        for f in figures:
            assert (tmp_path / f"run{n}" / f["file"]).read_bytes().endswith(b"IEND\xaeB`\x82")
        if n == 1:
            kept = list((tmp_path / "cache" / "references").glob("*.json"))
            assert len(kept) == 1 and json.loads(kept[0].read_text())["reference"]
    first, second = tmp_path / "run1", tmp_path / "run2"
    assert (first / "telemetry.csv").read_bytes() == (second / "telemetry.csv").read_bytes()
    metrics = [{k: v for k, v in json.loads((d / "metrics.json").read_text()).items()
                if k not in TIMINGS} for d in (first, second)]
    assert metrics[0] == metrics[1]
    assert metrics[0]["collision"]["restitution_interval_95"] is not None
    for f in figures:
        assert (first / f["file"]).read_bytes() == (second / f["file"]).read_bytes()


def test_main_called_from_other_code_returns_after_run(tmp_path):
    """Only the program itself (the console script, python -m app.cli) ends at once after
    `run`; main() called from other code, even with the process's arguments, returns
    its status to the caller."""
    code = ("import sys; sys.argv = ['orbit-emulator', 'run', 'collision', '--mode', "
            f"'ideal', '--duration', '0.2', '--out', {str(tmp_path / 'out')!r}, '--quiet']\n"
            "from app.cli import main\nstatus = main()\nprint('returned', status)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines()[-1] == "returned 0"
    assert (tmp_path / "out" / "metrics.json").is_file()


@pytest.mark.parametrize("stdout", ["reader gone", "disk full"])
def test_a_run_whose_stdout_fails_keeps_its_status_and_its_files(stdout, tmp_path):
    """`run | head` (stdout's reader gone before anything is printed, the collision's
    forecast first) or a stdout on a full disk is no failure of the run: no traceback,
    the run's own exit status (3 for a safety stop, 0 otherwise), its errors still on
    stderr (a full disk said once), its files written."""
    for setting, status, duration in (("loop.seed=1", 0, "3.5"),
                                      ("loop.max_tracking_error_m=1e-5", 3, "0.5")):
        out = tmp_path / setting.split("=")[0]
        if stdout == "reader gone":
            read, write = os.pipe()
            os.close(read)  # nobody reads: the first write gets EPIPE
        else:
            write = os.open("/dev/full", os.O_WRONLY)
        proc = subprocess.run([EXE, "run", "collision", "--duration", duration, "--quiet",
                               "--set", setting, "--out", str(out)],
                              stdout=write, stderr=subprocess.PIPE, text=True, timeout=300)
        os.close(write)
        assert proc.returncode == status, proc.stderr
        assert "Traceback" not in proc.stderr and "BrokenPipe" not in proc.stderr
        assert (status == 3) == ("error: the run ended in a safety stop" in proc.stderr)
        full = "warning: stdout: No space left on device; the rest of the report is not printed"
        assert proc.stderr.count(full) == (stdout == "disk full")
        assert {p.name for p in out.iterdir()} >= {"metrics.json", "telemetry.csv"}
        assert json.loads((out / "metrics.json").read_text())["status"] == (
            "finished" if status == 0 else "safety_stop")


@pytest.mark.parametrize("closed", [1, 2], ids=["stdout", "stderr"])
def test_a_run_with_a_closed_standard_stream_runs_and_writes_nothing_of_it_to_its_files(
        closed, tmp_path):
    """`run >&-` (or `2>&-`): a closed descriptor is /dev/null for the command, not the
    first file it opens; the run ends as any other and its telemetry is a table."""
    out = tmp_path / "out"
    proc = subprocess.run(
        [EXE, "run", "free-floating-scripted", "--duration", "0.5", "--out", str(out)],
        stdin=subprocess.DEVNULL, capture_output=False, timeout=120,
        stdout=subprocess.DEVNULL if closed == 2 else None,
        stderr=subprocess.DEVNULL if closed == 1 else None,
        preexec_fn=lambda: os.close(closed))
    assert proc.returncode == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["status"] == "finished"
    assert (out / "telemetry.csv").read_text().startswith("t_s,")


def test_a_stderr_that_cannot_be_written_does_not_fail_the_run_and_a_listing_says_so(
        tmp_path):
    """`run 2>/dev/full`: the progress bar and the warnings cannot be shown, which is no
    reason for the run to fail (it ended before its run, exit 1); `scenarios
    >/dev/full`: a listing that could not be printed exits 1."""
    out = tmp_path / "out"
    with open("/dev/full", "w") as full:
        proc = subprocess.run([EXE, "run", "free-floating-scripted", "--duration", "0.5",
                               "--out", str(out)], stdout=subprocess.DEVNULL, stderr=full,
                              timeout=120)
        assert proc.returncode == 0
        assert json.loads((out / "metrics.json").read_text())["status"] == "finished"
        listing = subprocess.run([EXE, "scenarios"], stdout=full, stderr=subprocess.PIPE,
                                 text=True, timeout=60)
    assert listing.returncode == 1
    assert listing.stderr.strip() == ("warning: stdout: No space left on device; the rest "
                                      "of the report is not printed")
