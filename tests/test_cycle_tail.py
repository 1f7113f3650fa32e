"""The cycle's fused tail and fused rest (app/sim/cycle_tail.py) against the stages of
Emulator.step."""

from __future__ import annotations

import numpy as np
import pytest

import app.sim.loop as loop
from app.config import merge_overrides
from app.scenarios import load_scenario, scenario_names
from app.sim.loop import Emulator
from app.sim.servo import SafetyBox
from app.sim.telemetry import Recorder


def _arm_state(em: Emulator) -> list:
    """What the tail writes of each arm: the VFDM's and the servo's state, the forward
    kinematics the next cycle reads."""
    out = []
    for arm in em.arms:
        v, s = arm.vfdm, arm.servo
        out += [v._x, v.last_error, v.last_scale, s.state.q_rad, s.state.qd_radps,
                s.state.qdd_radps2, s.state.stopped, s.state.reason, s._ring, s._slot,
                s._sp_prev, *arm.mockup_state_W()]
    return out


def _stepped(config, fuse: bool, cycles: int, calls: dict | None = None) -> Emulator:
    """An emulator of config prepared and stepped `cycles` times (fewer if the run ends);
    ``calls`` (:func:`_counting`'s) counts from the first step on: building the emulator
    loads the tail's kernels with one call on scratch data."""
    em = Emulator(config, mode="hil")
    em.fuse_tail = fuse
    em.prepare()
    if calls is not None:
        calls["tail"] = calls["rest"] = 0
    for _ in range(cycles):
        em.step()
        if em.status != "running":
            break
    return em


def _counting(monkeypatch) -> dict:
    """Count the fused tail's compiled calls ("tail") and the fused rest's, the chain and
    the tail in one ("rest"); the kernels themselves run."""
    calls = {"tail": 0, "rest": 0}
    for name, key in (("tail_one_arm", "tail"), ("tail_two_arms", "tail"),
                      ("sensed_tail_one_arm", "rest")):
        kernel = getattr(loop, name)

        def counted(*args, _kernel=kernel, _key=key):
            calls[_key] += 1
            return _kernel(*args)

        monkeypatch.setattr(loop, name, counted)
    return calls


