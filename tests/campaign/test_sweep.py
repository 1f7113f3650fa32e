"""Sweep specs (app/campaign/sweep.py): validation with the field named, expansion into runs, run
identity, the results table and --resume's reading of it; sweep-plot (app/campaign/sweep_plot.py).
No Ray here: tests/campaign/test_sweep_ray.py runs sweeps end to end."""

from __future__ import annotations

import csv
import json
import os
import shutil
import socket
import subprocess
import sys
import textwrap
import time

import pytest

from app.campaign.sweep import (
    MAX_RUNS,
    ResultsTable,
    Run,
    SpecError,
    cell,
    execute_run,
    ideal_id,
    load_spec,
    metric_value,
    plan_sweep,
    row_of,
    run_id,
)
from app.campaign.sweep_plot import label, plot_sweep, unit_of
from app.config import assignment_override
from app.runs.run_config import resolve_run_config
from app.scenarios import scenario_names

EXE = shutil.which("orbit-emulator") or f"{sys.prefix}/bin/orbit-emulator"

SPEC = """
scenario = "collision"
mode = "hil"
duration_s = 2.0
seeds = [0, 1]
metrics = ["collision.restitution", "satellites.0.position_error_max_m", "realtime_factor"]

[set]
"sensor.noise_force_N" = 1.0

[grid]
"materials.sponge.stiffness_Npm" = [500, 2000, 8000]

[random]
"satellites.0.velocity_mps.0" = { uniform = [0.02, 0.1] }
"""


def plan_of(tmp_path, text: str):
    path = tmp_path / "spec.toml"
    path.write_text(textwrap.dedent(text))
    return plan_sweep(load_spec(path), tmp_path, "spec.toml")


def test_a_spec_expands_into_grid_points_times_seeds_with_draws_per_seed(tmp_path):
    plan = plan_of(tmp_path, SPEC)
    runs = list(plan.runs())
    assert plan.count == len(runs) == 6
    assert [(r.params["materials.sponge.stiffness_Npm"], r.seed) for r in runs] == [
        (500, 0), (500, 1), (2000, 0), (2000, 1), (8000, 0), (8000, 1)]
    assert plan.columns() == [
        "run", "run_id", "seed", "materials.sponge.stiffness_Npm",
        "satellites.0.velocity_mps.0", "status", "reason", "collision.restitution",
        "satellites.0.position_error_max_m", "realtime_factor", "wall_s", "worker",
        "worker_rss_peak_MiB"]
    v = [r.params["satellites.0.velocity_mps.0"] for r in runs]
    assert all(0.02 <= x <= 0.1 for x in v)
    assert v[0] == v[2] == v[4] != v[1] == v[3] == v[5]  # drawn from the seed alone
    for r in runs:
        c = r.config
        assert c.materials["sponge"].stiffness_Npm == r.params["materials.sponge.stiffness_Npm"]
        assert c.satellites[0].velocity_mps == (v[r.index], 0.0, 0.0)
        assert c.sensor.noise_force_N == 1.0
        assert (c.loop.seed, c.loop.mode, c.loop.duration_s) == (r.seed, "hil", 2.0)
    assert len({r.run_id for r in runs}) == 6
    again = [(r.run_id, r.params) for r in plan_of(tmp_path, SPEC).runs()]
    assert again == [(r.run_id, r.params) for r in runs]  # draws and ids reproducible


def test_a_run_is_exactly_the_configuration_orbit_emulator_run_resolves(tmp_path):
    """What `run collision --duration 2 --seed S --set ... ` resolves, through the same
    function: the sweep's run has that configuration and is identified by its hash."""
    for r in plan_of(tmp_path, SPEC).runs():
        sets = ["sensor.noise_force_N=1.0"] + [f"{k}={v}" for k, v in r.params.items()]
        cli = resolve_run_config("collision", None, mode="hil", duration_s=2.0, seed=r.seed,
                                 overrides=[assignment_override(s) for s in sets])
        assert cli == r.config
        assert run_id(cli) == r.run_id


