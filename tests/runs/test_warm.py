"""The kernels compiled ahead of a first run (app/runs/warm.py): after `python -m app.runs.warm`
a first run compiles nothing, and a warm cache is recognised without compiling anew."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from app.runs import kernel_cache, warm

ROOT = Path(__file__).resolve().parents[2]


def _python(*args: str, **kwargs) -> subprocess.CompletedProcess:
    """``python ARGS`` in this tree; a warm-up without the collision's forecast (seconds:
    the runs below compute their own, in the session's cache)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    if args[:2] == ("-m", "app.runs.warm"):
        env["ORBIT_EMULATOR_CACHE"] = "off"
    return subprocess.run([sys.executable, *args], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=600, **kwargs)


def _cache_files(folder: Path) -> dict[str, tuple[int, int]]:
    return {p.name: (p.stat().st_mtime_ns, p.stat().st_size)
            for p in folder.iterdir() if p.suffix in (".nbi", ".nbc")}


def test_after_the_warm_up_a_first_run_on_rails_and_on_fixed_arms_compiles_nothing(tmp_path):
    assert _python("-m", "app.runs.warm").returncode == 0
    assert _python("-m", "app.runs.warm", "--check").returncode == 0
    folder = kernel_cache.cache_folder()
    before = _cache_files(folder)
    assert before
    for scenario in ("collision-rails", "collision"):  # a rail, then fixed arms
        run = _python("-m", "app.cli", "run", scenario, "--duration", "0.3", "--quiet",
                      "--out", str(tmp_path / scenario))
        assert run.returncode == 0, run.stderr
    assert _cache_files(folder) == before  # numba wrote no kernel: none was compiled


def test_a_warm_cache_is_recognised_in_well_under_a_second():
    assert _python("-m", "app.runs.warm").returncode == 0
    import time
    t0 = time.perf_counter()
    assert _python("-m", "app.runs.warm").returncode == 0
    assert time.perf_counter() - t0 < 1.0


def test_a_stamp_it_cannot_write_and_a_forecast_that_fails_still_end_the_warm_up_well(
        tmp_path, monkeypatch, capsys):
    blocked = tmp_path / "a file"
    blocked.write_text("")
    monkeypatch.setattr(warm, "cache_folder", lambda: blocked / "cache")  # under a file
    monkeypatch.setattr(warm, "KEPT_SETTINGS", ("no-such-scenario",))
    monkeypatch.setenv("ORBIT_EMULATOR_CACHE", str(tmp_path / "kept"))
    assert warm.main([]) == 0  # the kernels are compiled all the same
    err = capsys.readouterr().err
    assert f"the stamp {blocked / 'cache' / kernel_cache.STAMP_NAME} was not written (" in err
    assert "the next install warms up again" in err
    assert "warm: warning: the fidelity forecast of no-such-scenario was not kept (" in err
    assert blocked.read_text() == ""
