"""Each run's telemetry ring in shared memory: the loop process writes, the web reads.

The web process creates the ring when it asks for a run (:class:`RunTelemetry`, sized by
the run's configuration) and sends its name along; the loop process attaches to it
(:func:`attach_ring`) and the Emulator's telemetry buffer keeps its rows there
(``TelemetryBuffer.use_storage``). Telemetry downloads and metrics are then computed in the
web process from a copy (:func:`app.sim.telemetry.numbered_ring_rows`), and cost the loop nothing.
"""

from __future__ import annotations

from multiprocessing import shared_memory

import numpy as np

from app.config import EmulatorConfig
from app.sim.telemetry import loop_columns, numbered_ring_rows

__all__ = ["COUNTER_BYTES", "RunTelemetry", "attach_ring"]

COUNTER_BYTES = 16
"""Two int64 counters (rows claimed, rows committed) ahead of a telemetry ring's rows."""


class RunTelemetry:
    """One run's telemetry ring in shared memory: created here, written by the loop."""

    def __init__(self, config: EmulatorConfig, mode: str | None) -> None:
        self.config = config
        self.mode = mode or config.loop.mode
        n_arms = len(config.robots) if self.mode == "hil" else 0
        self.columns = loop_columns(len(config.satellites), n_arms)
        self.capacity = config.loop.telemetry_capacity
        size = COUNTER_BYTES + 8 * self.capacity * len(self.columns)
        self.shm = shared_memory.SharedMemory(create=True, size=size)
        self.shm.buf[:COUNTER_BYTES] = bytes(COUNTER_BYTES)
        self.name = self.shm.name

    def rows(self):
        """A copy of the rows committed so far, oldest first."""
        return self.numbered_rows()[1]

    def numbered_rows(self) -> tuple[int, np.ndarray]:
        """(the number of the first row since the run began, a copy of the rows committed
        so far, oldest first)."""
        counters = np.ndarray((2,), dtype=np.int64, buffer=self.shm.buf)
        data = np.ndarray((self.capacity, len(self.columns)), dtype=np.float64,
                          buffer=self.shm.buf, offset=COUNTER_BYTES)
        try:
            return numbered_ring_rows(data, counters)
        finally:
            del counters, data  # no view may outlive the mapping (close needs none)

    def release(self) -> None:
        self.shm.close()
        self.shm.unlink()


def attach_ring(name: str, capacity: int, n_columns: int):
    """(shm, data, counters) of a run's telemetry ring, in the loop process."""
    shm = shared_memory.SharedMemory(name=name)
    counters = np.ndarray((2,), dtype=np.int64, buffer=shm.buf)
    data = np.ndarray((capacity, n_columns), dtype=np.float64, buffer=shm.buf,
                      offset=COUNTER_BYTES)
    return shm, data, counters
