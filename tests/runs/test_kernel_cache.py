"""The kernel cache's stamp (app/runs/kernel_cache.py): what it was compiled from, and no
process loading kernels compiled from other sources."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

from app.runs import kernel_cache

ROOT = Path(__file__).resolve().parents[2]


def test_a_stamp_of_another_numba_or_source_or_a_missing_index_is_not_warm(tmp_path):
    stamp = kernel_cache.stamp()
    assert set(stamp["sources"]) >= {"vfdm.py", "rail_vfdm.py", "ur10e.py", "orbital.py"}
    (tmp_path / kernel_cache.STAMP_NAME).write_text(json.dumps(stamp))
    for source in kernel_cache.kernel_sources():
        (tmp_path / f"{source.stem}.kernel-1.py311.nbi").write_bytes(b"")
    assert kernel_cache.is_warm(tmp_path)
    (tmp_path / "rail_vfdm.kernel-1.py311.nbi").unlink()  # one module's index gone
    assert not kernel_cache.is_warm(tmp_path)
    (tmp_path / "rail_vfdm.kernel-1.py311.nbi").write_bytes(b"")
    for key, value in (("numba", "0.1"), ("sources", {**stamp["sources"], "vfdm.py": "0"})):
        (tmp_path / kernel_cache.STAMP_NAME).write_text(json.dumps({**stamp, key: value}))
        assert not kernel_cache.is_warm(tmp_path), key
    (tmp_path / kernel_cache.STAMP_NAME).write_text("not json")
    assert not kernel_cache.is_warm(tmp_path)


def _fake_cache(folder: Path, kept: dict | None) -> list[str]:
    """Compiled files of every kernel module in folder, with the stamp ``kept`` (None:
    none); their names."""
    folder.mkdir(parents=True, exist_ok=True)
    names = [f"{source.stem}.kernel-1.py311.nb{kind}"
             for source in kernel_cache.kernel_sources() for kind in "ic"]
    for name in names:
        (folder / name).write_bytes(b"")
    if kept is None:
        (folder / kernel_cache.STAMP_NAME).unlink(missing_ok=True)
    else:
        (folder / kernel_cache.STAMP_NAME).write_text(json.dumps(kept))
    return names


def test_a_cache_compiled_from_other_sources_is_deleted_before_the_warm_up(tmp_path):
    """numba keys a kernel's cache on its own file alone: a cache whose stamp is another
    tree's (a source changed) or missing loses app/sim's compiled files, and nothing
    else; with this tree's stamp it is kept."""
    stamp = kernel_cache.stamp()
    (tmp_path / "other.kernel-1.py311.nbi").write_bytes(b"")  # not a kernel module's
    names = _fake_cache(tmp_path, stamp)
    assert kernel_cache.clear_stale(tmp_path) == 0
    assert all((tmp_path / name).exists() for name in names)
    for kept in ({**stamp, "sources": {**stamp["sources"], "ur10e.py": "0"}}, None):
        _fake_cache(tmp_path, kept)
        assert kernel_cache.clear_stale(tmp_path) == len(names)
        assert not any((tmp_path / name).exists() for name in names)
    assert (tmp_path / "other.kernel-1.py311.nbi").exists()


def test_a_cache_of_other_sources_is_forgotten_before_any_kernel_loads(tmp_path, capsys):
    """forget_stale (app's import): another tree's stamp, or compiled files without one,
    lose app/sim's compiled files and take this tree's stamp (so that the next import
    keeps what numba compiles meanwhile); this tree's stamp keeps them; no cache, nothing
    written."""
    stamp = kernel_cache.stamp()
    other = {**stamp, "sources": {**stamp["sources"], "arm_sense.py": "0"}}
    for kept in (other, None):
        names = _fake_cache(tmp_path, kept)
        assert kernel_cache.forget_stale(tmp_path) == len(names)
        assert not any((tmp_path / name).exists() for name in names)
        assert json.loads((tmp_path / kernel_cache.STAMP_NAME).read_text()) == stamp
        assert "compiled kernel files of other sources deleted" in capsys.readouterr().err
        _fake_cache(tmp_path, stamp)  # compiled since, from this tree
        assert kernel_cache.forget_stale(tmp_path) == 0
        assert all((tmp_path / name).exists() for name in names)
    assert kernel_cache.forget_stale(tmp_path / "none") == 0
    assert not (tmp_path / "none").exists()


def test_importing_app_forgets_a_cache_of_other_sources(tmp_path):
    """The hook itself: ``import app`` in a fresh process, numba's cache under
    NUMBA_CACHE_DIR stamped by another tree: its compiled files are gone and the stamp is
    this tree's before anything else runs."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), NUMBA_CACHE_DIR=str(tmp_path))
    code = "from app.runs.kernel_cache import cache_folder; print(cache_folder())"
    folder = Path(subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env,
                                 capture_output=True, text=True, check=True).stdout.strip())
    stamp = kernel_cache.stamp()
    names = _fake_cache(folder, {**stamp, "numba": "0.1"})
    proc = subprocess.run([sys.executable, "-c", "import app"], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert not any((folder / name).exists() for name in names)
    assert json.loads((folder / kernel_cache.STAMP_NAME).read_text()) == stamp


def test_through_a_symbolic_link_the_cache_folder_is_the_one_numba_writes(tmp_path):
    link = tmp_path / "tree"
    link.symlink_to(ROOT)
    code = ("from app.runs import kernel_cache; from app.sim import orbital; "
            "print(kernel_cache.cache_folder()); "
            "print(orbital._direction_cosines._cache._cache_path)")
    env = dict(os.environ, PYTHONPATH=str(link), NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True,
                         text=True, env=env, timeout=60)
    ours, numbas = out.stdout.split()
    assert ours == numbas, out.stderr
    linked = str(link / "app" / "sim")  # (the link's path, not the tree's)
    assert numbas.endswith(hashlib.sha1(linked.encode()).hexdigest())
