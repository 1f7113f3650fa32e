"""The 3D replay's recording (app/backend/replay.py) against viser's own serializer."""

from __future__ import annotations

import sys

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


def _held_bytes(obj, seen: set[int] | None = None) -> int:
    """The memory ``obj`` holds: its size and that of everything it contains."""
    seen = set() if seen is None else seen
    if id(obj) in seen:
        return 0
    seen.add(id(obj))
    size = sys.getsizeof(obj)
    if isinstance(obj, dict):
        size += sum(_held_bytes(k, seen) + _held_bytes(v, seen) for k, v in obj.items())
    elif isinstance(obj, (list, tuple)):
        size += sum(_held_bytes(v, seen) for v in obj)
    elif isinstance(obj, np.ndarray) and obj.base is not None:
        size += _held_bytes(obj.base, seen)
    return size


def _recording_bytes(serializer) -> int:
    return sum(_held_bytes(getattr(serializer, name))
               for name in ("_messages", "_entries", "_pending", "_pending_t")
               if hasattr(serializer, name))


def test_the_compact_recording_holds_at_most_a_fifth_of_the_memory(server):
    """1500 pose updates (3000 messages, 50 s of a moving satellite's frame)."""
    held = {}
    for name, wrap in (("plain", lambda s: s), ("compact", _compact)):
        serializer = wrap(server.get_scene_serializer())
        before = _recording_bytes(serializer)
        _record(server, [serializer], moves=1500)
        held[name] = _recording_bytes(serializer) - before
        serializer.serialize()
    assert held["compact"] < 0.2 * held["plain"], held  # (0.11 here: 441 of them not yet deflated)


def test_messages_with_binary_buffers_keep_their_place_and_their_dedup(server):
    """A point cloud sent twice with the same points (viser's serialize() then shares one
    buffer and rewrites the placeholders), between pose updates: the same file."""
    plain = server.get_scene_serializer()
    compact = _compact(server.get_scene_serializer())
    points = np.random.default_rng(0).uniform(-1.0, 1.0, (200, 3)).astype(np.float32)
    _record(server, [plain, compact], moves=20)
    server.scene.add_point_cloud("/cloud", points=points, colors=(255, 0, 0))
    _record(server, [plain, compact], moves=20)
    server.scene.add_point_cloud("/cloud2", points=points, colors=(255, 0, 0))
    _record(server, [plain, compact], moves=700)
    assert compact.serialize() == plain.serialize()
