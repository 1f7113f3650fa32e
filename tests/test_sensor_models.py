"""F/T sensor models a lab can choose (app/sim/sensor_models.py, [sensor] model)."""

from __future__ import annotations

import numpy as np
import pytest

from app.config import (
    ConfigError,
    SensorConfig,
    assignment_override,
    merge_overrides,
    parse_config,
)
from app.scenarios import load_scenario
from app.sim.ft_sensor import VirtualFTSensor
from app.sim.sensor_models import SENSOR_MODELS, hold_lag_cycles, sample_every_cycles

G_W = np.array([0.0, 0.0, -9.81])
EYE = np.eye(4)

# (model, range F, range T, sd F, sd T, sample rate, delay cycles at 500 Hz): the data
# sheets' figures read as the module says (resolution = 1 sd, UR's ± precision = 3 sd)
DATA_SHEETS = [
    ("ur10e", 100.0, 10.0, 5.0 / 3.0, 0.2 / 3.0, None, 1),
    ("ati-gamma", 130.0, 10.0, 1.0 / 40.0, 1.0 / 800.0, None, 0),
    ("ati-mini45", 145.0, 5.0, 1.0 / 16.0, 1.0 / 752.0, None, 0),
    ("robotiq-ft300s", 300.0, 30.0, 0.1, 0.005, 100.0, 4),
]


@pytest.mark.parametrize(("model", "range_f", "range_t", "sd_f", "sd_t", "rate", "delay"),
                         DATA_SHEETS)
def test_each_model_takes_its_data_sheet_figures(model, range_f, range_t, sd_f, sd_t,
                                                 rate, delay):
    cfg = SensorConfig(model=model)
    assert (cfg.range_force_N, cfg.range_torque_Nm) == (range_f, range_t)
    assert (cfg.noise_force_N, cfg.noise_torque_Nm) == pytest.approx((sd_f, sd_t), rel=1e-12)
    assert (cfg.sample_rate_hz, cfg.delay_cycles) == (rate, delay)


def test_the_default_model_is_the_ur10e_the_tool_always_had():
    """Today's values exactly (the shipped scenarios' telemetry is unchanged)."""
    cfg = SensorConfig()
    assert cfg.model == "ur10e"
    assert (cfg.range_force_N, cfg.range_torque_Nm, cfg.noise_force_N, cfg.noise_torque_Nm,
            cfg.sample_rate_hz, cfg.delay_cycles) == (100.0, 10.0, 5.0 / 3.0, 0.2 / 3.0,
                                                      None, 1)


@pytest.mark.parametrize("model", [m[0] for m in DATA_SHEETS])
def test_the_simulated_noise_has_the_data_sheet_sd_and_clips_at_its_range(model):
    """20 000 readings at rest: each component's sd within 2 % of the figure (its
    standard error is 0.5 %); a push beyond the range reads the range."""
    cfg = SensorConfig(model=model, bias_force_N=(0, 0, 0), bias_torque_Nm=(0, 0, 0))
    sensor = VirtualFTSensor(cfg, 0.0, G_W, np.random.default_rng(7))
    readings = np.array([sensor.measure(np.zeros(6), EYE, EYE) for _ in range(20_000)])
    assert readings[:, :3].std(axis=0) == pytest.approx([cfg.noise_force_N] * 3, rel=0.02)
    assert readings[:, 3:].std(axis=0) == pytest.approx([cfg.noise_torque_Nm] * 3, rel=0.02)
    push = np.array([10 * cfg.range_force_N, 0, 0, 0, 0, -10 * cfg.range_torque_Nm])
    quiet = VirtualFTSensor(cfg.model_copy(update={"noise_force_N": 0.0,
                                                   "noise_torque_Nm": 0.0}),
                            0.0, G_W, np.random.default_rng(0))
    out = quiet.measure(push, EYE, EYE)
    assert out[0] == cfg.range_force_N and out[5] == -cfg.range_torque_Nm


def test_explicit_settings_override_the_model_and_a_new_model_fills_the_rest():
    """Only the fields not given come from the model, in a file and through --set alike;
    switching the model by an override takes the new model's figures, not the old one's."""
    cfg = parse_config({"sensor": {"model": "ati-gamma", "noise_force_N": 0.5}})
    assert cfg.sensor.noise_force_N == 0.5  # given
    assert cfg.sensor.noise_torque_Nm == 1.0 / 800.0  # the model's
    assert cfg.sensor.range_force_N == 130.0
    base = load_scenario("collision")
    gamma = merge_overrides(base, assignment_override('sensor.model="ati-gamma"'))
    assert (gamma.sensor.noise_force_N, gamma.sensor.delay_cycles) == (1.0 / 40.0, 0)
    kept = merge_overrides(gamma, assignment_override("sensor.delay_cycles=2"))
    robotiq = merge_overrides(kept, assignment_override('sensor.model="robotiq-ft300s"'))
    assert robotiq.sensor.delay_cycles == 2  # given, so it stays
    assert (robotiq.sensor.noise_force_N, robotiq.sensor.sample_rate_hz) == (0.1, 100.0)
    back = merge_overrides(robotiq, {"sensor": {"model": None, "delay_cycles": None}})
    assert back.sensor == base.sensor


def test_an_unknown_model_is_refused_with_the_names_it_knows():
    with pytest.raises(ConfigError, match=r"sensor.model: Input should be 'ur10e', "
                                          r"'ati-gamma', 'ati-mini45' or 'robotiq-ft300s'"):
        parse_config({"sensor": {"model": "ati-nano17"}})


def test_a_slower_sensor_holds_its_reading_between_samples():
    """100 Hz in a 500 Hz loop: a new reading every 5th cycle, the same one in between
    (zero-order hold), each handed out delay_cycles later; age_cycles says how old."""
    cfg = SensorConfig(model="robotiq-ft300s", noise_force_N=0.0, noise_torque_Nm=0.0,
                       bias_force_N=(0, 0, 0), bias_torque_Nm=(0, 0, 0))
    sensor = VirtualFTSensor(cfg, 0.0, G_W, np.random.default_rng(0), rate_hz=500.0)
    out, ages = [], []
    for k in range(20):
        out.append(sensor.measure(np.array([float(k), 0, 0, 0, 0, 0]), EYE, EYE)[0])
        ages.append(sensor.age_cycles)
    # samples taken at k = 0, 5, 10, 15; each seen from k + 4 on (delay 4)
    expected = [0.0] * 9 + [5.0] * 5 + [10.0] * 5 + [15.0]
    assert out == expected
    assert ages[9:] == [4, 5, 6, 7, 8] * 2 + [4]
    assert all(out[k] == k - ages[k] for k in range(4, 20))


def test_the_hold_lag_is_half_the_held_cycles():
    assert sample_every_cycles(None, 500.0) == 1.0
    assert sample_every_cycles(7000.0, 500.0) == 1.0
    assert sample_every_cycles(100.0, 500.0) == 5.0
    assert hold_lag_cycles(100.0, 500.0) == 2.0  # held 0..4 cycles: 2 on average
    assert hold_lag_cycles(None, 500.0) == 0.0


def test_every_model_cites_its_source():
    assert all(m.source for m in SENSOR_MODELS.values())
    assert set(SENSOR_MODELS) == {d[0] for d in DATA_SHEETS}
