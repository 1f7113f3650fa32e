"""Configuration models: paper defaults and bad input rejected with the field's name."""

import datetime
import math
import re

import numpy as np
import pytest

from app.config import (
    ConfigError,
    EmulatorConfig,
    SatelliteConfig,
    VfdmConfig,
    assignment_override,
    load_config,
    merge_overrides,
    parse_config,
)
from app.scenarios import load_scenario


def test_defaults_reproduce_the_paper():
    cfg = EmulatorConfig()
    assert cfg.orbit.altitude_m == 800e3
    assert cfg.orbit.gravity_gradient is True
    from app.sim.scaling import scaling_of

    assert cfg.scaling.law == "paper"
    assert scaling_of(cfg).torque_scale == pytest.approx(1 / 2000)
    sat = cfg.satellites[0]
    assert sat.mass_kg == 1.0 and sat.size_m == (0.2, 0.2, 0.1)
    np.testing.assert_allclose(sat.principal_inertia(), [0.05 / 12, 0.05 / 12, 0.08 / 12])
    v = cfg.vfdm
    assert (v.kp_lin, v.kp_rot, v.kd_lin, v.kd_rot) == (10.0, 1.0, 0.0, 0.0)
    assert (v.end_mass_kg, v.link_mass_kg, v.end_inertia_kgm2) == (1.0, 0.01, 1.0)
    assert v.link_inertia_ratio == 1e-6 and v.iterations == 10
    assert cfg.loop.rate_hz == 500.0


