"""Collision metrics (app/runs/metrics.py): what the mockups went through, against closed forms."""

from __future__ import annotations

import numpy as np
import pytest

from app.config import merge_overrides
from app.runs.headless import run_scenario
from app.runs.metrics import collision_metrics, compare_with_ideal, contact_pair
from app.scenarios import load_scenario
from tests.runs.test_uncertainty import significant_noisy_bias


@pytest.fixture(scope="module")
def ideal():
    return run_scenario(load_scenario("collision"), mode="ideal", duration_s=6.0)


@pytest.fixture(scope="module")
def hil():  # the forecast's default 200 replicates are not what these tests check
    return run_scenario(merge_overrides(load_scenario("collision"),
                                        {"uncertainty": {"forecast_replicates": 20}}),
                        mode="hil", duration_s=6.0)


def test_ideal_contact_energy_is_the_kinetic_energy_the_impact_lost(ideal):
    coll = ideal.metrics["collision"]
    e, m_red, v0 = coll["restitution"], 0.5, 0.16
    assert coll["contact_energy_J"] == pytest.approx(0.5 * m_red * v0**2 * (1 - e * e),
                                                     rel=1e-3)


def test_ideal_true_impulse_is_what_the_ods_received_and_the_momentum_change(ideal):
    coll = ideal.metrics["collision"]
    for name in ("sat1", "sat2"):
        np.testing.assert_allclose(coll["true_impulse_Ns"][name], coll["impulse_Ns"][name],
                                   rtol=0, atol=1e-12)
    j = np.array(coll["true_impulse_Ns"]["sat2"])
    assert j[0] == pytest.approx(0.5 * 0.16 * (1 + coll["restitution"]), rel=1e-3)
    assert coll["true_impulse_ratio"] == {"sat1": 1.0, "sat2": 1.0}
    assert coll["restitution_error"] == 0.0


def test_ideal_peak_force_and_duration_of_the_hunt_crossley_impact(ideal):
    from scipy.integrate import solve_ivp

    k = 1 / (1 / 500.0 + 1 / 2e4)
    c = (20.0 / 500.0 + 0.5 / 2e4) * k

    def rhs(_t, s):
        return [s[1], -max(0.0, k * s[0] * (1 + c * s[1])) / 0.5 if s[0] > 0 else 0.0]

    def apart(_t, s):
        return s[0]

    apart.terminal, apart.direction = True, -1
    sol = solve_ivp(rhs, (0, 1), [0.0, 0.16], rtol=1e-10, atol=1e-14, events=apart,
                    dense_output=True, max_step=1e-4)
    t = np.linspace(0, sol.t_events[0][0], 4000)
    d, dd = sol.sol(t)
    peak = np.max(np.maximum(0.0, k * d * (1 + c * dd)))
    coll = ideal.metrics["collision"]
    assert coll["peak_force_N"] == pytest.approx(peak, rel=0.01)
    # the force lasts until it reaches zero (no pull): within two 2 ms cycles of the ODE's
    last_force = t[np.nonzero(k * d * (1 + c * dd) > 0)[0][-1]]
    assert abs(coll["contact_duration_s"] - last_force) <= 2 * 0.002


def test_a_contact_under_the_deadband_is_named_where_a_sensor_meets_it(ideal):
    """The deadband warning belongs to a run with a sensor whose deadband the contact
    meets: not to an ideal run (no sensor), not where the contact gate lifts it."""
    coll = ideal.metrics["collision"]
    assert coll["peak_force_N"] < 4.0
    assert coll["warnings"] == []
    gateless = merge_overrides(load_scenario("collision"), {"wrench": {"contact_gate": False}})
    assert run_scenario(gateless, mode="ideal", duration_s=6.0).metrics["collision"][
        "warnings"] == []  # an ideal run has no sensor
    met = {k: v for k, v in coll.items() if k != "warnings"}
    compare_with_ideal(met, coll, deadband_N=4.0)
    assert met["warnings"] == [
        f"the ideal contact peaks at {coll['peak_force_N']:.1f} N, under the F/T force "
        "deadband of 4 N: the sensor cannot see it whole"]
    met = {k: v for k, v in coll.items() if k != "warnings"}
    compare_with_ideal(met, coll, deadband_N=0.0)  # the gate lifts it
    assert met["warnings"] == []


# --- synthetic telemetry: two 1 kg bodies on the x axis, a contact force profile ----------

