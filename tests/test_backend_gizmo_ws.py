"""A gizmo drag over viser's real websocket protocol moves the satellite.

The client below speaks what the viser browser client speaks: it connects with the
``viser-v<version>`` subprotocol, drains the server's (zstd + msgpack) frames, and sends
msgpack-encoded messages carrying their class name in ``type`` — the same
TransformControlsDragStart / Update / DragEnd messages the browser sends while the user
drags a transform gizmo.
"""

from __future__ import annotations

import asyncio
import dataclasses

import msgspec
import numpy as np
import pytest
import viser
import websockets
from viser import _messages

from app.backend.scene import GIZMO_OFFSET_W
from tests.live_server import LiveServer

GIZMO = "/gizmo/sat1"
"""(Its handle sits GIZMO_OFFSET_W from the point the hand holds: app/backend/scene.py.)"""


def _encode(message: _messages.Message) -> bytes:
    """Client -> server frame: a msgpack map of the message's fields plus its type."""
    data = dataclasses.asdict(message)
    data["type"] = type(message).__name__
    return msgspec.msgpack.encode(data)


async def _drag(port: int, path: list[tuple[float, float, float]], hold_s: float,
                turns: list[tuple[float, float, float, float]] | None = None) -> int:
    """Connect, wait for the scene (the gizmo must exist), drag along `path` (turned as
    `turns` says, square if None), hold, let go.

    Returns the number of frames received from the server (it must talk to us).
    """
    received = 0
    uri = f"ws://127.0.0.1:{port}/viewer"  # where viser's page connects: through the app
    async with websockets.connect(uri, subprotocols=[f"viser-v{viser.__version__}"],
                                  max_size=None) as ws:

        async def drain() -> None:
            nonlocal received
            async for _ in ws:
                received += 1

        reader = asyncio.create_task(drain())
        for _ in range(100):  # the scene backlog arrives first
            if received >= 1:
                break
            await asyncio.sleep(0.05)
        await asyncio.sleep(0.5)
        await ws.send(_encode(_messages.TransformControlsDragStartMessage(name=GIZMO)))
        for k, position in enumerate(path):
            await ws.send(_encode(_messages.TransformControlsUpdateMessage(
                name=GIZMO, wxyz=(1.0, 0.0, 0.0, 0.0) if turns is None else turns[k],
                position=position)))
            await asyncio.sleep(0.03)
        await asyncio.sleep(hold_s)
        await ws.send(_encode(_messages.TransformControlsDragEndMessage(name=GIZMO)))
        await asyncio.sleep(0.2)
        reader.cancel()
    return received


@pytest.fixture(scope="module")
def live():
    with LiveServer(default_scenario="free-floating") as server:
        yield server


def test_message_encoding_round_trips():
    msg = _messages.TransformControlsUpdateMessage(
        name=GIZMO, wxyz=(1.0, 0.0, 0.0, 0.0), position=(0.1, 0.2, 0.3))
    decoded = _messages.Message.deserialize(_encode(msg))
    assert decoded == msg