def test_the_ideal_reference_is_shared_by_the_seeds_of_a_configuration(tmp_path):
    plan = plan_of(tmp_path, """
        scenario = "collision"
        seeds = [0, 1, 2]
        metrics = ["collision.restitution"]
        [grid]
        "servo.delay_cycles" = [1, 3]
        """)
    runs = list(plan.runs())
    assert len({r.run_id for r in runs}) == 6
    assert [r.ideal_id for r in runs[:3]] == [runs[0].ideal_id] * 3
    assert runs[3].ideal_id == runs[5].ideal_id != runs[0].ideal_id
    ideal = resolve_run_config("collision", mode="ideal")
    assert ideal_id(ideal) is None  # an ideal run needs no reference
    one = resolve_run_config("free-floating")
    assert ideal_id(one) is None  # nor a run of one satellite


def test_a_spec_may_name_a_scenario_file_beside_it(tmp_path):
    (tmp_path / "mine.toml").write_text('extends = "collision"\n[loop]\nduration_s = 2.5\n'
                                        '[servo]\ndelay_cycles = 2\n')
    plan = plan_of(tmp_path, 'config = "mine.toml"\nseeds = [4]\n'
                             'metrics = ["collision.restitution"]\n')
    [run] = plan.runs()
    assert (run.config.loop.duration_s, run.config.servo.delay_cycles, run.seed) == (2.5, 2, 4)
    assert run.config == resolve_run_config(None, tmp_path / "mine.toml", seed=4)


def test_a_linked_axis_takes_its_keys_together(tmp_path):
    plan = plan_of(tmp_path, """
        scenario = "collision"
        draws = 2
        metrics = ["collision.restitution"]
        [grid]
        "servo.delay_cycles" = [1, 2]
        [grid.approach]
        "satellites.0.velocity_mps.0" = [0.01, 0.04, 0.1]
        "satellites.1.velocity_mps.0" = [-0.01, -0.04, -0.1]
        """)
    runs = list(plan.runs())
    assert plan.count == len(runs) == 2 * 3 * 2
    for r in runs:
        assert r.config.satellites[1].velocity_mps[0] == -r.config.satellites[0].velocity_mps[0]
    assert [r.seed for r in runs[:4]] == [0, 1, 0, 1]


def test_a_combination_that_is_not_valid_together_becomes_an_error_run(tmp_path):
    plan = plan_of(tmp_path, """
        scenario = "collision"
        seeds = [0]
        metrics = ["collision.restitution"]
        [grid]
        "robots.0.safety_box_min_m.0" = [-1.5, 1.0]
        "robots.0.safety_box_max_m.0" = [1.5, 0.5]
        """)
    bad = [r for r in plan.runs() if r.config is None]
    assert [r.params for r in bad] == [{"robots.0.safety_box_min_m.0": 1.0,
                                        "robots.0.safety_box_max_m.0": 0.5}]
    assert bad[0].error.startswith("ConfigError: invalid configuration: robots.0: "
                                   "safety_box_min_m must be below safety_box_max_m")


HEAD = 'scenario = "collision"\nseeds = [0]\nmetrics = ["collision.restitution"]\n'