def test_toml_file_round_trip(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text(
        """
[orbit]
altitude_m = 500e3
gravity_gradient = false

[[satellites]]
name = "a"
position_m = [0.1, 0.0, 0.0]
attitude_wxyz = [2.0, 0.0, 0.0, 0.0]

[[pulses]]
satellite = "a"
start_s = 1.0
end_s = 1.5
force_N = [1.0, 0.0, 0.0]
"""
    )
    cfg = load_config(path)
    assert cfg.orbit.altitude_m == 500e3 and not cfg.orbit.gravity_gradient
    assert cfg.satellites[0].attitude_wxyz == (1.0, 0.0, 0.0, 0.0)  # normalised
    assert cfg.pulses[0].force_N == (1.0, 0.0, 0.0)


@pytest.mark.parametrize(
    "data, message",
    [
        ({"orbit": {"altitude_km": 800}}, "orbit.altitude_km: Extra inputs are not permitted"),
        ({"passivity": {"idle_reset_s": -0.1}}, "passivity.idle_reset_s: Input should be greater"),
        ({"passivity": {"gain": 1.0}}, "passivity.gain: Extra inputs are not permitted"),
        ({"satellites": [{"name": "a", "mass_kg": -1.0}]}, "satellites.0.mass_kg"),
        ({"satellites": [{"name": "a", "mass_kg": math.nan}]}, "satellites.0.mass_kg"),
        (
            {"satellites": [{"name": "a", "velocity_mps": [0.0, math.inf, 0.0]}]},
            "satellites.0.velocity_mps.1: must be a finite number",
        ),
        (
            {"satellites": [{"name": "a", "attitude_wxyz": [0, 0, 0, 0]}]},
            "satellites.0.attitude_wxyz: quaternion must be non-zero",
        ),
        (
            {
                "satellites": [{"name": "a"}],
                "pulses": [{"satellite": "b", "start_s": 0, "end_s": 1}],
            },
            "pulses.0.satellite: 'b' names no satellite",
        ),
        (
            {"pulses": [{"satellite": "sat1", "start_s": 2, "end_s": 1}]},
            "pulses.0: end_s must be greater than start_s",
        ),
        (
            {"satellites": [{"name": "a", "inertia_kgm2": [1.0, 1.0, 5.0]}]},
            "satellites.0: inertia_kgm2 violates the triangle inequality",
        ),
        ({"satellites": [{"name": "a"}, {"name": "a"}]}, "names must be unique"),
        ({"satellites": []}, "satellites: List should have at least 1 item"),
        ({"vfdm": {"iterations": 0}}, "vfdm.iterations"),
        ({"loop": {"mode": "fast"}}, "loop.mode"),
    ],
)
def test_bad_input_names_the_field(data, message):
    with pytest.raises(ConfigError) as err:
        parse_config(data)
    assert message in str(err.value)


def test_unreadable_files_fail_clearly(tmp_path):
    with pytest.raises(ConfigError, match="config file not found"):
        load_config(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[orbit\naltitude_m = 1")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(bad)


def test_overrides_are_a_merge_patch_with_item_indices():
    """RFC 7396: objects merge, null takes the default back, a list replaces the list;
    an object of item indices patches those items in place."""
    base = parse_config({"satellites": [{"name": "a"}, {"name": "b", "mass_kg": 2.0}],
                         "vfdm": {"kp_lin": 20.0}})
    cfg = merge_overrides(base, {"satellites": {"1": {"velocity_mps": [0.01, 0, 0]}}})
    assert cfg.satellites[1].velocity_mps == (0.01, 0.0, 0.0)
    assert cfg.satellites[1].mass_kg == 2.0 and cfg.satellites[0].name == "a"
    whole = merge_overrides(base, {"satellites": [{"name": "c"}]})
    assert [s.name for s in whole.satellites] == ["c"]
    assert whole.satellites[0].mass_kg == SatelliteConfig(name="c").mass_kg
    assert merge_overrides(base, {"vfdm": {"kp_lin": None}}).vfdm.kp_lin == VfdmConfig().kp_lin
    assert merge_overrides(base, {}) == base
    # an integer stands for a float, a list for a tuple
    assert merge_overrides(base, {"loop": {"duration_s": 5}}).loop.duration_s == 5.0
    with pytest.raises(ConfigError, match="orbit.altitude_m"):
        merge_overrides(base, {"orbit": {"altitude_m": -1}})


@pytest.mark.parametrize(("patch", "message"), [
    ({"satellites": {"2": {"mass_kg": 1.0}}},
     "satellites.2: index out of range: the list has 2 item(s), indices 0..1"),
    ({"satellites": {"x": {}}}, "satellites: a list is replaced by a list or patched by an "
                                "object of item indices, got the key 'x'"),
    ({"satellites": {"0": None}}, "satellites.0: an item cannot be removed by null"),
    ({"satellites": [{"mass_kg": 1.0}]}, "satellites.0.name"),
    # strict, as JSON: a number in a string, 1 for true, a fraction for a count
    ({"loop": {"duration_s": "5"}}, "loop.duration_s: Input should be a valid number"),
    ({"passivity": {"enabled": 1}}, "passivity.enabled: Input should be a valid boolean"),
    ({"loop": {"telemetry_capacity": 1000.0}},
     "loop.telemetry_capacity: Input should be a valid integer"),
    # only what JSON holds, named where it is (a TOML date, a lone surrogate in a body)
    ({"satellites": {"0": {"name": datetime.date(1979, 5, 27)}}},
     "satellites.0.name: expected a number, flag, text or list, got a date"),
    ({"satellites": {"0": {"name": "\ud800"}}}, "satellites.0.name: text that is not valid"),
    # a run keeps its scenario's name (the metrics and the state say the same)
    ({"name": "mine"}, "name: the scenario's name is not a setting to override"),
    ({"description": "x"}, "description: the scenario's description is not a setting"),
])
def test_bad_patches_name_what_is_wrong(patch, message):
    base = parse_config({"satellites": [{"name": "a"}, {"name": "b"}]})
    with pytest.raises(ConfigError) as err:
        merge_overrides(base, patch)
    assert message in str(err.value)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("passivity.enabled=false", {"passivity": {"enabled": False}}),
        ("wrench.lowpass_hz = 20", {"wrench": {"lowpass_hz": 20}}),
        ("satellites.1.velocity_mps=[0.1, 0, 0]",
         {"satellites": {"1": {"velocity_mps": [0.1, 0, 0]}}}),
        ("satellites.0.material=rigid", {"satellites": {"0": {"material": "rigid"}}}),
        ("pulses=[]", {"pulses": []}),
        ("robots.0.rail=null", {"robots": {"0": {"rail": None}}}),  # removes the setting
        ('satellites.0.name="null"', {"satellites": {"0": {"name": "null"}}}),
    ],
)
def test_assignment_override(text, expected):
    assert assignment_override(text) == expected


def test_assignment_override_merges_one_field_of_one_item():
    base = load_scenario("collision")
    cfg = merge_overrides(base, assignment_override("satellites.1.velocity_mps=[-0.05, 0, 0]"))
    assert cfg.satellites[1].velocity_mps == (-0.05, 0.0, 0.0)
    assert cfg.satellites[1].material == base.satellites[1].material
    assert cfg.satellites[0] == base.satellites[0]


def test_assignment_override_sets_one_component_of_a_vector():
    """A number after a vector setting picks its component (a tuple in the model)."""
    base = load_scenario("collision")
    cfg = merge_overrides(base, assignment_override("satellites.0.velocity_mps.0=0.05"))
    assert cfg.satellites[0].velocity_mps == (0.05, 0.0, 0.0)
    assert cfg.satellites[1] == base.satellites[1]
    with pytest.raises(ConfigError, match=r"satellites\.0\.velocity_mps\.3: index out of range"):
        merge_overrides(base, assignment_override("satellites.0.velocity_mps.3=1"))


@pytest.mark.parametrize(
    ("text", "message"),
    [("passivity", "expected KEY=VALUE"), ("a..b=1", "expected KEY=VALUE"),
     ("0.x=1", "the first part of KEY must be a section name")],
)
def test_bad_assignment(text, message):
    with pytest.raises(ConfigError, match=message):
        assignment_override(text)


def test_the_telemetry_row_size_the_limit_uses_is_the_loop_s():
    from app.config import telemetry_row_floats
    from app.sim.telemetry import loop_columns

    for n_sat, n_rob in [(1, 0), (1, 1), (2, 2), (8, 4)]:
        assert telemetry_row_floats(n_sat, n_rob) == len(loop_columns(n_sat, n_rob))


@pytest.mark.parametrize(("override", "field"), [
    ({"loop": {"telemetry_capacity": 9_000_000}}, "loop.telemetry_capacity"),
    ({"vfdm": {"iterations": 201}}, "vfdm.iterations"),
    ({"loop": {"approach_timeout_s": 121}}, "loop.approach_timeout_s"),
    ({"loop": {"duration_s": 2e6}}, "loop.duration_s"),
    ({"compensation": {"lead_s": 1e9}}, "compensation.lead_s"),
    ({"compensation": {"lead_s": float("nan")}}, "compensation.lead_s"),
    ({"wrench": {"contact_gate_margin_m": 1.0}}, "wrench.contact_gate_margin_m"),
    ({"passivity": {"tank_max_J": 1e12}}, "passivity.tank_max_J"),
    ({"satellites": [{"name": f"s{i}"} for i in range(9)]}, "satellites"),
    ({"materials": {f"m{i}": {"stiffness_Npm": 1.0, "damping_spm": 0.0} for i in range(33)}},
     "materials"),
])
def test_settings_that_cost_memory_or_time_are_bounded(override, field):
    from app.config import ConfigError, parse_config

    with pytest.raises(ConfigError, match=field.replace(".", r"\.")) as err:
        parse_config(override)
    assert "index out of range" not in str(err.value)


def test_a_scenario_extends_another_and_its_lists_replace_the_base_s(tmp_path):
    """extends: the base's settings, this file's merged over them (a list replaces)."""
    scripted, hand = load_scenario("free-floating-scripted"), load_scenario("free-floating")
    assert hand.pulses == [] and len(scripted.pulses) == 10  # the web app's: yours to push
    assert scripted.loop.duration_s == 24.0 and hand.loop.duration_s == 120.0
    same = {"pulses", "name", "description", "loop"}
    assert scripted.model_dump(exclude=same) == hand.model_dump(exclude=same)
    (tmp_path / "mine.toml").write_text(
        'extends = "collision"\n[loop]\nduration_s = 3.0\n'
        '[[pulses]]\nsatellite = "cubesat"\nstart_s = 1.0\nend_s = 1.5\n'
        'force_N = [1.0, 0.0, 0.0]\n')
    mine, base = load_config(tmp_path / "mine.toml"), load_scenario("collision")
    assert mine.loop.duration_s == 3.0 and len(mine.pulses) == 1
    assert mine.satellites == base.satellites and mine.materials == base.materials


@pytest.mark.parametrize(
    ("files", "message"),
    [
        ({"a.toml": 'extends = "b"\n', "b.toml": 'extends = "a"\n'},
         "b.toml: extends: 'a' makes a cycle: a.toml -> b.toml -> a.toml"),
        ({"a.toml": 'extends = "nowhere"\n'}, "extends: no scenario 'nowhere' beside it"),
        ({"a.toml": "extends = 3\n"}, "extends: must name a scenario, got 3"),
    ],
)
def test_a_bad_extends_is_an_error_naming_it(tmp_path, files, message):
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    with pytest.raises(ConfigError, match=re.escape(message)):
        load_config(tmp_path / "a.toml")


def test_an_extends_chain_too_long_and_toml_nested_too_deeply_are_errors_naming_them(
        tmp_path):
    """A chain of 40 files (each extends the next; the last, the collision) stops at the
    32nd; a file of 20,000 nested lists (40 KB, under the size cap) is not a traceback."""
    from app.config import MAX_EXTENDS

    for i in range(40):
        (tmp_path / f"c{i}.toml").write_text(f'extends = "c{i + 1}"\n')
    (tmp_path / "c40.toml").write_text('extends = "collision"\n')
    with pytest.raises(ConfigError, match=re.escape(
            f"extends: more than {MAX_EXTENDS} files deep (from c0.toml)")):
        load_config(tmp_path / "c0.toml")
    (tmp_path / "c9.toml").write_text('extends = "collision"\n')  # 10 deep: fine
    assert load_config(tmp_path / "c0.toml").satellites == load_scenario("collision").satellites
    (tmp_path / "deep.toml").write_text("x = " + "[" * 20_000 + "]" * 20_000 + "\n")
    with pytest.raises(ConfigError, match=re.escape("deep.toml: not valid TOML: nested too "
                                                    "deeply")):
        load_config(tmp_path / "deep.toml")


def test_a_key_of_too_many_parts_is_refused_before_any_recursion():
    from app.config import assignment_override

    with pytest.raises(ConfigError, match="a KEY has at most 12 dotted parts"):
        assignment_override("a." * 999 + "a=1")


# --- [robots.rail] ---------------------------------------------------------------------------


def _robot_with_rail(**rail):
    return {"robots": [{"name": "r", "satellite": "sat1", "rail": rail}]}


def test_a_robot_has_no_rail_unless_one_is_configured():
    assert parse_config({"robots": [{"name": "r", "satellite": "sat1"}]}).robots[0].rail is None
    rail = parse_config(_robot_with_rail()).robots[0].rail
    assert rail.axis_W == (1.0, 0.0, 0.0) and rail.travel_m == (-2.0, 2.0)
    assert rail.start_m == 0.0 and rail.speed_limit_mps > 0 and rail.accel_limit_mps2 > 0


def test_the_rail_axis_is_normalised():
    rail = parse_config(_robot_with_rail(axis_W=[0.0, 3.0, 4.0])).robots[0].rail
    np.testing.assert_allclose(rail.axis_W, [0.0, 0.6, 0.8], rtol=0, atol=1e-15)
    huge = parse_config(_robot_with_rail(axis_W=[1e200, 1e200, 0.0])).robots[0].rail
    np.testing.assert_allclose(huge.axis_W, [0.5**0.5, 0.5**0.5, 0.0], rtol=1e-15)


@pytest.mark.parametrize("rail, message", [
    ({"axis_W": [0.0, 0.0, 0.0]}, "robots.0.rail: axis_W must be a non-zero"),
    ({"travel_m": [1.0, 1.0]}, "robots.0.rail: travel_m must be [min, max] with min < max"),
    ({"travel_m": [2.0, -2.0]}, "travel_m must be [min, max] with min < max, got [2, -2]"),
    ({"start_m": 2.5}, "start_m = 2.5 is outside travel_m = [-2, 2]"),
    ({"travel_m": [-1e9, 1e9]}, "robots.0.rail: travel_m must lie within ±50 m of the base's "
                                "position (a lab's track), got [-1e+09, 1e+09]"),
    ({"axis_W": [1e-200, 0.0, 0.0]}, "robots.0.rail: axis_W must be a non-zero"),
    ({"speed_limit_mps": 0.0}, "robots.0.rail.speed_limit_mps: Input should be greater than 0"),
    ({"accel_limit_mps2": -1.0}, "robots.0.rail.accel_limit_mps2: Input should be greater"),
    ({"bandwidth_hz": math.inf}, "robots.0.rail.bandwidth_hz: must be a finite number"),
    ({"delay_cycles": -1}, "robots.0.rail.delay_cycles"),
    ({"travel_m": [0.0, 1.0, 2.0]}, "robots.0.rail.travel_m: Tuple should have at most 2"),
    ({"stroke_m": 3.0}, "robots.0.rail.stroke_m: Extra inputs are not permitted"),
])
def test_bad_rail_settings_name_the_field(rail, message):
    with pytest.raises(ConfigError) as err:
        parse_config(_robot_with_rail(**rail))
    assert message in str(err.value)
