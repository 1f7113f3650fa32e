"""Each run's telemetry ring in shared memory: the loop process writes, the web reads.

The web process creates the ring when it asks for a run (:class:`RunTelemetry`, sized by
the run's configuration) and sends its name along; the loop process attaches to it
(:func:`attach_ring`) and the Emulator's telemetry buffer keeps its rows there
(``TelemetryBuffer.use_storage``). Telemetry downloads and metrics are then computed in the
web process, and cost the loop nothing.

The web process reads the ring with ``pread`` on its file, never through the mapping: what
it reads is a copy it owns and lets go of (a CSV is read a chunk at a time,
:meth:`RunTelemetry.chunks`), and the ring's pages never count in its resident memory.

The ring lives in ``/dev/shm`` (a tmpfs): a page the loop writes past what the tmpfs can
hold kills it with SIGBUS, so a ring is created only where it fits
(:func:`check_ring_space`: RingSpaceError naming ``loop.telemetry_capacity``).
"""

from __future__ import annotations

import os
from multiprocessing import shared_memory

import numpy as np

from app.config import EmulatorConfig
from app.sim.telemetry import loop_columns

__all__ = ["COUNTER_BYTES", "SHM_DIR", "RingFile", "RingSpaceError", "RunTelemetry", "attach_ring",
           "check_ring_space", "ring_bytes"]

COUNTER_BYTES = 16
"""Two int64 counters (rows claimed, rows committed) ahead of a telemetry ring's rows."""
SHM_DIR = "/dev/shm"
"""Where POSIX shared memory lives on Linux (Python's SharedMemory: shm_open)."""
CHUNK_ROWS = 4096
"""Rows read at a time by :meth:`RunTelemetry.chunks` (a two-arm row is 113 values: 3.6 MB)."""


class RingSpaceError(ValueError):
    """A run's telemetry ring does not fit in the shared memory left; names the setting."""


def ring_bytes(config: EmulatorConfig, mode: str | None) -> int:
    """The size of a run's ring: its counters and telemetry_capacity rows of its columns."""
    mode = mode or config.loop.mode
    n_arms = len(config.robots) if mode == "hil" else 0
    rails = config.rail_robots if mode == "hil" else ()
    return COUNTER_BYTES + 8 * config.loop.telemetry_capacity * len(
        loop_columns(len(config.satellites), n_arms, rails))


def _mib(n_bytes: float) -> str:
    return f"{n_bytes / 2**20:.1f} MiB"


def check_ring_space(config: EmulatorConfig, mode: str | None, where: str = SHM_DIR) -> None:
    """RingSpaceError unless ``where`` (a tmpfs) has room for the whole ring of this run
    now: its pages are taken as the loop writes them, and one it cannot have kills the
    loop with SIGBUS. The message names the setting and the space."""
    need = ring_bytes(config, mode)
    vfs = os.statvfs(where)
    free, total = vfs.f_bavail * vfs.f_frsize, vfs.f_blocks * vfs.f_frsize
    if need > free:
        row_bytes = (need - COUNTER_BYTES) // config.loop.telemetry_capacity
        fits = max(0, free - COUNTER_BYTES) // row_bytes
        raise RingSpaceError(
            f"loop.telemetry_capacity: {config.loop.telemetry_capacity} rows of "
            f"{row_bytes // 8} values need {_mib(need)} of shared memory in {where}, which "
            f"has {_mib(free)} free of {_mib(total)}: ask for at most {fits} rows, or give "
            f"{where} more room (docker run --shm-size=1g)")


class RunTelemetry:
    """One run's telemetry ring in shared memory: created here, written by the loop."""

    def __init__(self, config: EmulatorConfig, mode: str | None) -> None:
        self.config = config
        self.mode = mode or config.loop.mode
        n_arms = len(config.robots) if self.mode == "hil" else 0
        rails = config.rail_robots if self.mode == "hil" else ()
        self.columns = loop_columns(len(config.satellites), n_arms, rails)
        self.capacity = config.loop.telemetry_capacity
        check_ring_space(config, self.mode)
        size = ring_bytes(config, self.mode)
        self.shm = shared_memory.SharedMemory(create=True, size=size)
        self.shm.buf[:COUNTER_BYTES] = bytes(COUNTER_BYTES)
        self.name = self.shm.name

    @property
    def path(self) -> str:
        """The ring's file (what :class:`RingFile` reads, in any process)."""
        return f"{SHM_DIR}/{self.name}"

    def reader(self) -> RingFile:
        return RingFile(self.path, self.capacity, len(self.columns))

    def rows(self):
        """A copy of the rows committed so far, oldest first."""
        return self.numbered_rows()[1]

    def numbered_rows(self) -> tuple[int, np.ndarray]:
        return self.reader().numbered_rows()

    def chunks(self, chunk_rows: int = CHUNK_ROWS):
        return self.reader().chunks(chunk_rows)

    def release(self) -> None:
        self.shm.close()
        self.shm.unlink()


