"""The restitution's uncertainty (app/runs/uncertainty.py): the snapshot replays the run
exactly, the interval and the forecast match the spread over seeds, settings are checked."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from app.config import ConfigError, EmulatorConfig, assignment_override, merge_overrides
from app.runs import report
from app.runs.headless import checked_reference, headless_config, run_scenario
from app.runs.uncertainty import (
    Z95,
    add_systematic,
    forecast,
    measured_noise,
    replicate,
    sd_standard_error,
    snapshot_time_s,
    widening,
)
from app.scenarios import load_scenario
from app.sim.loop import Emulator

SHORT = ["satellites.0.position_m=[-0.16,0,0]", "satellites.1.position_m=[0.16,0,0]",
         "loop.duration_s=1.2"]
"""The shipped collision, started closer: the same contact (at 0.74 s) in a 1.2 s run."""


def significant_noisy_bias(forecast_: dict, e_ideal: float) -> float | None:
    """δ_noisy as the interval takes it: the noisy replicates' mean against the ideal,
    None within two of its standard errors of zero."""
    bias = forecast_["restitution_mean"] - e_ideal
    se = forecast_["restitution_sd"] / np.sqrt(forecast_["replicates_with_restitution"])
    return None if abs(bias) <= 2.0 * se else bias


def short_collision(*extra: str):
    config = load_scenario("collision")
    for a in [*SHORT, *extra]:
        config = merge_overrides(config, assignment_override(a))
    return headless_config(config, config.loop.duration_s)


@pytest.fixture(scope="module")
def reference():
    config = short_collision("uncertainty.replicates=8")  # the default forecast's 200
    return checked_reference(config, config.loop.duration_s)


def test_a_replicate_with_the_runs_own_noise_is_the_run_itself(reference):
    """From the snapshot, with the snapshot's own generators and calibration, the loop
    replays the run bit for bit: every telemetry column of every cycle."""
    config = short_collision()
    em = Emulator(config)
    em.snapshot_at_s = snapshot_time_s(config, reference)
    em.run(config.loop.duration_s)
    snap = em.snapshot
    lead_s = config.uncertainty.snapshot_lead_s
    assert snap is not None and snap.t_s == pytest.approx(
        reference["contact_start_s"] - lead_s, abs=em.dt_s)
    kept = copy.deepcopy(snap.ods.y)
    coll = replicate(snap, (1, 2), em.t_s)
    assert np.array_equal(snap.ods.y, kept)  # the snapshot itself is left as it was
    rows = em.telemetry.rows()
    twin = snap.copy_state(capacity=1000)
    while twin.t_s < em.t_s - 1e-9:
        twin.step()
    twin.record_final()
    mine = twin.telemetry.rows()
    start = int(np.searchsorted(rows[:, 0], mine[0, 0]))
    assert np.array_equal(rows[start:start + len(mine)], mine)
    assert coll["restitution"] is not None
    assert coll["window_s"][0] > snap.t_s  # the approach speed is read inside the replay


def test_the_noise_is_the_one_measured_at_calibration():
    """Each arm's rest readings give its noise: the configured 1.67 N per axis to within
    the sampling error of 1000 readings (~2.2 %), and the bias error σ / sqrt(1000)."""
    em = Emulator(short_collision())
    em.prepare()
    noise = measured_noise(em)
    assert len(noise) == 2
    for n in noise:
        np.testing.assert_allclose(n.sd_S[:3], 5.0 / 3.0, rtol=0.08)
        np.testing.assert_allclose(n.bias_sd_S, n.sd_S / np.sqrt(1000))


def test_interval_and_forecast_match_the_spread_over_seeds(reference):
    """Six seeds of the short collision (8 replicates each): each run's interval is e ±
    1.96 sd of its replicates, five or more of six hold the ideal restitution (0.95 each
    if calibrated), the median half-width is within a factor 2 of 1.96 x the sd across
    the seeds, and so is the forecast (six seeds know that sd to about ±30 %; the
    benchmark's 30 seeds are in docs/fidelity-uncertainty.md)."""
    config = short_collision("uncertainty.replicates=8")
    ei = reference["restitution"]
    runs = [run_scenario(merge_overrides(config, {"loop": {"seed": s}}), ideal=reference,
                         preflight_done=True).metrics["collision"] for s in range(6)]
    e = np.array([c["restitution"] for c in runs])
    delta = reference["forecast"]["restitution_systematic"]
    noisy = significant_noisy_bias(reference["forecast"], ei)
    for c in runs:  # the noise's interval, reaching the chain's systematic error further
        assert c["restitution_systematic"] == delta
        assert c["restitution_bias_noisy"] == (None if noisy is None
                                               else pytest.approx(noisy, abs=1e-12))
        added = 0.0 if noisy is None else noisy  # within its sampling error: not added
        assert c["restitution_interval_95"] == pytest.approx(
            [c["restitution"] - Z95 * c["restitution_sd"] - max(delta, added, 0.0),
             c["restitution"] + Z95 * c["restitution_sd"] + max(-delta, -added, 0.0)])
        assert c["uncertainty"]["replicates_with_restitution"] == 8
    holds = sum(lo <= ei <= hi for lo, hi in (c["restitution_interval_95"] for c in runs))
    assert holds >= 5
    spread = np.std(e, ddof=1)
    half = np.median([Z95 * c["restitution_sd"] for c in runs])
    assert 0.5 < half / (Z95 * spread) < 2.0
    forecast = reference["forecast"]
    assert 0.5 < forecast["restitution_sd"] / spread < 2.0
    # the forecast's draws are the configuration's, the same for every seed: its own
    # sampling error is not averaged out over seeds and must be small (60 replicates
    # gave ±9 %, and the rigid collision's 0.113 where 600 give 0.099)
    assert forecast["replicates_with_restitution"] == 200
    assert forecast["restitution_sd_se"] < 0.055 * forecast["restitution_sd"]
    assert forecast["peak_force_N"] == reference["peak_force_N"]
    assert forecast["noise_force_N"] == pytest.approx(5.0 / 3.0)
    assert forecast["peak_to_noise"] == pytest.approx(reference["peak_force_N"] / (5.0 / 3.0))
    # the replicates' mean error predicts the runs' (sd of the mean over six seeds: ~0.05)
    assert forecast["restitution_error_mean"] == pytest.approx(
        (forecast["restitution_mean"] - ei) / ei)
    assert abs(forecast["restitution_mean"] - e.mean()) < 3 * spread / np.sqrt(6) + 0.03


def test_without_noise_the_forecast_is_zero_spread():
    """No sensor noise: every replicate is the same contact (no calibration error
    either), so the forecast sd is 0 — the spread is the noise's, nothing else's."""
    config = short_collision("sensor.noise_force_N=0", "sensor.noise_torque_Nm=0",
                             "uncertainty.forecast_replicates=3")
    reference = checked_reference(config, config.loop.duration_s)
    assert reference["forecast"]["restitution_sd"] == 0.0
    assert reference["forecast"]["peak_to_noise"] is None


def test_fields_are_null_where_there_is_no_restitution_or_no_collision(reference):
    """A run that ends during its contact has no restitution: no sd, no interval; a run
    of one satellite has no collision and no forecast; uncertainty off: no interval."""
    config = short_collision("loop.duration_s=0.8", "uncertainty.replicates=2")
    ref = checked_reference(config, 0.8)
    coll = run_scenario(config, ideal=ref, preflight_done=True).metrics["collision"]
    assert coll["restitution"] is None and coll["contact_open_at_end"]
    assert coll["restitution_sd"] is None and coll["restitution_interval_95"] is None
    off = short_collision("uncertainty.enabled=false")
    metrics = run_scenario(off, ideal=reference, preflight_done=True).metrics
    assert metrics["collision"]["restitution"] is not None
    assert metrics["collision"]["restitution_sd"] is None
    assert metrics["collision"]["restitution_interval_95"] is None
    single = run_scenario(load_scenario("free-floating-scripted"), mode="ideal",
                          duration_s=0.1).metrics
    assert single["collision"] is None and single["collision_forecast"] is None


@pytest.mark.parametrize("key, value, message", [
    ("replicates", 1, "uncertainty.replicates: must be 2 or more (a standard deviation "
                      "needs two replicates), got 1"),
    ("forecast_replicates", 0, "uncertainty.forecast_replicates: must be 2 or more (a "
                               "standard deviation needs two replicates), got 0"),
    ("lead_s", 0.01, "uncertainty.lead_s: Input should be greater than or equal to 0.1"),
])
def test_bad_settings_are_refused_by_name(key, value, message):
    with pytest.raises(ConfigError) as err:
        merge_overrides(load_scenario("collision"), {"uncertainty": {key: value}})
    assert message in str(err.value)


@pytest.mark.parametrize("keys, message", [
    ({"replicates": 8}, "uncertainty: replicates is set but enabled is false: it would have "
                        "no effect (set enabled = true, or leave it out)"),
    ({"forecast_replicates": 8, "lead_s": 0.2},
     "uncertainty: forecast_replicates, lead_s are set but enabled is false: they would "
     "have no effect (set enabled = true, or leave them out)"),
])
def test_settings_with_the_uncertainty_off_are_refused_by_name(keys, message):
    """With ``enabled`` off the other keys change nothing: giving them is a mistake; a
    configuration that leaves them out survives a round trip through config.json and a
    further patch."""
    with pytest.raises(ConfigError) as err:
        merge_overrides(load_scenario("collision"), {"uncertainty": {"enabled": False, **keys}})
    assert message in str(err.value)
    off = merge_overrides(load_scenario("collision"), {"uncertainty": {"enabled": False}})
    again = merge_overrides(EmulatorConfig.model_validate(off.model_dump(mode="json")),
                            {"loop": {"seed": 3}})
    assert not again.uncertainty.enabled and again.uncertainty.replicates is None


def test_a_lead_before_the_start_is_named_with_the_lead_used(reference):
    """A lead longer than the time to the first touch: the snapshot is the first cycle's,
    and the run's metrics and the forecast say which lead was used."""
    config = short_collision("uncertainty.lead_s=1.0", "uncertainty.replicates=2",
                             "uncertainty.forecast_replicates=2")
    touch_s = reference["contact_start_s"]
    message = (f"uncertainty.lead_s = 1 s would put the snapshot at t = {touch_s - 1:.3f} s, "
               f"before the run starts: it was taken at t = 0, {touch_s:.3f} s before the "
               f"ideal run's first touch")
    result = run_scenario(config, ideal=reference, preflight_done=True)
    coll = result.metrics["collision"]
    assert message in coll["warnings"]
    assert result.emulator.snapshot.t_s == 0.0 and coll["restitution_sd"] is not None
    assert forecast(config, reference)["note"] == message


@pytest.mark.parametrize("material", ["sponge", "rigid"])
def test_with_the_noise_at_zero_the_interval_holds_the_ideal(material):
    """No noise: the replicates agree (sd ~ 0), and the interval is the chain's systematic
    error alone, the forecast's noise-free twin against the ideal run: it reaches from
    the run's e to the ideal e (sponge vs rigid, and rigid vs rigid)."""
    config = short_collision("sensor.noise_force_N=0", "sensor.noise_torque_Nm=0",
                             "uncertainty.replicates=2", "uncertainty.forecast_replicates=2",
                             f'satellites.1.material="{material}"')
    ref = checked_reference(config, config.loop.duration_s)
    metrics = run_scenario(config, ideal=ref, preflight_done=True).metrics
    coll = metrics["collision"]
    e, e_ideal, delta = coll["restitution"], ref["restitution"], coll["restitution_systematic"]
    for key in ("rendering_error_m", "contact_depth_m"):  # the twin's R1 is the run's
        assert metrics["collision_forecast"][key] == pytest.approx(coll[key], rel=1e-9)
    assert coll["restitution_sd"] < 1e-9
    assert delta == pytest.approx(e - e_ideal, abs=1e-9)  # the twin is this very run
    assert coll["restitution_bias_noisy"] == pytest.approx(delta, abs=1e-9)  # and so are
    # the forecast's replicates, with no noise to draw
    assert abs(delta) > 1e-4  # a point interval would miss the ideal
    low, high = coll["restitution_interval_95"]
    assert low <= e_ideal <= high and low <= e <= high
    assert high - low == pytest.approx(abs(delta), abs=1e-9)
    assert coll["uncertainty"]["systematic"].startswith("the forecast's noise-free twin")


def _forecast_of(e_ideal: float, e_twin: float | None, mean: float | None) -> dict:
    """A forecast's restitution fields as app.runs.uncertainty.forecast gives them."""
    return {"restitution_noise_free": e_twin,
            "restitution_systematic": None if e_twin is None else e_twin - e_ideal,
            "restitution_mean": mean,
            "restitution_error_mean": None if mean is None else (mean - e_ideal) / e_ideal}


def _noisy_run(e: float, sd: float) -> dict:
    return {"restitution": e, "restitution_sd": sd,
            "restitution_interval_95": [e - Z95 * sd, e + Z95 * sd],
            "uncertainty": {"replicates": 30}}


def test_a_bias_the_noise_makes_widens_the_interval_to_the_ideal():
    """A contact the noise makes stick (the noisy replicates' mean 0.019 against the
    ideal 0.297) while the noise-free twin parts (0.075): the run's e 0.001 ± 1.96 x
    0.030 reaches the ideal by the noisy bias -0.278, and would not by the twin's -0.222."""
    coll, twin_only = _noisy_run(0.001, 0.030), _noisy_run(0.001, 0.030)
    add_systematic(coll, _forecast_of(0.297, 0.075, 0.019))
    add_systematic(twin_only, {"restitution_systematic": 0.075 - 0.297})
    assert coll["restitution_systematic"] == pytest.approx(-0.222)
    assert coll["restitution_bias_noisy"] == pytest.approx(-0.278)
    low, high = coll["restitution_interval_95"]
    assert low == pytest.approx(0.001 - Z95 * 0.030)
    assert high == pytest.approx(0.001 + Z95 * 0.030 + 0.278)
    assert low <= 0.297 <= high and twin_only["restitution_interval_95"][1] < 0.297
    assert coll["uncertainty"]["systematic"] == (
        "the forecast's noise-free twin and its noisy replicates' mean against the ideal "
        "run, the further of the two added on the ideal's side")
    assert report.interval_text(coll) == (
        f"restitution 95 % interval [{low:.3f}, {high:.3f}] (sd 0.030, 30 replicates of "
        "the contact with the noise measured at calibration, widened by the chain's "
        "systematic error -0.278 (noisy replicates' mean); the noise-free twin's -0.222)")


def test_widening_names_each_sides_estimate():
    """The low side takes the largest positive δ, the high side the most negative; a tie
    goes to the first estimate; a δ of zero widens nothing."""
    twin, noisy = "noise-free twin", "noisy replicates' mean"
    assert widening([(0.03, twin), (0.03, noisy)]) == ((0.03, twin), None)
    assert widening([(-0.01, twin), (-0.04, noisy)]) == (None, (-0.04, noisy))
    assert widening([(-0.1, twin), (0.2, noisy)]) == ((0.2, noisy), (-0.1, twin))
    assert widening([(0.0, twin)]) == (None, None)
    assert widening([]) == (None, None)


def test_where_the_twins_bias_is_the_larger_the_interval_is_the_twins():
    """The twin's δ +0.030 beyond the noisy mean's +0.010: the interval is widened
    below by +0.030 alone, as with the twin's alone; a noisy bias of the other sign
    (-0.010) widens the other side by its own."""
    alone, both = _noisy_run(0.35, 0.05), _noisy_run(0.35, 0.05)
    add_systematic(alone, {"restitution_systematic": 0.030})
    add_systematic(both, _forecast_of(0.30, 0.33, 0.31))
    assert alone["restitution_bias_noisy"] is None
    assert both["restitution_bias_noisy"] == pytest.approx(0.010)
    assert both["restitution_interval_95"] == pytest.approx(alone["restitution_interval_95"])
    assert alone["restitution_interval_95"] == pytest.approx(
        [0.35 - Z95 * 0.05 - 0.030, 0.35 + Z95 * 0.05])
    assert "widened by the chain's systematic error +0.030 (noise-free twin); the noisy " \
           "replicates' mean's +0.010)" in report.interval_text(both)
    apart = _noisy_run(0.35, 0.05)
    add_systematic(apart, _forecast_of(0.30, 0.33, 0.29))
    assert apart["restitution_interval_95"] == pytest.approx(
        [0.35 - Z95 * 0.05 - 0.030, 0.35 + Z95 * 0.05 + 0.010])
    assert "errors +0.030 (noise-free twin) and -0.010 (noisy replicates' mean)" \
        in report.interval_text(apart)


def test_without_a_forecast_or_its_estimates_the_interval_is_the_noises():
    """No forecast, or one with neither a twin's nor a noisy mean's restitution: the
    interval is left the noise's, both estimates are None, and the run says why."""
    for given, why in ((None, "no forecast"), (_forecast_of(0.3, None, None),
                                               "the forecast has neither")):
        coll = _noisy_run(0.3, 0.05)
        add_systematic(coll, given)
        assert coll["restitution_interval_95"] == _noisy_run(0.3, 0.05)["restitution_interval_95"]
        assert coll["restitution_systematic"] is None and coll["restitution_bias_noisy"] is None
        assert coll["uncertainty"]["systematic"].startswith(f"not included ({why}")
    only_noisy = _noisy_run(0.0, 0.01)  # the twin gave no restitution, the replicates did
    add_systematic(only_noisy, _forecast_of(0.3, None, 0.02))
    assert only_noisy["restitution_bias_noisy"] == pytest.approx(-0.28)
    assert only_noisy["restitution_interval_95"][1] == pytest.approx(Z95 * 0.01 + 0.28)
    assert only_noisy["uncertainty"]["systematic"].startswith("the forecast's noisy")


def test_the_forecasts_twin_gets_the_noise_its_calibration_would_measure():
    """The forecast's noise-free twin is given the covariance a calibration measures from
    noisy rest readings (the pair fusion's Newton check and the deadbands read it):
    against the real calibration of the same configuration with the data sheet's noise
    (1000 readings per arm: a variance known to about ±4.5 %), the force and COM-torque
    covariances' diagonals agree within 15 % and the deadbands within 8 %; the twin's own
    calibration (noise off) has none (round-off)."""
    from app.runs.uncertainty import configured_noise, expect_measured_noise

    config = short_collision()
    noisy = Emulator(config)
    noisy.prepare()
    twin = Emulator(merge_overrides(config, {"sensor": {"noise_force_N": 0.0,
                                                        "noise_torque_Nm": 0.0}}))
    twin.prepare()
    assert np.all(np.abs(twin.arms[0].processor.calibration.force_noise_cov_S) < 1e-20)
    expect_measured_noise(twin, configured_noise(config))
    for got, want in zip(twin.arms, noisy.arms, strict=True):
        g, w = got.processor, want.processor
        for a, b in ((g.calibration.force_noise_cov_S, w.calibration.force_noise_cov_S),
                     (g.calibration.torque_noise_cov_S, w.calibration.torque_noise_cov_S)):
            np.testing.assert_allclose(np.diag(a), np.diag(b), rtol=0.15)
        assert g.deadband_force_N == pytest.approx(w.deadband_force_N, rel=0.08)
        assert g.deadband_torque_Nm == pytest.approx(w.deadband_torque_Nm, rel=0.08)


@pytest.mark.parametrize("draw, kurtosis", [
    (lambda rng, shape: rng.standard_normal(shape), 0.0),
    (lambda rng, shape: rng.laplace(size=shape), 3.0),
    (lambda rng, shape: rng.uniform(size=shape), -1.2),
])
def test_the_standard_error_of_a_spread_is_the_scatter_of_its_estimates(draw, kurtosis):
    """sd_standard_error against the scatter of the sd over 4000 samples of 200 draws (the
    forecast's count), for a normal, a heavy-tailed (Laplace, excess kurtosis 3) and a
    light-tailed (uniform, -1.2) distribution: the mean predicted error within 8 % of the
    scatter it predicts (the scatter of 4000 sds is known to about ±1-2 %; for the Laplace
    the sample kurtosis of 200 draws runs low, -5 %, of 60 draws -11 %); with fewer than
    four values there is none, and a constant sample has none."""
    n = 200
    rng = np.random.default_rng(28)
    samples = draw(rng, (4000, n))
    sds = np.std(samples, axis=1, ddof=1)
    predicted = np.array([sd_standard_error(x) for x in samples])
    assert np.mean(predicted) == pytest.approx(np.std(sds, ddof=1), rel=0.08)
    # the normal closed form s / sqrt(2 (n - 1)) is the kurtosis-0 case
    normal_form = np.mean(sds) / np.sqrt(2 * (n - 1))
    assert (np.mean(predicted) / normal_form) ** 2 == pytest.approx(
        1 + (n - 1) * kurtosis / (2 * n), abs=0.3)
    assert sd_standard_error([1.0, 2.0, 3.0]) is None
    assert sd_standard_error([0.3] * 10) == pytest.approx(0.0, abs=1e-15)
