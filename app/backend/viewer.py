"""The 3D viewer behind the web app: viser on loopback, reached only through /viewer/.

viser is not an ASGI app: it runs its own HTTP + websocket server. Here it listens on
127.0.0.1 only and answers a request only if it carries a secret that lives in this
process (403 otherwise, to a browser on this machine too: a page on any site could open
a websocket to a loopback port). The FastAPI app serves the viewer at ``/viewer/``: the
page by proxying viser's HTTP answer, the websocket by relaying frames both ways, both
behind the app's Host/Origin checks and its token. One port for everything.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import http
import http.client
import inspect
import io
import logging
import secrets
import urllib.error
import urllib.request
from contextlib import contextmanager
from urllib.parse import quote

import websockets
import websockets.asyncio.server
from fastapi import FastAPI, Request, WebSocket, WebSocketDisconnect
from fastapi.responses import Response
from uvicorn.protocols.utils import ClientDisconnected

log = logging.getLogger("orbit_emulator.viewer")

SECRET_HEADER = "X-Orbit-Emulator-Viewer"
PATH = "/viewer/"


@contextmanager
def _serve_behind(secret: str):
    """While viser starts its server: wrap the request hook it hands to websockets' serve
    so that every HTTP request and websocket handshake must carry the secret. viser calls
    ``websockets.asyncio.server.serve`` once, before its constructor returns."""
    original = websockets.asyncio.server.serve

    def serve(*args, process_request=None, **kwargs):
        return original(*args, process_request=_guard(process_request, secret), **kwargs)

    websockets.asyncio.server.serve = serve
    try:
        yield
    finally:
        websockets.asyncio.server.serve = original


def _guard(process_request, secret: str):
    async def guarded(connection, request):
        if not hmac.compare_digest(request.headers.get(SECRET_HEADER, ""), secret):
            return connection.respond(http.HTTPStatus.FORBIDDEN,
                                      f"the 3D viewer is served at the web app's {PATH}\n")
        if process_request is None:
            return None
        answer = process_request(connection, request)
        return await answer if inspect.isawaitable(answer) else answer

    return guarded


def start_viser(port: int = 0):
    """(a viser server on 127.0.0.1:port (0: any free port), its secret). Raises
    RuntimeError if viser answers a request without the secret (a viser that no longer
    starts its server as this module expects): the viewer is never left open."""
    import viser

    secret = secrets.token_urlsafe(32)
    # viser prints its own address, which answers nobody without the secret: not shown
    # (and a stdout gone away cannot fail the start)
    with _serve_behind(secret), contextlib.redirect_stdout(io.StringIO()):
        server = viser.ViserServer(host="127.0.0.1", port=port, verbose=False)
    try:
        urllib.request.urlopen(f"http://127.0.0.1:{server.get_port()}/", timeout=5)
    except urllib.error.HTTPError as err:
        if err.code == 403:
            return server, secret
    server.stop()
    raise RuntimeError("viser answered without the viewer secret: refusing to serve it")


def add_viewer_routes(app: FastAPI) -> None:
    """GET /viewer/... (viser's page and files) and the websocket at /viewer/; they read
    ``app.state.viser_port`` and ``app.state.viewer_secret``."""

    @app.get(PATH + "{path:path}", include_in_schema=False)
    async def viewer_page(path: str, request: Request):
        url = f"http://127.0.0.1:{request.app.state.viser_port}/{quote(path)}"
        status, kind, body = await asyncio.to_thread(
            _fetch, url, request.app.state.viewer_secret)
        return Response(body, status_code=status, media_type=kind)

    @app.websocket(PATH)
    @app.websocket(PATH.rstrip("/"))  # where viser's page connects: its own URL, no slash
    async def viewer_socket(client: WebSocket):
        offered = [p for p in client.scope.get("subprotocols", []) if p.startswith("viser-v")]
        try:
            upstream = await websockets.connect(
                f"ws://127.0.0.1:{client.app.state.viser_port}/",
                subprotocols=offered[:1] or None, max_size=None, compression=None,
                additional_headers={SECRET_HEADER: client.app.state.viewer_secret})
        except (OSError, websockets.InvalidHandshake):
            await client.close(code=1011)
            return
        await client.accept(subprotocol=upstream.subprotocol)
        try:
            await _relay(client, upstream)
        finally:
            await upstream.close()


def _fetch(url: str, secret: str) -> tuple[int, str, bytes]:
    request = urllib.request.Request(url, headers={SECRET_HEADER: secret})
    try:
        with urllib.request.urlopen(request, timeout=10) as answer:
            return answer.status, answer.headers.get_content_type(), answer.read()
    except urllib.error.HTTPError as err:
        return err.code, "text/plain", err.read()
    except (urllib.error.URLError, http.client.HTTPException, ValueError, OSError) as err:
        return 502, "text/plain", f"the 3D viewer did not answer: {err}\n".encode()


async def _relay(client: WebSocket, upstream) -> None:
    """Frames both ways until either side closes."""

    async def down():
        async for frame in upstream:
            if isinstance(frame, bytes):
                await client.send_bytes(frame)
            else:
                await client.send_text(frame)

    async def up():
        while True:
            message = await client.receive()
            if message["type"] == "websocket.disconnect":
                return
            if message.get("bytes") is not None:
                await upstream.send(message["bytes"])
            elif message.get("text") is not None:
                await upstream.send(message["text"])

    tasks = [asyncio.create_task(_until_closed(down())), asyncio.create_task(_until_closed(up()))]
    _, pending = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
    for task in pending:
        task.cancel()
    await _until_closed(client.close(code=_client_close_code(upstream.close_code)))


def _client_close_code(upstream_code: int | None) -> int:
    """The code the browser gets when viser ended the connection: viser's own, except the
    codes that may not be sent (1005 no code: a normal close; 1006 the connection broke,
    1015 TLS: viser is going away, 1001)."""
    if upstream_code in (None, 1005):
        return 1000
    if upstream_code in (1006, 1015):
        return 1001
    return upstream_code


async def _until_closed(work) -> None:
    """Run `work`; a side that went away (the browser closed the tab, viser stopped) ends
    it quietly: that is how every viewer connection ends."""
    try:
        await work
    except (websockets.ConnectionClosed, WebSocketDisconnect, ClientDisconnected, OSError,
            RuntimeError) as err:
        log.debug("viewer connection closed: %r", err)
