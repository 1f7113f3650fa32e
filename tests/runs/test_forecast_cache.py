"""The forecasts kept on disk (app/runs/forecast_cache.py): one per setting, whatever the
seed; found again only for the same configuration, ideal run and code."""

from __future__ import annotations

import json
import os

import pytest

from app.config import assignment_override, merge_overrides
from app.runs import forecast_cache
from app.runs.forecast_cache import cached_forecast, forecast_key, reference_key
from app.runs.headless import checked_reference
from app.runs.preflight import PreflightRefused
from app.runs.uncertainty import forecast
from tests.runs.test_uncertainty import short_collision


def _plant(path, content: str, elsewhere: str, huge: str):
    """Put a hostile file where a kept one would be: a FIFO, a symlink to a file holding
    ``elsewhere`` (next to ``path``'s folder), ``huge`` (over the size bound), or
    ``content`` itself; the symlink's target."""
    target = path.parent.parent / "elsewhere.json"
    target.write_text(elsewhere)
    if content == "fifo":
        os.mkfifo(path)
    elif content == "symlink":
        path.symlink_to(target)
    elif content == "huge":
        path.write_text(huge)
    else:
        path.write_text(content)
    return target


def _counted(calls: list):
    def compute(config, ideal):
        calls.append(config.loop.seed)
        return forecast(config, ideal)
    return compute


def test_a_forecast_does_not_depend_on_the_seed_so_one_serves_every_seed(monkeypatch):
    """The key sets the seed aside: that is only right if the forecast itself is the same
    for every seed, computed anew for each."""
    monkeypatch.setenv("ORBIT_EMULATOR_CACHE", "off")
    answers = []
    for seed in (11, 4711):
        config = short_collision("uncertainty.forecast_replicates=4", f"loop.seed={seed}")
        reference = checked_reference(config, config.loop.duration_s)
        assert reference["forecast"]["restitution_sd"] is not None
        answers.append((reference["forecast"], forecast_key(config, reference)))
    assert answers[0] == answers[1]


def test_a_kept_forecast_is_found_for_the_same_setting_and_only_for_it(tmp_path, monkeypatch):
    monkeypatch.setenv("ORBIT_EMULATOR_CACHE", str(tmp_path))
    config = short_collision("uncertainty.forecast_replicates=4")
    monkeypatch.setenv("ORBIT_EMULATOR_CACHE", "off")
    ideal = {k: v for k, v in checked_reference(config, config.loop.duration_s).items()
             if k != "forecast"}
    monkeypatch.setenv("ORBIT_EMULATOR_CACHE", str(tmp_path))
    calls = []
    first = cached_forecast(config, ideal, _counted(calls))
    again = cached_forecast(merge_overrides(config, assignment_override("loop.seed=99")),
                            ideal, _counted(calls))
    assert calls == [config.loop.seed] and again == first  # computed once, read back whole
    assert len(list((tmp_path / "forecasts").glob("*.json"))) == 1
    noisier = merge_overrides(config, assignment_override("sensor.noise_force_N=2.0"))
    other = cached_forecast(noisier, ideal, _counted(calls))
    assert len(calls) == 2 and other["noise_force_N"] == 2.0
    moved = cached_forecast(config, {**ideal, "restitution": ideal["restitution"] + 0.01},
                            _counted(calls))
    assert len(calls) == 3 and moved["restitution_error_mean"] != first[
        "restitution_error_mean"]


def test_a_new_code_or_a_broken_file_computes_it_anew(tmp_path, monkeypatch):
    monkeypatch.setenv("ORBIT_EMULATOR_CACHE", str(tmp_path))
    config = short_collision("uncertainty.forecast_replicates=4")
    ideal = {"pair": ["sat0", "sat1"], "window_s": [0.7, 0.8], "contact_duration_s": 0.1,
             "restitution": 0.3, "peak_force_N": 3.0}
    calls = []
    key = forecast_key(config, ideal)
    path = tmp_path / "forecasts" / f"{key}.json"
    path.parent.mkdir(parents=True)
    path.write_text('{"forecast": ')  # a file cut short: computed and written whole
    cached_forecast(config, ideal, lambda c, i: calls.append(1) or {"restitution_sd": 0.1})
    assert calls == [1] and path.read_text() == '{"forecast": {"restitution_sd": 0.1}}'
    monkeypatch.setattr(forecast_cache, "code_fingerprint", lambda: "another code")
    assert forecast_key(config, ideal) != key
    monkeypatch.setenv("ORBIT_EMULATOR_CACHE", "OFF")
    assert forecast_cache.cache_dir() is None