REFUSED = {
    "unknown key": (HEAD + '[grid]\n"materials.sponge.stiffnes_Npm" = [500, 2000]\n',
                    'spec.toml: grid."materials.sponge.stiffnes_Npm": unknown key '
                    "(materials.sponge has no 'stiffnes_Npm'; did you mean "
                    "'materials.sponge.stiffness_Npm'?)"),
    "bad value": (HEAD + '[grid]\n"materials.sponge.stiffness_Npm" = [500, -1]\n',
                  'spec.toml: grid."materials.sponge.stiffness_Npm" = -1: invalid '
                  "configuration: materials.sponge.stiffness_Npm: Input should be greater "
                  "than 0"),
    "index beyond the list": (HEAD + '[grid]\n"satellites.2.mass_kg" = [1, 2]\n',
                              'spec.toml: grid."satellites.2.mass_kg": unknown key '
                              "(satellites is a list of 2: '2' is not an index of it)"),
    "random bound": (HEAD + '[random]\n"sensor.noise_force_N" = { uniform = [-1, 1] }\n',
                     'spec.toml: random."sensor.noise_force_N" = -1.0: invalid configuration: '
                     "sensor.noise_force_N: Input should be greater than or equal to 0"),
    "set": (HEAD + '[set]\n"loop.rate_hz" = 10\n',
            'spec.toml: set."loop.rate_hz" = 10: invalid configuration: loop.rate_hz: Input '
            "should be greater than or equal to 100"),
    "too many runs": ('scenario = "collision"\ndraws = 1000\nmetrics = ["status"]\n[grid]\n'
                      '"servo.delay_cycles" = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11]\n'
                      '"vfdm.iterations" = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10]\n',
                      "spec.toml: the spec names 110,000 runs (11 × 10 grid points × 1000 "
                      f"seeds); at most {MAX_RUNS:,}"),
    "unknown field": (HEAD + "sedes = [1]\n",
                      "spec.toml: sedes: unknown field (fields: scenario, config, description, "
                      "mode, duration_s, seeds, draws, metrics, set, grid, random)"),
    "unknown metric": (HEAD.replace("collision.restitution", "collision.restitutio"),
                       "spec.toml: metrics.0 ('collision.restitutio'): collision has no "
                       "'restitutio' (it has: pair, impulse_Ns,"),
    "metric robot": (HEAD.replace("collision.restitution", "robots.2.rail_travel_m"),
                     "spec.toml: metrics.0 ('robots.2.rail_travel_m'): robots.N with N in "
                     "0..1 (the scenario has 2)"),
    "metric robot field": (HEAD.replace("collision.restitution", "robots.0.rail"),
                           "spec.toml: metrics.0 ('robots.0.rail'): robots has no 'rail' "
                           "(it has: id, name,"),
    "metric satellite": (HEAD.replace("collision.restitution",
                                      "satellites.2.position_error_max_m"),
                         "spec.toml: metrics.0 ('satellites.2.position_error_max_m'): "
                         "satellites.N with N in 0..1 (the scenario has 2)"),
    "metric is a column": (HEAD.replace("collision.restitution", "status"),
                           "spec.toml: metrics.0 ('status'): already a column of the table"),
    "seeds and draws": (HEAD + "draws = 3\n",
                        "spec.toml: (top level): give one of seeds = [0, 1, ...] or draws = N"),
    "no scenario": ('seeds = [0]\nmetrics = ["status"]\n',
                    'spec.toml: (top level): give one of scenario = "NAME" or config = '
                    '"FILE.toml"'),
    "unknown scenario": (HEAD.replace('"collision"', '"colision"'),
                         "spec.toml: scenario: unknown scenario 'colision'; choose one of "
                         + ", ".join(scenario_names()) + ', or config = "FILE.toml"'),
    "distribution": (HEAD + '[random]\n"sensor.noise_force_N" = { uniform = [0, 1], '
                     "normal = [1, 2] }\n",
                     'spec.toml: random."sensor.noise_force_N": give exactly one of uniform = '
                     "[lo, hi], loguniform = [lo, hi], normal = [mean, sd] or choice = [values] "
                     "(got uniform, normal)"),
    "linked lengths": (HEAD + '[grid.approach]\n"satellites.0.velocity_mps.0" = [0.01, 0.04]\n'
                       '"satellites.1.velocity_mps.0" = [-0.01]\n',
                       "spec.toml: grid.approach: the lists of a linked axis must have one "
                       "length, got satellites.0.velocity_mps.0: 2, satellites.1.velocity_mps.0: "
                       "1"),
    "unquoted dotted key": (HEAD + "[grid]\nmaterials.sponge.stiffness_Npm = [500]\n",
                            "spec.toml: grid.materials.sponge: a linked axis holds a list of "
                            'values per key (a dotted key is quoted: "a.b.c" = [...])'),
    "value twice": (HEAD + '[grid]\n"servo.delay_cycles" = [1, 2, 1]\n',
                    'spec.toml: grid."servo.delay_cycles": the value 1 is given twice'),
    "swept twice": (HEAD + '[grid]\n"servo.delay_cycles" = [1, 2]\n[random]\n'
                    '"servo.delay_cycles" = { choice = [1, 2] }\n',
                    'spec.toml: random."servo.delay_cycles": the key is swept twice'),
    "seed twice": (HEAD.replace("seeds = [0]", "seeds = [0, 1, 0]"),
                   "spec.toml: (top level): seeds: given twice: [0]"),
    "set and grid": (HEAD + '[set]\n"servo.delay_cycles" = 1\n[grid]\n'
                     '"servo.delay_cycles" = [1, 2]\n',
                     'spec.toml: grid."servo.delay_cycles": also in [set]; give it in one '
                     "place"),
    "key too deep": (HEAD + '[grid]\n"' + "a." * 999 + 'a" = [1]\n',
                     'spec.toml: grid."' + "a." * 999 + "a\": unknown key (the "
                     "configuration has no 'a')"),
    "nested too deeply": (HEAD + "x = " + "[" * 20_000 + "]" * 20_000 + "\n",
                          "spec.toml: not valid TOML: nested too deeply"),
    "duration": (HEAD + "duration_s = 1e5\n",
                 "spec.toml: duration_s: 100000 s at 500 Hz is 5e+07 cycles; a headless run "
                 "keeps every cycle in memory"),
}


