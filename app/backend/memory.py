"""Giving freed memory back to the system, for a web process that runs for hours."""

from __future__ import annotations

__all__ = ["TRIM_EVERY_S", "give_back_memory"]

TRIM_EVERY_S = 10.0
"""How often the runner's watchdog hands freed memory back (:func:`give_back_memory`)."""


def give_back_memory() -> None:
    """Hand the memory freed by the process back to the system (glibc's malloc_trim).

    After a heavy read: without it the allocator keeps what the copies of a big ring used,
    and the web process's resident size stays tens of MiB up after each download. Every
    TRIM_EVERY_S too: the free pages scattered through the heap by many small requests
    (eight clients polling for ten minutes) are otherwise kept, and the resident size
    creeps while the Python objects alive stay the same (benchmarks/soak.py)."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):  # not glibc: nothing to do
        pass