@pytest.mark.parametrize("content", [
    '{"forecast": "abc"}', '{"forecast": null}', '{"forecast": [1, 2]}',
    '{"forecast": {"restitution_sd": -0.1}}', '{"forecast": {"restitution_sd": NaN}}',
    '{"forecast": {"restitution_sd": 0.1, "velocity_sd_mps": [0.1, 0.1]}}',
    '{"forecast": {"restitution_sd": 0.1, "velocity_sd_mps": {"sat1": [0.1, "x", 0]}}}',
    '{"forecast": {"restitution_sd": true}}', "[" * 100_000 + "]" * 100_000,
    "fifo", "symlink", "huge"])
def test_a_file_that_is_not_a_forecast_is_computed_anew_and_written_over(content, tmp_path,
                                                                           monkeypatch):
    """A kept file of the wrong type, shape or kind (a FIFO would hang a reader, a symlink
    would be written through, deep nesting raised RecursionError) is never read as a
    forecast: the run computes its own and keeps that."""
    monkeypatch.setenv("ORBIT_EMULATOR_CACHE", str(tmp_path))
    config = short_collision("uncertainty.forecast_replicates=4")
    ideal = {"pair": ["sat0", "sat1"], "restitution": 0.3}
    path = tmp_path / "forecasts" / f"{forecast_key(config, ideal)}.json"
    path.parent.mkdir(parents=True)
    target = _plant(path, content, '{"forecast": {"restitution_sd": 9.0}}',
                    '{"forecast": {"restitution_sd": 9.0, "note": "' + "x" * (2 << 20) + '"}}')
    got = cached_forecast(config, ideal, lambda c, i: {"restitution_sd": 0.1,
                                                       "velocity_sd_mps": {"sat1": [0, 0, 0]}})
    assert got == {"restitution_sd": 0.1, "velocity_sd_mps": {"sat1": [0, 0, 0]}}
    assert path.is_file() and not path.is_symlink()
    assert json.loads(path.read_text())["forecast"] == got
    assert target.read_text() == '{"forecast": {"restitution_sd": 9.0}}'  # untouched


def test_the_preflight_reference_does_not_depend_on_the_seed_so_one_serves_every_seed(
        monkeypatch):
    """The pre-flight's outcome (its ideal run's collision reference, the forecast) is
    kept per setting with the seed set aside: right only if it is the same for every
    seed, computed anew for each."""
    monkeypatch.setenv("ORBIT_EMULATOR_CACHE", "off")
    answers = []
    for seed in (11, 4711):
        config = short_collision("uncertainty.forecast_replicates=4", f"loop.seed={seed}")
        reference = checked_reference(config, config.loop.duration_s)
        assert reference["restitution"] is not None
        answers.append((reference, reference_key(config, config.loop.duration_s)))
    assert answers[0] == answers[1]


def test_a_setting_that_passed_is_read_back_and_one_refused_is_never_kept(tmp_path,
                                                                          monkeypatch):
    monkeypatch.setenv("ORBIT_EMULATOR_CACHE", str(tmp_path))
    config = short_collision("uncertainty.forecast_replicates=4")
    duration = config.loop.duration_s
    computed = checked_reference(config, duration)
    path = tmp_path / "references" / f"{reference_key(config, duration)}.json"
    assert json.loads(path.read_text())["reference"] == computed
    kept = json.loads(path.read_text())  # the kept one is what a next run reads:
    kept["reference"]["restitution"] = 0.5  # trusted as the installation is
    path.write_text(json.dumps(kept))
    other_seed = merge_overrides(config, assignment_override("loop.seed=99"))
    assert checked_reference(other_seed, duration)["restitution"] == 0.5
    assert reference_key(config, duration + 0.2) != reference_key(config, duration)
    far = merge_overrides(config, assignment_override("satellites.0.position_m=[3,0,0]"))
    with pytest.raises(PreflightRefused, match="leaves the safety volume"):
        checked_reference(far, duration)
    with pytest.raises(PreflightRefused, match="leaves the safety volume"):  # again
        checked_reference(far, duration)
    assert not (tmp_path / "references" / f"{reference_key(far, duration)}.json").exists()