@pytest.mark.parametrize("case", list(REFUSED))
def test_a_bad_spec_is_refused_naming_the_field(case, tmp_path):
    text, message = REFUSED[case]
    path = tmp_path / "spec.toml"
    path.write_text(text)
    with pytest.raises(SpecError) as err:
        plan_sweep(load_spec(path), tmp_path, "spec.toml")
    assert str(err.value).replace(str(path), "spec.toml").startswith(message), str(err.value)


@pytest.mark.parametrize("case", ["unknown key", "too many runs"])
def test_the_cli_refuses_a_bad_spec_before_anything_starts(case, tmp_path):
    text, message = REFUSED[case]
    (tmp_path / "spec.toml").write_text(text)
    t0 = time.perf_counter()
    proc = subprocess.run([EXE, "sweep", "spec.toml", "--out", "out"], capture_output=True,
                          text=True, timeout=60, cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr == f"error: {message}\n" or message in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr
    assert not (tmp_path / "out").exists()  # refused before the output was made
    assert time.perf_counter() - t0 < 20  # no Ray was started


def test_a_bad_address_fails_at_once_with_a_clear_message(tmp_path):
    (tmp_path / "spec.toml").write_text(HEAD + "duration_s = 0.5\n")
    with socket.socket() as s:  # a port nobody listens on (closed again at once)
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    t0 = time.perf_counter()
    proc = subprocess.run([EXE, "sweep", "spec.toml", "--out", "out", "--address",
                           f"127.0.0.1:{port}"], capture_output=True, text=True, timeout=60,
                          cwd=tmp_path)
    assert time.perf_counter() - t0 < 30
    assert proc.returncode == 2, proc.stderr
    assert (f"error: --address 127.0.0.1:{port}: no Ray head answers there (Connection "
            f"refused); start one with `ray start --head --port={port}`") in proc.stderr
    assert not (tmp_path / "out" / "results.csv").exists()
    proc = subprocess.run([EXE, "sweep", "spec.toml", "--address", "nohost"],
                          capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert proc.returncode == 2
    assert "error: --address: expected HOST:PORT of a Ray head" in proc.stderr


# --- the table ------------------------------------------------------------------------------


def test_metric_paths_and_cells():
    metrics = {"collision": None, "satellites": [{"position_error_max_m": 0.1}],
               "cycle_time_us": {"p50": 12.5}, "warnings": ["a"]}
    assert metric_value(metrics, "satellites.0.position_error_max_m") == 0.1
    assert metric_value(metrics, "satellites.1.position_error_max_m") is None
    assert metric_value(metrics, "collision.restitution") is None  # no contact: empty
    assert metric_value(None, "status") is None
    assert [cell(v) for v in (None, True, 3, 0.1 + 0.2, "x", [1, 2], {"a": 1})] == [
        "", "true", "3", "0.30000000000000004", "x", "[1,2]", '{"a":1}']
    assert float(cell(0.1 + 0.2)) == 0.1 + 0.2  # numbers exactly


def _outcome(status="finished", reason="", value=0.5):
    return {"status": status, "reason": reason, "metrics": {"collision": {"restitution": value}},
            "wall_s": 1.0, "worker": "host:1", "worker_rss_peak_MiB": 300.0}


def test_the_table_refuses_to_overwrite_and_resume_reads_it_back(tmp_path):
    plan = plan_of(tmp_path, HEAD + 'duration_s = 1\n[grid]\n"servo.delay_cycles" = [1, 2, 3]\n')
    runs = list(plan.runs())
    path = tmp_path / "results.csv"
    table = ResultsTable(path, plan.columns(), resume=False)
    assert not path.exists()  # nothing written before a row
    table.append(row_of(plan, runs[0], _outcome()))
    table.append(row_of(plan, runs[1], _outcome("lost", "WorkerCrashedError: died")))
    table.append(row_of(plan, runs[2], _outcome("error", "ValueError: bad\nthing")))
    table.close()
    with pytest.raises(SpecError, match="--out: .*results.csv exists: --resume continues"):
        ResultsTable(path, plan.columns(), resume=False)
    with open(path, "a") as f:
        f.write("3,abc,0,4,finis")  # a row cut short by a hard kill
    resumed = ResultsTable(path, plan.columns(), resume=True)
    resumed.close()
    assert resumed.done == {runs[0].run_id: "finished", runs[2].run_id: "error"}
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    assert [r["run_id"] for r in rows] == [runs[0].run_id, runs[2].run_id]  # lost: again
    assert rows[1]["reason"] == "ValueError: bad thing" and rows[0]["collision.restitution"] \
        == "0.5"
    other = plan_of(tmp_path, HEAD + '[grid]\n"vfdm.iterations" = [5]\n')
    with pytest.raises(SpecError, match="--resume: .* has the columns .* another spec's table"):
        ResultsTable(path, other.columns(), resume=True)


def test_an_unresolved_run_has_a_row_with_its_reason(tmp_path):
    plan = plan_of(tmp_path, HEAD)
    run = Run(0, 0, {}, None, error="ConfigError: nope", run_id="x")
    from app.campaign.sweep import unresolved_outcome

    row = row_of(plan, run, unresolved_outcome(run))
    assert (row["status"], row["reason"], row["collision.restitution"]) == (
        "error", "ConfigError: nope", "")


# --- sweep-plot -----------------------------------------------------------------------------


def test_units_come_from_the_name():
    assert unit_of("materials.sponge.stiffness_Npm") == "N/m"
    assert unit_of("satellites.0.velocity_mps.0") == "m/s"
    assert unit_of("cycle_time_us.p50") == "µs"
    assert unit_of("servo.delay_cycles") == "cycles"
    assert unit_of("satellites.0.position_error_max_m") == "m"
    assert unit_of("collision.restitution") is None
    assert unit_of("realtime_factor") is None
    assert label("loop.duration_s") == "loop.duration_s (s)"
    assert label("collision.restitution_error") == "collision.restitution_error"


def _write_results(path, rows):
    columns = ["run", "run_id", "seed", "materials.sponge.stiffness_Npm", "servo.delay_cycles",
               "status", "reason", "collision.restitution", "wall_s", "worker",
               "worker_rss_peak_MiB"]
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(columns)
        for i, (k, d, seed, e) in enumerate(rows):
            w.writerow([i, f"id{i}", seed, k, d, "finished", "", e, 1.0, "h:1", 300])


def test_sweep_plot_draws_a_line_plot_and_a_heat_map(tmp_path):
    rows = [(k, d, s, 0.3 + 1e-5 * k + 0.01 * d + 0.001 * s)
            for k in (500, 2000) for d in (1, 3) for s in (0, 1)]
    _write_results(tmp_path / "results.csv", rows)
    line = plot_sweep(tmp_path, "materials.sponge.stiffness_Npm", None, "collision.restitution")
    assert line == tmp_path / "collision.restitution_vs_materials.sponge.stiffness_Npm.png"
    heat = plot_sweep(tmp_path, "materials.sponge.stiffness_Npm", "servo.delay_cycles",
                      "collision.restitution", tmp_path / "heat.png")
    for png in (line, heat):
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000


def test_sweep_plot_merges_more_combinations_than_it_draws_lines(tmp_path):
    """More combinations of the other settings than MAX_LINES: one line, the mean over
    them (as the manual's campaign tutorial draws the 27-run fidelity map over one
    setting); it raised on the merged line's empty key."""
    rows = [(k, d, 0, 0.3 + 1e-5 * k + 0.01 * d) for k in (500, 5000) for d in range(9)]
    _write_results(tmp_path / "results.csv", rows)
    png = plot_sweep(tmp_path, "materials.sponge.stiffness_Npm", None, "collision.restitution")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000


def test_sweep_plot_names_what_is_missing(tmp_path):
    with pytest.raises(ValueError, match="no results.csv"):
        plot_sweep(tmp_path, "a", None, "b")
    _write_results(tmp_path / "results.csv", [(500, 1, 0, 0.3)])
    with pytest.raises(ValueError, match=r"--x: 'stiffness' is not a setting the sweep varied "
                                         r"\(its settings: materials.sponge.stiffness_Npm, "
                                         r"servo.delay_cycles\)"):
        plot_sweep(tmp_path, "stiffness", None, "collision.restitution")
    with pytest.raises(ValueError, match="--metric: 'restitution' is not a column"):
        plot_sweep(tmp_path, "servo.delay_cycles", None, "restitution")
    proc = subprocess.run([EXE, "sweep-plot", str(tmp_path), "--x", "servo.delay_cycles",
                           "--metric", "nope"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "error: --metric: 'nope' is not a column" in proc.stderr


def test_settings_that_must_change_together_are_checked_together(tmp_path):
    """Docking has contact: scaling.length must equal scaling.time. Set apart in [set], or
    as a linked axis, they are applied together and then checked; a plain grid of one
    of them alone is refused with the reason."""
    head = 'scenario = "docking"\nseeds = [0]\nmetrics = ["capture.captured"]\n'
    for extra in ('[set]\n"scaling.length" = 2.0\n"scaling.time" = 2.0\n',
                  '[grid.k]\n"scaling.length" = [2.0, 3.0]\n"scaling.time" = [2.0, 3.0]\n'):
        path = tmp_path / "spec.toml"
        path.write_text(head + extra)
        plan = plan_sweep(load_spec(path), tmp_path, "spec.toml")
        assert all(r.config.scaling.length == r.config.scaling.time for r in plan.runs())
    path.write_text(head + '[grid]\n"scaling.length" = [2.0]\n')
    with pytest.raises(SpecError, match="scaling.length must equal scaling.time"):
        plan_sweep(load_spec(path), tmp_path, "spec.toml")


def test_run_applies_its_set_options_together():
    from app.config import assignment_override
    from app.runs.run_config import resolve_run_config

    cfg = resolve_run_config("docking", None, overrides=[
        assignment_override("scaling.length=2"), assignment_override("scaling.time=2")])
    assert (cfg.scaling.length, cfg.scaling.time) == (2.0, 2.0)


@pytest.mark.parametrize(("scenario", "axis", "values", "metric"), [
    ("rendezvous", "satellites.0.gnc.waypoints.2.transfer_s", [900.0], "success.waypoints"),
    ("tumbling-target", "satellites.1.omega_radps.2", [0.0523599], "success.synchronisation"),
    ("gravity-stabilised", "satellites.0.attitude_wxyz", [[0.9990482, 0, 0, 0.0436194]],
     "success.libration"),
    ("free-flying", "satellites.0.gnc.thrust_max_N", [1.5], "success.recovery"),
    ("docking", "satellites.0.gnc.waypoints.0.approach_speed_mps", [0.015], "capture.t_s"),
])
def test_the_scenario_library_sweeps_and_reports_its_success(
        tmp_path, scenario, axis, values, metric):
    """A grid over a GNC setting, the target's spin or the release angle plans, and its
    runs (ideal, without Ray: what each Ray task does) pass and report their success
    figures in the row."""
    path = tmp_path / "spec.toml"
    path.write_text(f'scenario = "{scenario}"\nmode = "ideal"\nseeds = [0]\n'
                    f'metrics = ["success.passed", "{metric}"]\n'
                    f'[grid]\n"{axis}" = {values}\n')
    plan = plan_sweep(load_spec(path), tmp_path, "spec.toml")
    runs = list(plan.runs())
    assert len(runs) == len(values)
    for run in runs:
        outcome = execute_run(run.config, None, "none", None)
        assert outcome["status"] == "finished", outcome["reason"]
        row = row_of(plan, run, outcome)
        assert row["success.passed"] == "true", row
        assert metric in row and row[metric]


SPEC_RULE = "a sweep spec must be a regular file of at most 1 MiB"
TOML_RULE = "a TOML file must be a regular file of at most 1 MiB"


def _odd_files(tmp_path):
    os.mkfifo(tmp_path / "fifo.toml")
    (tmp_path / "dir.toml").mkdir()
    with open(tmp_path / "big.toml", "wb") as f:
        f.truncate((1 << 20) + 1)


@pytest.mark.parametrize("spec, message", [
    ("/dev/zero", f"error: /dev/zero: is a character device; {SPEC_RULE}"),
    ("fifo.toml", f"error: fifo.toml: is a FIFO (named pipe); {SPEC_RULE}"),
    ("dir.toml", "error: dir.toml: is a directory, not a sweep spec"),
    ("big.toml", f"error: big.toml: is 1,048,577 bytes; {SPEC_RULE}"),
], ids=["dev-zero", "fifo", "directory", "oversize"])
def test_a_sweep_spec_must_be_a_regular_file_under_1_mib(spec, message, tmp_path):
    _odd_files(tmp_path)
    proc = subprocess.run([EXE, "sweep", spec, "--out", "out"], capture_output=True,
                          text=True, timeout=30, cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr == message + "\n"
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("config, message", [
    ("/dev/zero", f"/dev/zero: is a character device; {TOML_RULE}"),
    ("fifo.toml", f"fifo.toml: is a FIFO (named pipe); {TOML_RULE}"),
    ("dir.toml", "dir.toml: is a directory, not a TOML file"),
    ("big.toml", f"big.toml: is 1,048,577 bytes; {TOML_RULE}"),
], ids=["dev-zero", "fifo", "directory", "oversize"])
def test_a_sweep_specs_config_must_be_a_regular_file_under_1_mib(config, message, tmp_path):
    _odd_files(tmp_path)
    (tmp_path / "spec.toml").write_text(
        f'config = "{config}"\nseeds = [0]\nmetrics = ["cycles"]\n')
    proc = subprocess.run([EXE, "sweep", "spec.toml", "--out", "out"], capture_output=True,
                          text=True, timeout=30, cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr == f"error: spec.toml: config: {message}\n"
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("key, shown", [
    ("satellites." + "1" * 4301 + ".mass_kg", "'111111111111... (4301 characters)'"),
    ("satellites.\u0661.mass_kg", "'\u0661'"),
])
def test_a_swept_list_index_is_a_short_ascii_number(key, shown, tmp_path):
    path = tmp_path / "spec.toml"
    path.write_text(HEAD + f'[grid]\n"{key}" = [1, 2]\n')
    with pytest.raises(SpecError) as err:
        plan_sweep(load_spec(path), tmp_path, "spec.toml")
    quoted = json.dumps(key)  # (the spec's key as the message quotes it)
    assert str(err.value) == (f'spec.toml: grid.{quoted}: unknown key (satellites is a list of '
                              f"2: {shown} is not an index of it (1 to 6 ASCII digits))")


def test_the_ideal_runs_started_ahead_are_each_started_once_one_per_worker_at_most():
    """The sweep's look-ahead (app/campaign/sweep_ray.py) over 150 configurations of one seed
    each, the next run submitted after each look: every configuration's ideal run is started
    exactly once, and never more than one per worker ahead of its runs, however fast the
    ideals finish (none is evicted from the cache before its runs took it)."""
    from collections import OrderedDict

    from app.campaign import sweep_ray
    from app.campaign.sweep import Run
    from app.config import EmulatorConfig

    started = []

    class IdealTask:  # what ray.remote(compute_ideal) is to the loop: .remote(config) -> ref
        @staticmethod
        def remote(config):
            started.append(config)
            return object()

    config = EmulatorConfig()
    runs = [Run(index=k, seed=0, params={}, config=config, run_id=f"r{k}", ideal_id=f"c{k}")
            for k in range(150)]
    upcoming = sweep_ray._Lookahead([], iter(runs))
    ideals, ahead = OrderedDict(), set()
    summary = {"workers": 2, "ideal_runs": 0, "ideal_runs_ahead": 0}
    most_ahead = 0
    while True:
        sweep_ray._prefetch_ideals(upcoming, ideals, ahead, IdealTask, summary)
        most_ahead = max(most_ahead, len(ahead))
        run = upcoming.pop()
        if run is None:
            break
        sweep_ray._ideal_ref(ideals, run, IdealTask, summary)
        ahead.discard(run.ideal_id)
    assert len(started) == summary["ideal_runs"] == 150
    assert summary["ideal_runs_ahead"] == 150  # (each one started before its run)
    assert most_ahead == 2


def test_the_first_ideal_run_computed_apart_while_ray_starts_is_the_one_a_worker_computes():
    """A local sweep starts its first configuration's ideal run in a forked process before
    Ray starts (app/campaign/sweep_ray.py ``_ideal_apart``): what it hands the runs is
    compute_ideal's own result, to the last bit; and where that process died, the ideal
    is a Ray task like any other (here: what ray.remote(compute_ideal) is to the loop)."""
    import signal
    from collections import OrderedDict

    from app.campaign import sweep_ray
    from app.campaign.sweep import Run, compute_ideal

    config = resolve_run_config("collision", mode="hil", duration_s=3.5,
                                overrides=[assignment_override("uncertainty.enabled=false")])
    run = Run(index=0, seed=0, params={}, config=config, run_id="r0", ideal_id="c0")
    submitted = []

    class IdealTask:
        @staticmethod
        def remote(config):
            submitted.append(config)
            return "a Ray task's ref"

    class Ray:  # ray.put: the object store keeps the value as it is
        @staticmethod
        def put(value):
            return ("put", value)

    summary = {"ideal_runs": 0, "ideal_runs_apart": 0}
    ideals = OrderedDict(c0=sweep_ray._ideal_apart(run))
    sweep_ray._resolve_apart(ideals, run, IdealTask, Ray, summary)
    assert ideals["c0"] == ("put", compute_ideal(config))
    assert ideals["c0"][1][0] == "ok" and ideals["c0"][1][1]["restitution"] > 0
    assert summary == {"ideal_runs": 1, "ideal_runs_apart": 1} and not submitted

    import time

    from app.runs.replicate_pool import apart

    computing = apart(time.sleep, 60.0)  # a process apart killed before it answers
    os.kill(computing.pid, signal.SIGKILL)
    ideals = OrderedDict(c0=computing)
    sweep_ray._resolve_apart(ideals, run, IdealTask, Ray, summary)
    assert ideals["c0"] == "a Ray task's ref" and submitted == [config]
    assert summary == {"ideal_runs": 2, "ideal_runs_apart": 1}

    hung = apart(time.sleep, 60.0)  # a process apart that does not answer in time
    ideals = OrderedDict(c0=hung)
    t0 = time.monotonic()
    sweep_ray.IDEAL_APART_TIMEOUT_S, kept = 0.5, sweep_ray.IDEAL_APART_TIMEOUT_S
    try:
        sweep_ray._resolve_apart(ideals, run, IdealTask, Ray, summary)
    finally:
        sweep_ray.IDEAL_APART_TIMEOUT_S = kept
    assert time.monotonic() - t0 < 5.0 and hung.stop() == -signal.SIGKILL
    assert ideals["c0"] == "a Ray task's ref" and submitted == [config, config]
