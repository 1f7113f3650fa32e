"""The files a user names (``--config``, a sweep spec and its ``config``, a scenario's
``extends``), read within bounds: a regular file of at most a stated size.

A path is looked at with ``os.stat`` before it is opened, so that a FIFO (whose opening
for reading waits for a writer) or a device (``/dev/zero`` never ends) is refused without
being opened; the file is then opened without blocking, checked again (it may have been
replaced meanwhile), and at most ``cap + 1`` bytes are read.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

__all__ = ["MAX_TOML_BYTES", "InputFileError", "read_bounded_text"]

MAX_TOML_BYTES = 1 << 20
"""A TOML file (scenario, sweep spec) is read up to 1 MiB (the largest built-in scenario
is under 10 KiB)."""


class InputFileError(ValueError):
    """A named file that is missing, not a regular file, too large or unreadable."""


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISCHR(mode):
        return "a character device"
    if stat.S_ISBLK(mode):
        return "a block device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def _mib(n_bytes: int) -> str:
    return f"{n_bytes / 2**20:g} MiB"


def _shown(path: Path, most: int = 80) -> str:
    """A path as an error message shows it: whole, or its start and its length."""
    text = str(path)
    return text if len(text) <= most else f"{text[:most]}... ({len(text)} characters)"


def read_bounded_text(path: str | Path, cap: int = MAX_TOML_BYTES,
                      what: str = "a TOML file") -> str:
    """The text (UTF-8) of the regular file ``path``, of at most ``cap`` bytes; else
    InputFileError naming the path and the rule (FileNotFoundError, IsADirectoryError are
    raised as such, for the caller's own words)."""
    path = Path(path)
    rule = f"{what} must be a regular file of at most {_mib(cap)}"
    try:
        info = os.stat(path)  # follows links; never opens (a FIFO would wait for a writer)
    except FileNotFoundError:
        raise
    except OSError as err:  # a name too long, a loop of links, no permission
        raise InputFileError(f"{_shown(path)}: {err.strerror}; {rule}") from None
    if stat.S_ISDIR(info.st_mode):
        raise IsADirectoryError(21, "Is a directory", str(path))
    if not stat.S_ISREG(info.st_mode):
        raise InputFileError(f"{path}: is {_kind(info.st_mode)}; {rule}")
    if info.st_size > cap:
        raise InputFileError(f"{path}: is {info.st_size:,} bytes; {rule}")
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except OSError as err:  # e.g. no permission to read it
        raise InputFileError(f"{_shown(path)}: {err.strerror}; {rule}") from None
    try:
        again = os.fstat(fd)  # what was opened, should the path have changed since
        if not stat.S_ISREG(again.st_mode):
            raise InputFileError(f"{path}: is {_kind(again.st_mode)}; {rule}")
        data = bytearray()
        while len(data) <= cap:
            chunk = os.read(fd, cap + 1 - len(data))
            if not chunk:
                break
            data += chunk
    finally:
        os.close(fd)
    if len(data) > cap:
        raise InputFileError(f"{path}: is larger than {_mib(cap)}; {rule}")
    return data.decode("utf-8")
