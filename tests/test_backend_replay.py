"""The 3D replay's recording (app/backend/replay.py) against viser's own serializer."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest
import viser

from app.backend.replay import _compact


@pytest.fixture(scope="module")
def server():
    srv = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    yield srv
    srv.stop()


def _record(server, serializers, moves: int) -> None:
    """A frame moved `moves` times at 30 Hz (the scene's updates while a satellite moves),
    with its time in every serializer."""
    frame = server.scene.add_frame("/moving", axes_length=0.1)
    for k in range(moves):
        frame.position = (0.001 * k, 0.0, 0.5)
        frame.wxyz = (np.cos(0.001 * k), 0.0, 0.0, np.sin(0.001 * k))
        for serializer in serializers:
            serializer.insert_sleep(1.0 / 30.0)


def test_the_compact_recording_is_the_same_file_as_viser_s(server):
    plain = server.get_scene_serializer()
    compact = _compact(server.get_scene_serializer())
    _record(server, [plain, compact], moves=300)
    assert len(plain._messages) > 600  # (the compact one holds them deflated)
    assert compact.serialize() == plain.serialize()


def test_the_compact_recording_holds_at_most_a_quarter_of_the_memory(server):
    held = {}
    for name, wrap in (("plain", lambda s: s), ("compact", _compact)):
        tracemalloc.start()
        serializer = wrap(server.get_scene_serializer())
        before = tracemalloc.get_traced_memory()[0]
        _record(server, [serializer], moves=1500)
        held[name] = tracemalloc.get_traced_memory()[0] - before
        tracemalloc.stop()
        serializer.serialize()
    assert held["compact"] < 0.25 * held["plain"], held
