"""The stop signals of a command: a scheduler's SIGTERM, or a closed terminal's SIGHUP, is
handled as Ctrl+C, so that the command ends as an interrupted one does, keeping what it
recorded (exit 130), rather than dying where it stands; and a stop can be held over a
call that must not be cut half-way (a Ray start)."""

from __future__ import annotations

import signal
import sys
import threading
from contextlib import contextmanager

STOPS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
"""Ctrl+C, a scheduler's stop, a closed terminal."""


def _main_thread() -> bool:
    """Only the main thread may set a signal's handler."""
    return threading.current_thread() is threading.main_thread()


def interrupt_on_termination() -> None:
    """From now on SIGTERM and SIGHUP raise KeyboardInterrupt in the main thread (nothing
    elsewhere); one the process ignores (``nohup``) stays ignored. A library that installs
    a handler of its own (Ray's ``ray.init``) must come first, or be held
    (:func:`held_stops`)."""

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    if _main_thread():
        for sig in (signal.SIGTERM, signal.SIGHUP):
            if signal.getsignal(sig) is not signal.SIG_IGN:
                signal.signal(sig, interrupt)


@contextmanager
def held_stops(note: str | None = None, on_stop=None):
    """Ctrl+C, SIGTERM and SIGHUP held over the block (main thread only; an ignored one
    stays ignored): the block gets the list of those that came (the first prints
    ``note`` on stderr, if any), and the handlers in place before it are put back at its
    end (SIGINT last: a Ctrl+C then finds the others back). The caller acts on the
    list. ``on_stop``: called (without arguments) as each stop comes, in the handler."""
    came: list[int] = []
    if not _main_thread():
        yield came
        return

    def hold(signum, frame):
        if not came and note:
            print(note, file=sys.stderr, flush=True)
        came.append(signum)
        if on_stop is not None:
            on_stop()

    before = {sig: signal.getsignal(sig) for sig in STOPS}
    held = [sig for sig, handler in before.items() if handler is not signal.SIG_IGN]
    for sig in held:
        signal.signal(sig, hold)
    try:
        yield came
    finally:
        for sig in reversed(held):
            handler = before[sig]
            signal.signal(sig, signal.SIG_DFL if handler is None else handler)


@contextmanager
def interrupts_held():
    """:func:`held_stops` over the block, then, if a stop came, KeyboardInterrupt as it
    ends: the block is done whole before the stop acts."""
    with held_stops() as came:
        yield
    if came:
        raise KeyboardInterrupt


def reassert_handlers() -> None:
    """Put the stop signals' Python handlers back in force at the system level: a library
    that resets a signal's action underneath Python (Ray's shutdown does, for SIGTERM)
    leaves Python's record of the handler and what the system does apart."""
    if _main_thread():
        for sig in STOPS:
            handler = signal.getsignal(sig)
            if handler is not None:
                signal.signal(sig, handler)


def as_helper_process() -> None:
    """A process forked to help a command (a replicate's, a figure's): Ctrl+C ignored (the
    command's to handle), SIGTERM and SIGHUP end it (not the command's "as Ctrl+C"); a
    SIGHUP the command ignores (nohup) it ignores too."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if signal.getsignal(signal.SIGHUP) is not signal.SIG_IGN:
        signal.signal(signal.SIGHUP, signal.SIG_DFL)