@pytest.mark.parametrize("content", [
    '{"reference": "abc"}', '{"reference": [1]}', '{"reference": {"pair": ["sat1"]}}',
    '{"reference": {"pair": ["sat1", "sat2"], "window_s": [0, NaN], "warnings": []}}',
    '{"reference": {"pair": ["sat1", "sat2"], "window_s": [0, 1], "warnings": [], '
    '"restitution": -1}}',
    '{"reference": {"pair": ["sat1", "sat2"], "window_s": [0, 1], "warnings": [], '
    '"forecast": {"restitution_sd": -1}}}',
    "[" * 100_000 + "]" * 100_000, "symlink", "huge"])
def test_a_file_that_is_not_a_reference_is_computed_anew_and_written_over(content, tmp_path,
                                                                           monkeypatch):
    monkeypatch.setenv("ORBIT_EMULATOR_CACHE", str(tmp_path))
    config = short_collision("uncertainty.forecast_replicates=4")
    duration = config.loop.duration_s
    path = tmp_path / "references" / f"{reference_key(config, duration)}.json"
    path.parent.mkdir(parents=True)
    target = _plant(path, content, '{"reference": null}',
                    '{"reference": null, "x": "' + "x" * (2 << 20) + '"}')
    got = checked_reference(config, duration)
    assert got["restitution"] is not None and got["forecast"]["restitution_sd"] is not None
    assert path.is_file() and not path.is_symlink()
    assert json.loads(path.read_text())["reference"] == got
    assert target.read_text() == '{"reference": null}'  # untouched


def _fake(calls: list):
    def compute(config, ideal):
        calls.append(1)
        return {"restitution_sd": 0.01 * len(calls)}
    return compute


IDEAL = {"pair": ["cubesat", "sponge"], "restitution": 0.3}


def test_a_file_or_folder_others_could_write_is_never_read(tmp_path, monkeypatch):
    """A kept reference lets a run skip its pre-flight: a file that another user could have
    written (group- or world-writable, or in such a folder) is computed anew, not read."""
    monkeypatch.setenv("ORBIT_EMULATOR_CACHE", str(tmp_path))
    config = short_collision()
    calls = []
    first = cached_forecast(config, IDEAL, _fake(calls))
    assert cached_forecast(config, IDEAL, _fake(calls)) == first and len(calls) == 1
    (path,) = (tmp_path / "forecasts").glob("*.json")
    os.chmod(path, 0o664)
    assert cached_forecast(config, IDEAL, _fake(calls)) != first and len(calls) == 2
    os.chmod(path, 0o600)
    os.chmod(path.parent, 0o777)
    cached_forecast(config, IDEAL, _fake(calls))
    assert len(calls) == 3


def test_a_reference_without_a_contact_is_read_back(tmp_path, monkeypatch):
    """An ideal run without a contact leaves the reference {}: kept, it is read back."""
    monkeypatch.setenv("ORBIT_EMULATOR_CACHE", str(tmp_path))
    config = short_collision()
    assert forecast_cache.cached_reference(config, 1.0) is forecast_cache.NOT_KEPT
    forecast_cache.keep_reference(config, 1.0, {})
    assert forecast_cache.cached_reference(config, 1.0) == {}


def test_a_result_json_cannot_write_is_not_kept_and_leaves_nothing(tmp_path, monkeypatch):
    import numpy as np

    monkeypatch.setenv("ORBIT_EMULATOR_CACHE", str(tmp_path))
    config = short_collision()
    forecast_cache.keep_reference(config, 1.0, {"pair": np.int64(3)})
    assert list((tmp_path / "references").iterdir()) == []