DT = 0.002
FIELDS = ("x_m", "y_m", "z_m", "vx_mps", "vy_mps", "vz_mps", "fx_N", "fy_N", "fz_N",
          "true_fx_N", "true_fy_N", "true_fz_N")


def _telemetry(force_N: np.ndarray, v0_mps: float = 0.1, n_sat: int = 2,
               pair: tuple[int, int] = (0, 1)) -> tuple[np.ndarray, dict]:
    """Rows of bodies pair[0] (at -0.2 m, moving +v0) and pair[1] (at +0.2 m, moving -v0)
    under ±force_N[k] along x over cycle k (Newton, 1 kg), the others at rest far away;
    the ODS receives the true force."""
    index = {"t_s": 0}
    for s in range(1, n_sat + 1):
        for f in FIELDS:
            index[f"sat{s}_{f}"] = len(index)
    rows = np.zeros((len(force_N), len(index)))
    rows[:, 0] = DT * np.arange(len(force_N))
    x = {pair[0]: -0.2, pair[1]: 0.2}
    v = {pair[0]: v0_mps, pair[1]: -v0_mps}
    for s in set(range(n_sat)) - set(pair):
        rows[:, index[f"sat{s + 1}_y_m"]] = 5.0 * (s + 1)  # the others: far away
    for k, f in enumerate(force_N):
        for s, sign in ((pair[0], -1.0), (pair[1], 1.0)):
            c = f"sat{s + 1}_"
            rows[k, index[c + "x_m"]], rows[k, index[c + "vx_mps"]] = x[s], v[s]
            rows[k, index[c + "fx_N"]] = rows[k, index[c + "true_fx_N"]] = sign * f
            v[s] += sign * f * DT
            x[s] += v[s] * DT
    return rows, index


def _pulses(*spans: tuple[float, float, float], total_s: float = 1.0) -> np.ndarray:
    """A force profile: (start s, end s, N) blocks."""
    f = np.zeros(int(round(total_s / DT)))
    for t0, t1, value in spans:
        f[int(round(t0 / DT)):int(round(t1 / DT))] = value
    return f


def test_a_clean_bounce_gives_the_restitution_of_its_impulse():
    """Impulse 0.15 N s on each 1 kg body closing at 0.2 m/s: they part at 0.1 m/s, e 0.5."""
    rows, index = _telemetry(_pulses((0.1, 0.13, 5.0)))
    coll = collision_metrics(rows, index, DT)
    assert coll["restitution"] == pytest.approx(0.5, rel=1e-9)
    assert coll["warnings"] == [] and coll["contact_open_at_end"] is False
    assert coll["pair"] == ["sat1", "sat2"]


def test_bodies_that_do_not_part_get_no_restitution_but_a_warning():
    """Impulse 0.06 N s: still closing at 0.08 m/s after the contact (the arms' stuck
    case): no negative "restitution"."""
    rows, index = _telemetry(_pulses((0.1, 0.112, 5.0)))
    coll = collision_metrics(rows, index, DT)
    assert coll["restitution"] is None
    assert len(coll["warnings"]) == 1
    assert coll["warnings"][0].startswith(
        "the satellites were not moving apart after the contact (relative normal velocity "
        "-80.0 mm/s at t = ")


def test_a_touch_while_moving_apart_gives_no_restitution_but_a_warning():
    """A body grazed while the two already separate (e.g. a light satellite thrown about
    by sensor noise): no approach, so no restitution, and the metrics say why."""
    rows, index = _telemetry(_pulses((0.1, 0.13, 5.0)), v0_mps=-0.05)
    coll = collision_metrics(rows, index, DT)
    assert coll["restitution"] is None
    assert coll["warnings"][0].startswith(
        "the satellites were not closing in before the first touch (relative normal "
        "velocity +100.0 mm/s at t = 0.050 s)")


def test_a_second_touch_is_named_and_left_out():
    rows, index = _telemetry(_pulses((0.1, 0.13, 5.0), (0.5, 0.52, 1.0)))
    coll = collision_metrics(rows, index, DT)
    assert coll["restitution"] == pytest.approx(0.5, rel=1e-9)  # the first contact's
    assert coll["contact_end_s"] == pytest.approx(0.128)
    assert coll["warnings"] == ["the bodies touched again at t = 0.500 s: the collision "
                                "metrics cover the first contact only"]


