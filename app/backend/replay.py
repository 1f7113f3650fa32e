"""A run's 3D replay: viser's scene recording, in one HTML file that plays without a server.

While a run goes on, :class:`ReplayRecorder` records what the scene sends (viser's scene
serializer, with the time between updates); when it ends, the recording is kept. The
standalone file (:func:`replay_html`) is viser's own client page (one self-contained
HTML file in the viser package) with the recording embedded: a small script in front of
the client hands the recording to the client's playback (``?playbackPath=``) when it
asks for it, so the file plays from disk, offline, in any browser.
"""

from __future__ import annotations

import base64
import copy
import logging
import threading
from collections.abc import Callable
from pathlib import Path

__all__ = ["MAX_REPLAY_S", "ReplayRecorder", "replay_html", "replay_title"]

MAX_REPLAY_S = 600.0
"""A replay keeps at most this much of a run (its first 10 minutes), to bound memory."""

_NAME = "orbit-emulator-replay.viser"

log = logging.getLogger("orbit_emulator.replay")

Finished = tuple[int, bytes, bool]
"""(generation, recording, truncated) of a finished recording."""


class ReplayRecorder:
    """Records the scene during one run at a time; keeps the last finished recording."""

    def __init__(self, server) -> None:
        self.server = server
        self._lock = threading.Lock()
        self._serializer = None
        self._generation: int | None = None
        self._last_time = 0.0
        self._recorded_s = 0.0
        self.last: Finished | None = None
        """(generation, recording, truncated) of the last finished recording."""
        self.on_finish: Callable[[int, bytes, bool], None] | None = None
        """Called with each recording as it finishes (outside the lock; the web app keeps
        it in the run's folder: app/backend/recorder.py save_replay)."""

    @property
    def recording(self) -> bool:
        with self._lock:
            return self._serializer is not None

    def start(self, generation: int) -> None:
        """Begin recording run `generation` (the scene as it is now, then every change)."""
        with self._lock:
            done = self._finish_locked(truncated=False)
            self._serializer = _compact(self.server.get_scene_serializer())
            self._generation, self._last_time, self._recorded_s = generation, 0.0, 0.0
        self._hand_on(done)

    def tick(self, t_s: float) -> None:
        """Scenario time ``t_s`` has come: call before sending a frame's updates. The
        recording's clock is the scenario's, so a replay plays at scenario time whatever
        the loop's real-time factor was while it ran."""
        done = None
        with self._lock:
            if self._serializer is None:
                return
            dt = max(0.0, t_s - self._last_time)
            self._last_time = max(self._last_time, t_s)
            self._recorded_s += dt
            if self._recorded_s > MAX_REPLAY_S:
                done = self._finish_locked(truncated=True)
            else:
                self._serializer.insert_sleep(dt)
        self._hand_on(done)

    def finish(self) -> None:
        """End the recording (the run ended or was replaced); keep it as the last one."""
        with self._lock:
            done = self._finish_locked(truncated=False)
        self._hand_on(done)

    def _finish_locked(self, truncated: bool) -> Finished | None:
        if self._serializer is None:
            return None
        self.last = (self._generation, self._serializer.serialize(), truncated)
        self._serializer = None
        return self.last

    def _hand_on(self, done: Finished | None) -> None:
        if done is None or self.on_finish is None:
            return
        try:
            self.on_finish(*done)
        except Exception:  # noqa: BLE001 - the scene goes on whatever keeping it did
            log.exception("keeping the replay of run %d failed", done[0])

    def current(self) -> tuple[int, bytes, bool] | None:
        """The recording of the run going on, so far (it goes on recording), else the last
        finished one; None before any run."""
        with self._lock:
            if self._serializer is None:
                return self.last
            return self._generation, _serialize_copy(self._serializer), False


def _compact(serializer):
    """``serializer`` (viser's), made a :class:`_CompactSerializer`: what it records
    from now on is held encoded."""
    import array

    serializer.__class__ = _compact_class()
    serializer._entries, serializer._pending = [], []
    serializer._pending_t = array.array("d")
    return serializer


