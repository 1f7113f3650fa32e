"""The snapshot channel from the loop process to the web process, in shared memory.

The loop publishes its state (a plain dict, pickled) with :class:`SnapshotWriter`; the web
process reads the latest one with :func:`read_snapshot`. The block holds a header (a
sequence number and the length of each slot) and two slots of ``SLOT_BYTES``: the writer
fills the slot the last write did not use, then bumps the sequence number, so it never
waits for a reader; a reader retries when the writer lapped it meanwhile.
"""

from __future__ import annotations

import pickle
import struct
import time
from multiprocessing import shared_memory

SLOT_BYTES = 1 << 20  # one snapshot slot in shared memory
HEADER = struct.Struct("<QQQ")  # sequence number, length of slot 0, length of slot 1
HEARTBEAT = struct.Struct("<Q")  # the loop's heartbeat counter, after the header
HEARTBEAT_AT = 32
SLOT0 = 64  # offset of slot 0 (the header comes first)
SHM_BYTES = SLOT0 + 2 * SLOT_BYTES  # size of the shared memory block


class SnapshotError(RuntimeError):
    """No consistent snapshot could be read (the writer kept lapping the reader)."""


def clear(buf) -> None:
    """Mark a new block as holding no snapshot yet (and no heartbeat)."""
    HEADER.pack_into(buf, 0, 0, 0, 0)
    HEARTBEAT.pack_into(buf, HEARTBEAT_AT, 0)


def beat(buf, count: int) -> None:
    """The loop process: 'still here' (count: its own running counter)."""
    HEARTBEAT.pack_into(buf, HEARTBEAT_AT, count)


def heartbeat(buf) -> int:
    """The last heartbeat count the loop process wrote (0: none yet)."""
    return HEARTBEAT.unpack_from(buf, HEARTBEAT_AT)[0]


def sequence(buf) -> int:
    """Sequence number of the latest snapshot (0 before the first write); cheap."""
    return HEADER.unpack_from(buf, 0)[0]


class SnapshotWriter:
    """The loop process's end: publishes snapshots into a block made by the web process."""

    def __init__(self, shm: shared_memory.SharedMemory) -> None:
        self.buf = shm.buf
        self.seq = 0

    def write(self, snap: dict) -> None:
        data = pickle.dumps(snap, protocol=pickle.HIGHEST_PROTOCOL)
        if len(data) > SLOT_BYTES:  # pragma: no cover - snapshots are a few kB
            raise ValueError(f"snapshot of {len(data)} bytes does not fit its slot")
        nxt = self.seq + 1
        slot = nxt % 2
        start = SLOT0 + slot * SLOT_BYTES
        self.buf[start:start + len(data)] = data
        _, l0, l1 = HEADER.unpack_from(self.buf, 0)
        lens = [l0, l1]
        lens[slot] = len(data)
        HEADER.pack_into(self.buf, 0, nxt, lens[0], lens[1])
        self.seq = nxt


def read_snapshot(buf) -> tuple[int, dict | None]:
    """(sequence, snapshot) from shared memory; (0, None) before the first write."""
    for _ in range(100):
        seq, l0, l1 = HEADER.unpack_from(buf, 0)
        if seq == 0:
            return 0, None
        slot = seq % 2
        length = (l0, l1)[slot]
        start = SLOT0 + slot * SLOT_BYTES
        data = bytes(buf[start:start + length])
        seq2 = HEADER.unpack_from(buf, 0)[0]
        if seq2 - seq < 2:  # the writer did not come back to this slot meanwhile
            try:
                return seq, pickle.loads(data)
            except Exception:  # torn read: retry
                pass
        time.sleep(0.0005)
    raise SnapshotError("could not read a consistent snapshot")