def test_a_contact_open_at_the_end_has_no_restitution_and_no_impulse_ratio():
    rows, index = _telemetry(_pulses((0.9, 1.0, 5.0)))
    coll = collision_metrics(rows, index, DT)
    assert coll["contact_open_at_end"] is True and coll["restitution"] is None
    assert coll["warnings"] == ["the contact had not ended when the run stopped at t = "
                                "0.998 s: its impulse is incomplete, no restitution"]
    done = collision_metrics(*_telemetry(_pulses((0.1, 0.13, 5.0))), DT)
    compare_with_ideal(coll, done, deadband_N=0.0)
    assert coll["true_impulse_ratio"] is None and coll["restitution_error"] is None
    assert len(coll["warnings"]) == 1  # kept, not overwritten


def test_the_pair_is_found_among_three_satellites():
    """Satellites 2 and 3 collide while 1 flies alone: the metrics name and measure them."""
    rows, index = _telemetry(_pulses((0.1, 0.13, 5.0)), n_sat=3, pair=(1, 2))
    assert contact_pair(rows, index, 3) == (2, 3)
    coll = collision_metrics(rows, index, DT, *contact_pair(rows, index, 3))
    assert coll["pair"] == ["sat2", "sat3"]
    assert coll["restitution"] == pytest.approx(0.5, rel=1e-9)
    assert collision_metrics(rows, index, DT) is None  # 1 and 2 never touch


def test_a_push_on_one_satellite_is_no_contact():
    rows, index = _telemetry(np.zeros(100))
    rows[10:20, index["sat1_true_fx_N"]] = 3.0  # the hand, on satellite 1 alone
    assert contact_pair(rows, index, 2) is None
    assert collision_metrics(rows, index, DT) is None


def test_hil_metrics_compare_the_actual_mockups_with_the_ideal_run(hil, ideal):
    coll, ref = hil.metrics["collision"], ideal.metrics["collision"]
    ja, jb = (np.array(coll["true_impulse_Ns"][n]) for n in ("sat1", "sat2"))
    np.testing.assert_allclose(ja + jb, 0.0, atol=1e-12)  # action and reaction on the mockups
    assert coll["restitution_ideal"] == ref["restitution"]
    assert coll["restitution_error"] == pytest.approx(
        (coll["restitution"] - ref["restitution"]) / ref["restitution"])
    assert coll["true_impulse_ratio"]["sat2"] == pytest.approx(
        np.linalg.norm(jb) / np.linalg.norm(ref["true_impulse_Ns"]["sat2"]))
    assert coll["contact_energy_J"] > 0.0  # a dissipative contact absorbs energy
    assert ref["approach_speed_mps"] == pytest.approx(0.16, rel=1e-3)
    assert ref["touches"] == 1 and ref["warnings"] == []
    # the noise may part the bodies for a few ms near the contact's soft end: named if so
    chatter = [f"the bodies touched {coll['touches']} times within this contact"]
    assert [w[:len(chatter[0])] for w in coll["warnings"]] == chatter * (coll["touches"] > 1)
    # the interval (app/runs/uncertainty.py) replaced the unchecked open-loop bound
    e, sd = coll["restitution"], coll["restitution_sd"]
    assert sd > 0.0
    fc = hil.metrics["collision_forecast"]
    delta = fc["restitution_systematic"]  # the chain's, twice: the noise-free twin's and
    noisy = significant_noisy_bias(fc, ref["restitution"])  # the noisy replicates' mean's
    assert coll["restitution_systematic"] == delta
    assert coll["restitution_bias_noisy"] == (None if noisy is None
                                              else pytest.approx(noisy, abs=1e-12))
    noisy = 0.0 if noisy is None else noisy  # within its sampling error: not added
    assert coll["restitution_interval_95"] == pytest.approx(  # the further on the ideal's side
        [e - 1.959964 * sd - max(delta, noisy, 0.0), e + 1.959964 * sd + max(-delta, -noisy, 0.0)])
    assert ref["restitution_sd"] is None and ref["restitution_interval_95"] is None  # ideal
    assert hil.metrics["collision_forecast"]["restitution_sd"] > 0.0