def _compact_class():
    """The class of a compact recording (made on first use: viser is imported late)."""
    global _COMPACT
    if _COMPACT is None:
        import array
        import zlib

        import msgspec
        from viser.infra._infra import StateSerializer

        encode = msgspec.msgpack.Encoder().encode

        class _CompactSerializer(StateSerializer):
            """A scene recording that holds what it records compressed: each message
            as its msgpack encoding, CHUNK_MESSAGES of them at a time deflated (zlib)
            with their times and lengths; serialize() hands them to viser's as they are
            (``msgspec.Raw``): the same file. A message with binary buffers (a mesh, a
            point cloud) is kept as viser keeps it, in its place, for viser's
            serialize() rewrites those. The scene sends about 160 messages a second
            while a satellite moves, and the recording of a run (up to MAX_REPLAY_S)
            stays in the web process until the run ends: held as viser holds it (a
            tuple and a dict each) it grew the web process by about 3.6 MB a minute,
            held so by about a twentieth of that (a private part of viser 1.x, as
            :func:`_serialize_copy`; tests/test_backend_replay.py checks both)."""

            def _insert_message(self, message) -> None:
                if not self._filter(message):
                    return
                buffers = len(self._binary_buffers)
                data = message.as_serializable_dict(self._binary_buffers)
                if len(self._binary_buffers) != buffers:
                    self._flush()
                    self._entries.append(("plain", self._time, data))
                    return
                self._pending.append(encode(data))
                self._pending_t.append(self._time)
                if len(self._pending) >= CHUNK_MESSAGES:
                    self._flush()

            def _flush(self) -> None:
                if self._pending:
                    self._entries.append((zlib.compress(b"".join(self._pending), 1),
                                          array.array("I", map(len, self._pending)),
                                          self._pending_t))
                    self._pending, self._pending_t = [], array.array("d")

            def serialize(self) -> bytes:
                self._flush()
                messages = list(self._messages)
                for entry in self._entries:
                    if entry[0] == "plain":
                        messages.append(entry[1:])
                        continue
                    data, at = zlib.decompress(entry[0]), 0
                    for n, t_s in zip(entry[1], entry[2], strict=True):
                        messages.append((t_s, msgspec.Raw(data[at:at + n])))
                        at += n
                self._messages, self._entries = messages, []
                return super().serialize()

            def copy(self):
                """A copy to serialize while this one goes on recording."""
                clone = copy.copy(self)
                clone._messages = list(self._messages)
                clone._binary_buffers = list(self._binary_buffers)
                clone._entries = list(self._entries)
                clone._pending = list(self._pending)
                clone._pending_t = array.array("d", self._pending_t)
                return clone

        _COMPACT = _CompactSerializer
    return _COMPACT


_COMPACT = None
CHUNK_MESSAGES = 512
"""A compact recording deflates its messages this many at a time (about 3 s of a run)."""


def _serialize_copy(serializer) -> bytes:
    """What ``serializer`` recorded so far, leaving it recording. viser's serialize() ends
    a recording, so a copy of it (its message and buffer lists) is serialized instead; the
    copy is registered with the websocket handler for the moment, as serialize() expects
    (a private part of viser 1.x: tests/test_backend_rest.py checks it)."""
    clone = serializer.copy()
    handler = serializer._handler
    with handler._record_lock:
        handler._record_handles.append(clone)
    return clone.serialize()


def _client_page() -> str:
    import viser

    return (Path(viser.__file__).parent / "client" / "build" / "index.html").read_text()


def replay_html(recording: bytes, title: str) -> str:
    """One HTML file that replays `recording` (a .viser scene recording) offline."""
    page = _client_page()
    shim = f"""<script>
(function () {{
  // the recording, embedded: handed to the viewer's playback when it asks for it
  var b64 = "{base64.b64encode(recording).decode()}";
  var name = "{_NAME}";
  var bin = atob(b64), bytes = new Uint8Array(bin.length);
  for (var i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
  if (new URLSearchParams(location.search).get("playbackPath") !== name) {{
    history.replaceState(null, "", location.pathname + "?playbackPath=" + name);
  }}
  var realFetch = window.fetch.bind(window);
  window.fetch = function (input, init) {{
    var url = typeof input === "string" ? input : (input && input.url) || String(input);
    if (url.indexOf(name) !== -1) {{
      return Promise.resolve(new Response(bytes, {{status: 200, headers: {{
        "Content-Type": "application/octet-stream",
        "Content-Length": String(bytes.length)}}}}));
    }}
    return realFetch(input, init);
  }};
}})();
</script>"""
    page = page.replace("<title>Viser</title>", f"<title>{_escape(title)}</title>", 1)
    head = page.index("<head>") + len("<head>")
    return page[:head] + "\n" + shim + page[head:]


def replay_title(scenario: str, mode: str, truncated: bool) -> str:
    """A replay's title: what ran, and whether only its first 10 minutes are in it."""
    return (f"orbit-emulator replay: {scenario} ({mode})"
            + (f", first {MAX_REPLAY_S / 60:g} min" if truncated else ""))


def _escape(text: str) -> str:
    return (text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;"))