class RingFile:
    """Reads a run's ring from its file with ``pread``, in the web process or in a
    download's worker: never through a mapping, so that what it reads is a copy of its
    own and the ring's pages never count in the reader's resident memory. A ring
    released (unlinked) before a read began reads as OSError; one released during a read
    is read to its end (the open file keeps it)."""

    def __init__(self, path: str, capacity: int, n_columns: int) -> None:
        self.path, self.capacity, self.n_columns = path, capacity, n_columns
        self.row_bytes = 8 * n_columns

    def _open(self) -> int:
        return os.open(self.path, os.O_RDONLY | os.O_CLOEXEC)

    @staticmethod
    def _counters(fd: int) -> tuple[int, int]:
        """(rows claimed, rows committed), read from the file."""
        claimed, committed = np.frombuffer(os.pread(fd, COUNTER_BYTES, 0), dtype=np.int64)
        return int(claimed), int(committed)

    def _read(self, fd: int, first: int, stop: int) -> np.ndarray:
        """Rows numbered first..stop-1 (all within the ring's span) as a new array."""
        out = np.empty((stop - first, self.n_columns), dtype=np.float64)
        if stop <= first:
            return out
        flat = memoryview(out.reshape(-1).view(np.uint8))
        done = 0
        while first + done < stop:
            slot = (first + done) % self.capacity
            n = min(stop - first - done, self.capacity - slot)  # up to the ring's end
            view = flat[done * self.row_bytes:(done + n) * self.row_bytes]
            offset = COUNTER_BYTES + slot * self.row_bytes
            got = 0
            while got < len(view):
                k = os.preadv(fd, [view[got:]], offset + got)
                if k <= 0:
                    raise OSError("the run's telemetry ring ended early")
                got += k
            done += n
        return out

    def wrap_slack_rows(self) -> int:
        """The rows a wrapped ring's stream leaves out at its oldest end: an eighth of
        the ring (3.75 s of a 30 s ring at 500 Hz), the time its reader may pause."""
        return self.capacity // 8

    def _span(self, fd: int) -> tuple[int, int]:
        """(first, end): the numbers of the rows committed and not overwritten."""
        claimed, committed = self._counters(fd)
        return max(0, committed - self.capacity, claimed - self.capacity), committed

    def numbered_rows(self) -> tuple[int, np.ndarray]:
        """(the number of the first row since the run began, a copy of the rows committed
        so far, oldest first): one array of the ring's rows at most (the rows the loop
        may overwrite while they are read are left out, as in
        app.sim.telemetry.numbered_ring_rows)."""
        fd = self._open()
        try:
            _, committed = self._counters(fd)
            start = max(0, committed - self.capacity)
            rows = self._read(fd, start, committed)
            first = max(start, self._counters(fd)[0] - self.capacity)
        finally:
            os.close(fd)
        if first >= committed:
            return committed, np.empty((0, self.n_columns))
        return first, rows[first - start:]

    def rows_since(self, first: int) -> tuple[int, np.ndarray]:
        """(the number of the first row read, a copy of the rows committed from row
        ``first`` on): only the new rows, for a reader that keeps up (the runs store's
        recorder); a row the loop overwrote before it was read is left out (the number
        returned is then larger than ``first``)."""
        fd = self._open()
        try:
            start, end = self._span(fd)
            start = max(start, first)
            rows = self._read(fd, start, max(start, end))
            lost = self._span(fd)[0] - start  # rows overwritten while read
        finally:
            os.close(fd)
        if lost > 0:
            return start + lost, rows[lost:]
        return start, rows

    def chunks(self, chunk_rows: int = CHUNK_ROWS):
        """(number of the first row, rows) of the rows committed when called, oldest first,
        chunk_rows at a time, each chunk but the first beginning at a multiple of
        chunk_rows (so that a whole chunk is the same rows at every read, for a cache):
        memory for one chunk, whatever the ring's size.

        A ring that has wrapped is overwritten at its oldest end while it is read, and a
        streamed read pauses between chunks as its client takes them: read from the
        oldest row, a pause of a few cycles lost rows in the middle of the stream. So a
        wrapped ring's stream begins :meth:`wrap_slack_rows` after its oldest row (at a
        chunk boundary): the rows it holds are contiguous unless its reader stalls for
        that long, and then the rows overwritten are left out (a gap in the time
        column). Yields nothing for a ring released before the call."""
        try:
            fd = self._open()
        except OSError:
            return
        try:
            first, end = self._span(fd)
            if first > 0:  # wrapped: keep clear of the rows the loop overwrites next
                first = min(end, -(-(first + self.wrap_slack_rows()) // chunk_rows)
                            * chunk_rows)
            while first < end:
                stop = min((first // chunk_rows + 1) * chunk_rows, end)
                rows = self._read(fd, first, stop)
                lost = self._span(fd)[0] - first  # rows overwritten while read
                if lost > 0:
                    first += lost
                    continue
                yield first, rows
                first = stop
        finally:
            os.close(fd)


def attach_ring(name: str, capacity: int, n_columns: int):
    """(shm, data, counters) of a run's telemetry ring, in the loop process."""
    shm = shared_memory.SharedMemory(name=name)
    counters = np.ndarray((2,), dtype=np.int64, buffer=shm.buf)
    data = np.ndarray((capacity, n_columns), dtype=np.float64, buffer=shm.buf,
                      offset=COUNTER_BYTES)
    return shm, data, counters
