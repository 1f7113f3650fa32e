"""Ray's processes that outlive a sweep's local Ray: adopted, then ended with the sweep.

A stop that reaches a local Ray while it starts (a scheduler's SIGTERM to the sweep's
whole process group, a closed terminal) can end Ray's raylet before the agents it
started; those agents (``ray::DashboardAgent``, ``ray::RuntimeEnvAgent``) then live on
under init, for ever, and some ignore SIGTERM. The sweep command therefore makes itself
the subreaper of what it starts (Linux ``PR_SET_CHILD_SUBREAPER``): an orphan of its
tree is re-parented to it, not to init, and whatever of Ray is still among its children
once Ray has been shut down is ended (SIGTERM, then SIGKILL) and reaped."""

from __future__ import annotations

import ctypes
import os
import signal
import time
from pathlib import Path

PR_SET_CHILD_SUBREAPER = 36
"""prctl's option (linux/prctl.h)."""
GRACE_S = 2.0
"""How long a leftover has after SIGTERM before SIGKILL."""


def adopt_orphans() -> set[int]:
    """This process becomes the subreaper of its descendants (where the system allows);
    returns its descendants now, which are not Ray's leftovers whatever they are."""
    try:
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0)
    except (OSError, AttributeError):  # no prctl: orphans go to init, as before
        pass
    return set(descendants())


def descendants() -> list[int]:
    """The pids under this process, children first (from /proc)."""
    tree, out, todo = _tree(), [], [os.getpid()]
    while todo:
        for pid in tree.get(todo.pop(0), []):
            out.append(pid)
            todo.append(pid)
    return out


def _tree() -> dict[int, list[int]]:
    """Each process's children (from /proc)."""
    tree: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                stat = (entry / "stat").read_text()
            except OSError:
                continue
            tree.setdefault(int(stat.rsplit(")", 1)[1].split()[1]), []).append(int(entry.name))
    return tree


def is_ray(pid: int) -> bool:
    """Whether the process is one of Ray's (its name ``ray::...``, or a program of the
    ray package: gcs_server, raylet, an agent, a worker)."""
    try:
        cmdline = (Path("/proc") / str(pid) / "cmdline").read_bytes().replace(b"\0", b" ")
    except OSError:
        return False
    text = cmdline.decode(errors="replace")
    return text.startswith("ray::") or "/ray/" in text


def live_name(pid: int) -> str | None:
    """The program name of a live process (None: gone, or a zombie)."""
    try:
        name, rest = (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)
    except OSError:
        return None
    return None if rest.split()[0] == "Z" else name.split("(", 1)[1]


def end_leftovers(kept: set[int], grace_s: float = GRACE_S) -> list[int]:
    """End Ray's processes under this process that are not in ``kept``: SIGTERM, then
    SIGKILL after ``grace_s``; those that are (or become) its children are reaped.
    Returns their pids."""
    left = [pid for pid in descendants() if pid not in kept and is_ray(pid)]
    for pid in left:
        _signal(pid, signal.SIGTERM)
    deadline, waiting = time.monotonic() + grace_s, set(left)
    while waiting and time.monotonic() < deadline:
        waiting = {pid for pid in waiting if not _ended(pid)}
        time.sleep(0.02)
    for pid in waiting:
        _signal(pid, signal.SIGKILL)
    for pid in left:
        _ended(pid, block=True)
    return left


def _signal(pid: int, sig: int) -> None:
    try:
        os.kill(pid, sig)
    except ProcessLookupError:
        pass


def _ended(pid: int, block: bool = False) -> bool:
    """Whether the process has ended: reaped if it is a child (waited for with
    ``block``), else gone from /proc or a zombie another parent has to reap."""
    try:
        done, _ = os.waitpid(pid, 0 if block else os.WNOHANG)
        return done == pid
    except ChildProcessError:  # not a child: its own parent reaps it
        return live_name(pid) is None