def _assert_same(fused: Emulator, stages: Emulator) -> None:
    assert (fused.status, fused.cycles, fused.safety_stop) == (
        stages.status, stages.cycles, stages.safety_stop)
    assert fused.ods.t_s == stages.ods.t_s
    np.testing.assert_array_equal(fused.ods.y, stages.ods.y)
    np.testing.assert_array_equal(fused.telemetry.rows(), stages.telemetry.rows())
    for a, b in zip(_arm_state(fused), _arm_state(stages), strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("name", scenario_names())
def test_the_fused_tail_is_the_stages_to_the_last_bit(name, monkeypatch):
    """Every shipped scenario, hil, 1,800 cycles (the collision's contact among them):
    the same telemetry, ODS state and arm states with the fused calls as with the
    stages; where the setting allows it, every cycle took one: the rest (one arm, no
    passivity, no gate: the free-floating runs) or the tail."""
    config = load_scenario(name)
    calls = _counting(monkeypatch)
    fused = _stepped(config, True, 1800, calls)
    taken, rest = calls["tail"], calls["rest"]
    stages = _stepped(config, False, 1800, calls)
    assert calls["tail"] == calls["rest"] == 0  # the stages never call them
    _assert_same(fused, stages)
    if fused._tail_fusable and not fused.gnc:
        assert taken + rest == fused.cycles > 1000  # (prepare() moves the arms, steps none)
        assert rest == (fused.cycles if fused._rest_fusable else 0)
    else:  # a rail, a capture to check or a GNC's own actuation: the stages
        assert taken == rest == 0
    if name.startswith("free-floating"):
        assert rest == fused.cycles


def test_a_servo_stop_in_the_fused_tail_stops_the_run_as_the_stages_do(monkeypatch):
    """A safety box 1 cm around the TCP once the run has started: the servo stops the
    arm inside the fused call, and the run ends with the stages' safety stop, at the
    same cycle, for the same reason."""
    calls = _counting(monkeypatch)
    ems, taken = [], []
    for fuse in (True, False):
        em = _stepped(load_scenario("free-floating-scripted"), fuse, 10, calls)
        servo = em.arms[0].servo
        p_W = servo.safety.tcp_position_W(servo.state.q_rad)
        servo.safety = SafetyBox(p_W - 0.01, p_W + 0.01, servo.safety.chain)
        em.arms[0]._fused = None  # the command path reads the servo's box anew
        for _ in range(20000):
            em.step()
            if em.status != "running":
                break
        ems.append(em)
        taken.append(calls["tail"] + calls["rest"])
    assert taken[0] == ems[0].cycles > 10 and taken[1] == 0  # (the rest: free-floating)
    assert ems[0].status == "safety_stop"
    assert ems[0].safety_stop["reason"] == "TCP left safety volume"
    _assert_same(*ems)


@pytest.mark.parametrize("n_arms", [1, 3])
def test_a_recorder_of_other_arms_raises_the_stages_error_and_writes_nothing(n_arms):
    """A recorder of one arm or three for the collision's two: the cycle raises the
    stages' ValueError (the fused call would write the second arm's columns outside the
    row's), with the ODS not advanced and no row claimed."""
    for fuse in (True, False):
        em = Emulator(load_scenario("collision"), mode="hil")
        em.fuse_tail = fuse
        em.prepare()
        em.step()
        em.recorder = Recorder(2, n_arms, 10, em.T_R_W, em.ods.params.orbit_rate_radps)
        t0 = em.ods.t_s
        with pytest.raises(ValueError, match=f"recorder of 2 satellites and {n_arms} arms "
                                             r"got .*, 2 arms$"):
            em.step()
        assert em.ods.t_s == t0 and em.recorder.buffer.count == 0


def test_a_row_that_does_not_fit_raises_the_stages_error_and_writes_nothing():
    """A recorder of another width (three satellites' columns for a two-satellite run):
    the fused call claims no row, and the cycle raises the stages' ValueError with the
    ODS not advanced, as the stages do."""
    errors, ts = [], []
    for fuse in (True, False):
        em = Emulator(load_scenario("collision"), mode="hil")
        em.fuse_tail = fuse
        em.prepare()
        em.step()
        em.recorder = Recorder(3, 2, 10, em.T_R_W, em.ods.params.orbit_rate_radps)
        t0 = em.ods.t_s
        with pytest.raises(ValueError) as err:
            em.step()
        errors.append(str(err.value))
        ts.append((t0, em.ods.t_s, em.recorder.buffer.count))
    assert errors[0] == errors[1]
    assert "recorder of 3 satellites and 2 arms" in errors[0]
    assert ts[0] == ts[1] and ts[0][0] == ts[0][1] and ts[0][2] == 0


def test_a_copy_of_the_loop_takes_the_fused_tail_on_its_own_buffers(monkeypatch):
    """copy_state (the replicates' and the forecast's twin of a run): the twin's fused
    tail writes the twin's telemetry and moves the twin's arms, bit for bit as a twin on
    the stages, and leaves the original as it was."""
    em = _stepped(load_scenario("collision"), True, 200)
    before = em.telemetry.rows().copy(), em.ods.y.copy()
    twins = [em.copy_state(capacity=2000), em.copy_state(capacity=2000)]
    twins[1].fuse_tail = False
    calls = _counting(monkeypatch)
    for twin in twins:
        for _ in range(1500):
            twin.step()
    assert calls["tail"] == 1500
    _assert_same(*twins)
    assert twins[0].telemetry.count == 1500
    np.testing.assert_array_equal(em.telemetry.rows(), before[0])
    np.testing.assert_array_equal(em.ods.y, before[1])


@pytest.mark.parametrize(("name", "overrides"), [
    ("collision", {"servo": {"model": "servoj"}}),
    ("free-floating", {"compensation": {"enabled": True, "servo_feedforward": True}}),
])
def test_a_setting_with_the_servo_feedforward_takes_the_stages(name, overrides, monkeypatch):
    """The servo feedforward (servoj) is not fused: the loop builds, and every cycle
    takes the stages, bit for bit as with the fused tail off."""
    config = merge_overrides(load_scenario(name), overrides)
    calls = _counting(monkeypatch)
    fused = _stepped(config, True, 300, calls)
    assert calls["tail"] == calls["rest"] == 0 and fused.arms[0].feedforward is not None
    _assert_same(fused, _stepped(config, False, 300))


def test_a_copy_shares_the_read_only_answer_of_a_loop_without_a_gate():
    em = _stepped(merge_overrides(load_scenario("collision"),
                                  {"wrench": {"contact_gate": False}}), True, 5)
    twin = em.copy_state()
    assert twin._gate_closed is em._gate_closed
    assert not any(a.flags.writeable for a in twin._gate_closed)


def test_a_reading_at_the_sensors_range_stops_the_fused_rest_as_the_stages_do(monkeypatch):
    """A 20 N range on the free-floating-scripted run, whose push goes past it: the fused
    rest ends its call after the chain, and the run stops at the same cycle, for the same
    reason, with the same readings, ODS state and telemetry as the stages'; with
    ``stop_at_sensor_range`` off the run goes on, the same in both."""
    for stop in (True, False):
        config = merge_overrides(load_scenario("free-floating-scripted"),
                                 {"sensor": {"range_force_N": 20.0},
                                  "loop": {"stop_at_sensor_range": stop}})
        calls = _counting(monkeypatch)
        fused = _stepped(config, True, 4000, calls)
        assert calls["rest"] == fused.cycles + stop > 100  # (the stopping call)
        stages = _stepped(config, False, 4000)
        _assert_same(fused, stages)
        assert fused.arms[0].last_raw_S.tobytes() == stages.arms[0].last_raw_S.tobytes()
        assert fused.applied_force_R.tobytes() == stages.applied_force_R.tobytes()
        if stop:
            assert fused.status == "safety_stop"
            assert fused.safety_stop["reason"].startswith("F/T force reading at the sensor's")
        else:
            assert fused.status == "running" and fused.cycles == 4000


@pytest.mark.parametrize("overrides", [
    {"passivity": {"enabled": True}},  # the coupling changes the chain's output
    {"wrench": {"contact_gate": True}},  # a gate may open: the estimate
    {"sensor": {"placement": "mockup"}},  # the chain's stages: the wrench to the face
    {"sensor": {"sample_rate_hz": 125.0}},  # a held reading
])
def test_a_setting_the_fused_rest_does_not_cover_takes_the_tail(overrides, monkeypatch):
    """One-arm settings where the chain's output is not the ODS input as it is, or the
    chain is not one call: every cycle takes the fused tail after the stages of the
    chain, bit for bit as the stages."""
    config = merge_overrides(load_scenario("free-floating-scripted"), overrides)
    calls = _counting(monkeypatch)
    fused = _stepped(config, True, 600, calls)
    assert calls["rest"] == 0 and calls["tail"] == fused.cycles == 600
    _assert_same(fused, _stepped(config, False, 600))
