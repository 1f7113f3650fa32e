"""The kernels compiled ahead of a first run (app/runs/warm.py): after `python -m app.runs.warm`
a first run compiles nothing, and a warm cache is recognised without compiling anew."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

from app.runs import warm

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
    folder = warm.cache_folder()
    before = _cache_files(folder)
    assert before
    for scenario in ("collision-rails", "collision"):  # a rail, then fixed arms
        run = _python("-m", "app.cli", "run", scenario, "--duration", "0.3", "--quiet",
                      "--out", str(tmp_path / scenario))
        assert run.returncode == 0, run.stderr
    assert _cache_files(folder) == before  # numba wrote no kernel: none was compiled


def test_a_stamp_of_another_numba_or_source_or_a_missing_index_is_not_warm(tmp_path):
    stamp = warm.stamp()
    assert set(stamp["sources"]) >= {"vfdm.py", "rail_vfdm.py", "ur10e.py", "orbital.py"}
    (tmp_path / warm.STAMP_NAME).write_text(json.dumps(stamp))
    for source in warm.kernel_sources():
        (tmp_path / f"{source.stem}.kernel-1.py311.nbi").write_bytes(b"")
    assert warm.is_warm(tmp_path)
    (tmp_path / "rail_vfdm.kernel-1.py311.nbi").unlink()  # one module's index gone
    assert not warm.is_warm(tmp_path)
    (tmp_path / "rail_vfdm.kernel-1.py311.nbi").write_bytes(b"")
    for key, value in (("numba", "0.1"), ("sources", {**stamp["sources"], "vfdm.py": "0"})):
        (tmp_path / warm.STAMP_NAME).write_text(json.dumps({**stamp, key: value}))
        assert not warm.is_warm(tmp_path), key
    (tmp_path / warm.STAMP_NAME).write_text("not json")
    assert not warm.is_warm(tmp_path)


def test_a_cache_compiled_from_other_sources_is_deleted_before_the_warm_up(tmp_path):
    """numba keys a kernel's cache on its own file alone: a cache whose stamp is another
    tree's (a source changed) or missing loses app/sim's compiled files, and nothing
    else; with this tree's stamp it is kept."""
    stamp = warm.stamp()
    names = [f"{source.stem}.kernel-1.py311.nb{kind}"
             for source in warm.kernel_sources() for kind in "ic"]
    (tmp_path / "other.kernel-1.py311.nbi").write_bytes(b"")  # not a kernel module's

    def cache(kept: dict | None) -> None:
        for name in names:
            (tmp_path / name).write_bytes(b"")
        if kept is None:
            (tmp_path / warm.STAMP_NAME).unlink(missing_ok=True)
        else:
            (tmp_path / warm.STAMP_NAME).write_text(json.dumps(kept))

    cache(stamp)
    assert warm.clear_stale(tmp_path) == 0
    assert all((tmp_path / name).exists() for name in names)
    for kept in ({**stamp, "sources": {**stamp["sources"], "ur10e.py": "0"}}, None):
        cache(kept)
        assert warm.clear_stale(tmp_path) == len(names)
        assert not any((tmp_path / name).exists() for name in names)
    assert (tmp_path / "other.kernel-1.py311.nbi").exists()


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
    assert f"the stamp {blocked / 'cache' / warm.STAMP_NAME} was not written (" in err
    assert "the next install warms up again" in err
    assert "warm: warning: the fidelity forecast of no-such-scenario was not kept (" in err
    assert blocked.read_text() == ""


def test_through_a_symbolic_link_the_cache_folder_is_the_one_numba_writes(tmp_path):
    link = tmp_path / "tree"
    link.symlink_to(ROOT)
    code = ("from app.runs import warm; from app.sim import orbital; "
            "print(warm.cache_folder()); print(orbital._direction_cosines._cache._cache_path)")
    env = dict(os.environ, PYTHONPATH=str(link), NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                         text=True, env=env, timeout=60)
    ours, numbas = out.stdout.split()
    assert ours == numbas, out.stderr
    linked = str(link / "app" / "sim")  # (the link's path, not the tree's)
    assert numbas.endswith(hashlib.sha1(linked.encode()).hexdigest())


def _fake_cache(folder: Path, kept: dict | None) -> list[str]:
    """Compiled files of every kernel module in folder, with the stamp ``kept`` (None:
    none); their names."""
    folder.mkdir(parents=True, exist_ok=True)
    names = [f"{source.stem}.kernel-1.py311.nb{kind}"
             for source in warm.kernel_sources() for kind in "ic"]
    for name in names:
        (folder / name).write_bytes(b"")
    if kept is None:
        (folder / warm.STAMP_NAME).unlink(missing_ok=True)
    else:
        (folder / warm.STAMP_NAME).write_text(json.dumps(kept))
    return names


def test_a_cache_of_other_sources_is_forgotten_before_any_kernel_loads(tmp_path, capsys):
    """forget_stale (app's import): another tree's stamp, or compiled files without one,
    lose app/sim's compiled files and take this tree's stamp (so that the next import
    keeps what numba compiles meanwhile); this tree's stamp keeps them; no cache, nothing
    written."""
    stamp = warm.stamp()
    other = {**stamp, "sources": {**stamp["sources"], "arm_sense.py": "0"}}
    for kept in (other, None):
        names = _fake_cache(tmp_path, kept)
        assert warm.forget_stale(tmp_path) == len(names)
        assert not any((tmp_path / name).exists() for name in names)
        assert json.loads((tmp_path / warm.STAMP_NAME).read_text()) == stamp
        assert "compiled kernel files of other sources deleted" in capsys.readouterr().err
        _fake_cache(tmp_path, stamp)  # compiled since, from this tree
        assert warm.forget_stale(tmp_path) == 0
        assert all((tmp_path / name).exists() for name in names)
    assert warm.forget_stale(tmp_path / "none") == 0
    assert not (tmp_path / "none").exists()


def test_importing_app_forgets_a_cache_of_other_sources(tmp_path):
    """The hook itself: ``import app`` in a fresh process, numba's cache under
    NUMBA_CACHE_DIR stamped by another tree: its compiled files are gone and the stamp is
    this tree's before anything else runs."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), NUMBA_CACHE_DIR=str(tmp_path))
    folder = Path(subprocess.run(
        [sys.executable, "-c", "from app.runs.warm import cache_folder; print(cache_folder())"],
        cwd=ROOT, env=env, capture_output=True, text=True, check=True).stdout.strip())
    stamp = warm.stamp()
    names = _fake_cache(folder, {**stamp, "numba": "0.1"})
    proc = subprocess.run([sys.executable, "-c", "import app"], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert not any((folder / name).exists() for name in names)
    assert json.loads((folder / warm.STAMP_NAME).read_text()) == stamp
