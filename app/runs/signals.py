"""A scheduler's SIGTERM handled as Ctrl+C: a command then ends as an interrupted one does,
keeping what it recorded (exit 130), rather than dying where it stands."""

from __future__ import annotations

import signal
import threading


def interrupt_on_sigterm() -> None:
    """From now on SIGTERM raises KeyboardInterrupt in the main thread (nothing elsewhere:
    only the main thread may set a handler). A library that installs a handler of its own
    (Ray's ``ray.init``) must come first."""

    def interrupt(signum, frame):
        raise KeyboardInterrupt

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, interrupt)