def test_touches_closer_than_the_quiet_time_are_one_contact_with_a_chatter_warning():
    """Two touches 10 ms apart (chatter): one contact, counted, and the first touch's own
    length named beside the whole span."""
    rows, index = _telemetry(_pulses((0.1, 0.12, 5.0), (0.13, 0.14, 5.0)))
    coll = collision_metrics(rows, index, DT)
    assert coll["touches"] == 2
    assert coll["contact_duration_s"] == pytest.approx(0.04)
    assert coll["restitution"] == pytest.approx(0.5, rel=1e-9)  # 0.15 N s in all
    assert coll["warnings"] == [
        "the bodies touched 2 times within this contact (apart for 10 ms at most, under the "
        "50 ms that end a contact): chatter or a re-touch; contact_duration_s spans them "
        "all, the first touch alone lasted 20 ms"]
    assert collision_metrics(*_telemetry(_pulses((0.1, 0.13, 5.0))), DT)["touches"] == 1


def test_a_run_that_stops_right_after_the_contact_names_the_missing_restitution():
    """The contact ended (50 ms quiet) but the run stopped within the 20 ms after the
    window at which the velocities are read."""
    rows, index = _telemetry(_pulses((0.1, 0.13, 5.0), total_s=0.19))
    coll = collision_metrics(rows, index, DT)
    assert coll["contact_open_at_end"] is False and coll["restitution"] is None
    assert coll["warnings"] == [
        "the run stopped at t = 0.188 s, before the velocities after the contact could be "
        "read (t = 0.198 s, 20 ms past the contact window): no restitution"]


def test_a_restitution_above_one_is_named_as_energy_the_emulation_put_in():
    """A contact that pushes the bodies apart harder than they came (e 1.5; the impulse of
    a dissipative contact cannot do that): the figure is kept, with a warning."""
    rows, index = _telemetry(_pulses((0.1, 0.15, 5.0)))
    coll = collision_metrics(rows, index, DT)
    assert coll["restitution"] == pytest.approx(1.5, rel=1e-9)
    [warning] = coll["warnings"]
    assert warning.startswith("restitution 1.500 > 1: the satellites left faster than they "
                              "came, which a dissipative contact cannot do (the contact "
                              "itself absorbed -")
    assert warning.endswith("mJ): the emulation put energy into the collision")


def test_a_contact_the_ods_never_felt_is_named_and_the_summary_prints():
    """True force on the mockups, none received by the ODS (a deadband that hid it): no
    impulse balance, a warning, and the printed summary copes."""
    from app.runs.report import run_summary

    rows, index = _telemetry(_pulses((0.1, 0.13, 5.0)))
    for s in (1, 2):
        rows[:, index[f"sat{s}_fx_N"]] = 0.0
    coll = collision_metrics(rows, index, DT)
    assert coll["impulse_balance"] is None
    assert coll["warnings"][-1].startswith("the ODS received no force over the contact window")
    metrics = {"scenario": "x", "mode": "hil", "status": "finished", "duration_s": 1.0,
               "cycles": 500, "rate_hz": 500.0, "realtime_factor": 1.0,
               "cycle_time_us": {"p50": 1.0, "p99": 2.0}, "satellites": [],
               "force_scale": 1.0, "torque_scale": 1.0,
               "collision": {**coll, "restitution_ideal": None, "restitution_error": None,
                             "true_impulse_ratio": None}, "safety_stop": None,
               "passivity": None, "warnings": []}
    assert "impulse balance -" in run_summary(metrics)


def test_a_third_body_in_the_contact_is_named():
    rows, index = _telemetry(_pulses((0.1, 0.13, 5.0)), n_sat=3)
    rows[60:62, index["sat3_true_fx_N"]] = 1.0  # within the window (0.05 .. 0.18 s)
    coll = collision_metrics(rows, index, DT)
    assert any(w.startswith("sat3 also felt a force during this contact")
               for w in coll["warnings"])


def test_what_the_ideal_run_cannot_give_is_named():
    """An ideal run without a restitution, and one whose contact spans few cycles."""
    coll = collision_metrics(*_telemetry(_pulses((0.1, 0.13, 5.0))), DT)
    ideal = collision_metrics(*_telemetry(_pulses((0.1, 0.112, 5.0))), DT)  # no parting
    compare_with_ideal(coll, ideal, deadband_N=0.0)
    assert coll["restitution_error"] is None
    assert coll["warnings"] == [
        "the ideal run gives no restitution to compare with (the satellites were not "
        "moving apart after the contact (relative normal velocity -80.0 mm/s at t = "
        "0.180 s): no restitution)"]
    coll = collision_metrics(*_telemetry(_pulses((0.1, 0.13, 5.0))), DT)
    short = collision_metrics(*_telemetry(_pulses((0.1, 0.108, 18.75))), DT)  # 4 cycles
    compare_with_ideal(coll, short, deadband_N=0.0)
    assert coll["warnings"] == [
        "the ideal contact lasts 4.0 cycles at this rate: its peak force and duration are "
        "sampled once per cycle, and the reference is not converged; raise loop.rate_hz"]


