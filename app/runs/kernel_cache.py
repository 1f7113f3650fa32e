"""The numba kernel cache's stamp: what app/sim's compiled kernels were compiled from, and
the rule that no process loads kernels compiled from other sources.

numba keeps the machine code of app/sim's kernels (``@njit(cache=True)``) in
``app/sim/__pycache__``, or under ``NUMBA_CACHE_DIR``, keyed on the CPU and on the source
file that defines each kernel, that file alone: a kernel that calls into another module
(the fused command, sensor and tail paths) would be loaded as compiled against that
module's old code once it changed. A stamp beside the cache (``orbit-emulator-warm.json``)
records the Python, numba's version, the CPU name numba targets and each kernel source
file's SHA-256; a cache whose stamp is not this tree's loses app/sim's compiled files
before any kernel loads (:func:`forget_stale`, at app's import) and before the warm-up
(app/runs/warm.py, :func:`clear_stale`). Standard library only: app's import runs it.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
from importlib import metadata
from pathlib import Path

__all__ = ["SIM_DIR", "STAMP_NAME", "cache_folder", "clear_stale", "forget_stale",
           "is_warm", "kept_stamp", "kernel_sources", "stamp", "write_stamp"]

SIM_DIR = Path(os.path.abspath(__file__)).parents[1] / "sim"
"""app/sim as numba names it (os.path.abspath, symbolic links kept: its cache locator's
rule, so that the folder below is the one numba writes)."""
STAMP_NAME = "orbit-emulator-warm.json"


def kernel_sources() -> list[Path]:
    """The app/sim files that define numba kernels."""
    return sorted(p for p in SIM_DIR.glob("*.py") if "@njit" in p.read_text())


def cache_folder() -> Path:
    """Where numba keeps app/sim's compiled kernels (its own rule: NUMBA_CACHE_DIR holds
    a tree named after the sources' folder; else their ``__pycache__``)."""
    root = os.environ.get("NUMBA_CACHE_DIR")
    if not root:
        return SIM_DIR / "__pycache__"
    # numba's UserProvidedCacheLocator: the folder's name and the SHA-1 of its path
    return Path(root) / f"{SIM_DIR.name}_{hashlib.sha1(str(SIM_DIR).encode()).hexdigest()}"


def stamp() -> dict:
    """What a warm cache was compiled from (module doc)."""
    return {"python": sys.version, "numba": metadata.version("numba"),
            "cpu": os.environ.get("NUMBA_CPU_NAME", ""),
            "sources": {p.name: hashlib.sha256(p.read_bytes()).hexdigest()
                        for p in kernel_sources()}}


def is_warm(folder: Path | None = None) -> bool:
    """Whether the stamp in the cache matches this tree and every kernel module has its
    index files there."""
    folder = folder or cache_folder()
    if kept_stamp(folder) != stamp():
        return False
    return all(any(folder.glob(f"{p.stem}.*.nbi")) for p in kernel_sources())


def kept_stamp(folder: Path) -> dict | None:
    """The stamp kept in the cache folder (None: none, or not one that reads)."""
    try:
        return json.loads((folder / STAMP_NAME).read_text())
    except (OSError, ValueError):
        return None


def write_stamp(folder: Path, current: dict | None = None) -> None:
    """Keep ``current`` (:func:`stamp`'s, if at hand) as the cache folder's stamp (OSError
    where it cannot be written)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / STAMP_NAME).write_text(json.dumps(current or stamp(), indent=1) + "\n")


def clear_stale(folder: Path | None = None, current: dict | None = None) -> int:
    """Delete app/sim's compiled kernels from the cache unless its stamp is this tree's
    (``current``: :func:`stamp`'s, if at hand) (an older tree's, or none: compiled from
    other sources, numba would load a kernel against the old code of the modules it
    calls); the number of files deleted."""
    folder = folder or cache_folder()
    if kept_stamp(folder) == (current or stamp()):
        return 0
    deleted = 0
    for source in kernel_sources():
        for path in folder.glob(f"{source.stem}.*.nb[ic]"):
            try:
                path.unlink()
                deleted += 1
            except OSError:  # (gone already: another process cleared it)
                pass
    return deleted


def forget_stale(folder: Path | None = None) -> int:
    """Before any kernel loads (app/__init__.py runs it at the package's import): a cache
    whose stamp is not this tree's, or that has compiled files and no stamp, loses app/sim's
    compiled files (:func:`clear_stale`) and is stamped as this tree's, empty, so that no
    process loads a kernel compiled against other sources (an update or an edit run
    without ``scripts/install``); the kernels compile again on first use, or in the next
    warm-up (:func:`is_warm` wants their index files too). The number of files deleted;
    nothing where the stamp matches (a few ms: the sources' hashes) or where the cache
    cannot be written."""
    folder = folder or cache_folder()
    current = stamp()
    if kept_stamp(folder) == current:
        return 0
    try:
        deleted = clear_stale(folder, current)
        if folder.is_dir():
            write_stamp(folder, current)
    except OSError:  # (a read-only install: numba keeps its kernels elsewhere)
        return 0
    if deleted:
        print(f"orbit-emulator: {deleted} compiled kernel files of other sources deleted "
              f"from {folder}; the kernels compile again on first use (`bash "
              f"scripts/install` compiles them now)", file=sys.stderr)
    return deleted