def test_gizmo_drag_over_websocket_moves_the_satellite(live):
    quiet = {"pulses": []}  # no scripted pushes
    s = live.client.post("/api/scenarios/free-floating/start", json=quiet).json()
    assert s["status"] == "running"
    live.wait_for_scene()
    s0 = live.wait_for(lambda s: s["t_s"] > 0.2)
    p0_R = np.array(s0["satellites"][0]["position_m"])
    mockup_W = np.array(s0["robots"][0]["mockup_position_W_m"]) + GIZMO_OFFSET_W  # handle
    # drag 15 cm along +y of the lab (= +y of R here: R is not rotated) in 5 steps
    path = [tuple(float(v) for v in mockup_W + [0.0, 0.03 * k, 0.0]) for k in range(1, 6)]
    received = asyncio.run(_drag(live.port, path, hold_s=1.0))
    assert received > 0
    s1 = live.state()
    p1_R = np.array(s1["satellites"][0]["position_m"])
    v1_R = np.array(s1["satellites"][0]["velocity_mps"])
    dp = p1_R - p0_R
    # the hand's press (k x 0.15 m, capped), x force_scale on the mass, held ~1 s; less the
    # F/T deadband and the way the mockup closes on the hand: at least 40 % of that
    cfg = live.app.state.service.config_for("free-floating")
    force_N = min(cfg.hand.stiffness_Npm * 0.15, cfg.hand.max_force_N)
    assert v1_R[1] > 0.4 * cfg.orbit.force_scale * force_N / cfg.satellites[0].mass_kg, v1_R
    assert dp[1] > 0.01, dp
    assert abs(v1_R[0]) < 0.3 * v1_R[1] and abs(v1_R[2]) < 0.3 * v1_R[1], v1_R
    # letting go stops the push: the velocity stays (free floating), nothing pulls back
    s2 = live.wait_for(lambda s: s["t_s"] > s1["t_s"] + 0.6)
    v2_R = np.array(s2["satellites"][0]["velocity_mps"])
    assert abs(v2_R[1] - v1_R[1]) < 0.2 * v1_R[1], (v1_R, v2_R)
    live.client.post("/api/stop")


def test_a_gizmo_turned_about_z_twists_the_satellite_one_way(live):
    """The gizmo turned 30 degrees about the lab's z (= R's z here) in 5 steps and held
    1 s, without moving: the hand twists the mockup about z (k_t x angle, capped at
    max_torque_Nm), the satellite spins up about z and keeps spinning after the let-go,
    never back; no push (the position stays)."""
    live.client.post("/api/stop")
    s = live.client.post("/api/scenarios/free-floating/start", json={"pulses": []}).json()
    assert s["status"] == "running"
    live.wait_for_scene()
    s0 = live.wait_for(lambda s: s["t_s"] > 0.2)
    mockup_W = tuple(float(v) for v in np.array(s0["robots"][0]["mockup_position_W_m"])
                     + GIZMO_OFFSET_W)  # the handle, under the mockup
    angles = np.radians([6.0 * k for k in range(1, 6)])
    turns = [(float(np.cos(a / 2)), 0.0, 0.0, float(np.sin(a / 2))) for a in angles]
    asyncio.run(_drag(live.port, [mockup_W] * 5, hold_s=1.0, turns=turns))
    s1 = live.state()
    w1 = np.array(s1["satellites"][0]["omega_radps"])
    cfg = live.app.state.service.config_for("free-floating")
    izz = cfg.satellites[0].principal_inertia()[2]
    rate_max = cfg.orbit.torque_scale * cfg.hand.max_torque_Nm / izz  # rad/s^2 at the cap
    assert 0.02 < w1[2] < rate_max * 1.6, w1  # ~1.3 s of twisting at most
    assert np.hypot(w1[0], w1[1]) < 0.2 * w1[2], w1
    s2 = live.wait_for(lambda s: s["t_s"] > s1["t_s"] + 1.0)
    w2 = np.array(s2["satellites"][0]["omega_radps"])
    assert abs(w2[2] - w1[2]) < 0.1 * w1[2], (w1, w2)  # let go: it spins on
    assert np.linalg.norm(s2["satellites"][0]["velocity_mps"]) < 1e-3
    live.client.post("/api/stop")


def test_gizmo_drag_when_stopped_changes_nothing(live):
    live.client.post("/api/stop")
    s0 = live.state()
    mockup_W = np.array(s0["robots"][0]["mockup_position_W_m"]) + GIZMO_OFFSET_W
    target = tuple(float(v) for v in mockup_W + [0.0, 0.1, 0.0])
    asyncio.run(_drag(live.port, [target], hold_s=0.2))
    s1 = live.state()
    assert s1["t_s"] == s0["t_s"]
    assert s1["satellites"] == s0["satellites"]