def test_a_contact_beyond_the_sensor_range_stops_the_run_or_is_named():
    """Rigid mockups closing at 1 m/s: the contact peaks far beyond the F/T range of
    100 N. By default the reading at the range stops the run; with
    ``stop_at_sensor_range`` off the run goes on and the metrics say the readings clipped.
    (No forecast: with its noise's drift after so hard a contact, the pre-flight would
    refuse the run before it reaches the range.)"""
    fast = {"satellites": {"0": {"velocity_mps": [0.5, 0.0, 0.0]},
                           "1": {"velocity_mps": [-0.5, 0.0, 0.0], "material": "rigid"}},
            "uncertainty": {"enabled": False}}
    stopped = run_scenario(merge_overrides(load_scenario("collision"), fast), duration_s=2.0)
    assert stopped.metrics["safety_stop"]["reason"] == (
        "F/T force reading at the sensor's 100 N range: the contact pushes harder than it "
        "can measure")
    cfg = merge_overrides(load_scenario("collision"),
                          {**fast, "loop": {"stop_at_sensor_range": False}})
    coll = run_scenario(cfg, duration_s=2.0).metrics["collision"]
    assert coll["peak_force_N"] > 100.0
    assert any(w.startswith(f"the contact peaked at {coll['peak_force_N']:.0f} N, beyond the "
                            f"F/T sensor's 100 N range: its readings clipped")
               for w in coll["warnings"])


def test_a_satellite_the_sensor_noise_can_spin_is_warned_about(tmp_path):
    """The rendezvous at k_M = 500: each 500 kg, 300 kg m2 satellite is 1.5e-5 kg m2 in lab
    units, and one sample at the 0.25 N m deadband for a 2 ms cycle turns it at 33 rad/s;
    at the scenario's k_M = 1 (0.0075 kg m2: 0.067 rad/s), and in every built-in scenario,
    no warning."""
    from app.config import merge_overrides
    from app.runs.metrics import noise_spin_warnings
    from app.scenarios import load_scenario, scenario_names

    heavy = merge_overrides(load_scenario("rendezvous"), {"scaling": {"mass": 500.0}})
    warned = noise_spin_warnings(heavy, [0, 1])
    assert len(warned) == 2 and warned[1] == (
        "satellite 'target': its inertia in lab units (1.5e-05 kg m2) is so small that one "
        "F/T sample at the torque deadband (0.25 N m) for one cycle would turn it at 33.3 "
        "rad/s: the sensor's noise can spin it (lower scaling.mass or scaling.length, or "
        "raise its inertia)")
    assert noise_spin_warnings(heavy, []) == []  # nothing carried (an ideal run)
    # the CLI says so on stderr before the arms move (here: then the stop it predicted)
    import json
    import subprocess

    from tests.test_cli import EXE

    proc = subprocess.run([EXE, "run", "rendezvous", "--out", str(tmp_path / "out"), "--quiet",
                           "--duration", "0.5", "--set", "scaling.mass=500"],
                          capture_output=True, text=True, timeout=300)
    assert proc.stderr.startswith(f"warning: {warned[0]}\nwarning: {warned[1]}\n"), proc.stderr
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert metrics["warnings"] == warned
    for name in scenario_names():
        cfg = load_scenario(name)
        assert noise_spin_warnings(cfg, list(range(len(cfg.satellites)))) == [], name


def test_the_off_normal_noise_bound_counts_the_samples_a_slower_sensor_takes():
    """The off-normal warning's noise bound adds one independent sample per sample
    interval: every 2 ms cycle for the UR10e's sensor, every 10 ms for the FT 300-S's
    100 Hz stream (held in between), whatever the loop's rate; no sensor without arms."""
    from app.runs.metrics import _sensor_noise

    cfg = load_scenario("collision")
    assert _sensor_noise(cfg, True) == (cfg.sensor.noise_force_N, 1.0 / 500.0)
    slow = merge_overrides(cfg, {"sensor": {"model": "robotiq-ft300s"}})
    assert _sensor_noise(slow, True) == (0.1, 1.0 / 100.0)
    assert _sensor_noise(cfg, False) is None
