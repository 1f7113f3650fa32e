"""FastAPI app: REST API (OpenAPI at /docs), the static page, and the viser server.

viser is not an ASGI app and runs its own websocket/HTTP server on another port; the
lifespan starts it (reading the port it actually bound back: it moves to the next free
port when taken, and port 0 gives an ephemeral one), builds the scene, starts the loop
thread, and stops all three on shutdown.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import os
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Annotated, Any, Literal

from fastapi import Body, FastAPI, HTTPException, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, HTMLResponse, JSONResponse, PlainTextResponse
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, ConfigDict, Field, StrictInt

from app.backend.runner import RunnerError
from app.backend.service import (
    MAX_PUSH_DURATION_S,
    MAX_PUSH_FORCE_N,
    EmulatorService,
    InvalidRequest,
    RunnerBusy,
    UnknownScenario,
)

log = logging.getLogger("orbit_emulator.server")

# strict: no numeric strings or booleans; finite: no NaN / Infinity (which Python's JSON
# parser accepts)
FiniteFloat = Annotated[float, Field(strict=True, allow_inf_nan=False)]


def static_dir() -> Path | None:
    """static/ of the source tree (or $ORBIT_EMULATOR_STATIC, or ./static)."""
    candidates = []
    if os.environ.get("ORBIT_EMULATOR_STATIC"):
        candidates.append(Path(os.environ["ORBIT_EMULATOR_STATIC"]))
    candidates += [Path(__file__).resolve().parents[2] / "static", Path.cwd() / "static"]
    for path in candidates:
        if (path / "index.html").is_file():
            return path
    return None


# --- request / response models ----------------------------------------------------------


class PushRequest(BaseModel):
    """A hand push on one satellite: force in frame R through its COM, for duration_s."""

    model_config = ConfigDict(extra="forbid")

    satellite: StrictInt = Field(description="1-based satellite index", examples=[1])
    force_N: list[FiniteFloat] = Field(
        min_length=3, max_length=3,
        description=f"force in R (N), magnitude at most {MAX_PUSH_FORCE_N:g} N (sensor range)",
        examples=[[0.0, 20.0, 0.0]],
    )
    duration_s: FiniteFloat = Field(
        gt=0.0, le=MAX_PUSH_DURATION_S, description="seconds", examples=[0.3]
    )


class ScenarioInfo(BaseModel):
    name: str
    description: str


MAX_MISS_RATIO = 0.01
"""Health turns "degraded" when more of the last 10 s of cycles missed their deadline."""


class Health(BaseModel):
    status: Literal["ok", "degraded"]
    deadline_miss_ratio_10s: float | None = Field(
        description="share of the cycles of the last 10 s that missed their deadline "
        "(null when none ran); above 0.01 the status is 'degraded'")
    viser_port: int
    loop_alive: bool
    emulator_status: str
    scene_generation: int | None = Field(
        description="generation of the run the 3D scene shows (see /api/state)"
    )


class Message(BaseModel):
    detail: str


class Fault(BaseModel):
    """/api/health while the loop process is dead or stalled (503)."""

    status: Literal["fault"]
    reason: str


START_BODY_EXAMPLE = {
    "satellites": {"0": {"velocity_mps": [0.01, 0.0, 0.0]}},
    "vfdm": {"kp_lin": 20},
    "mode": "hil",
}


def json_safe(value):
    """Replace non-finite floats with None (JSON has no NaN / Infinity)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    return value


def _field_errors(errors) -> str:
    parts = []
    for e in errors:
        loc = list(e.get("loc", ()))
        if e.get("type") == "json_invalid":
            loc = ["body"]  # loc[1] is the character position
        elif len(loc) > 1 and loc[0] == "body":
            loc = loc[1:]
        msg = str(e.get("msg", "invalid")).removeprefix("Value error, ")
        parts.append(f"{'.'.join(str(p) for p in loc) or 'body'}: {msg}")
    return "; ".join(parts)


# --- the app ----------------------------------------------------------------------------


MAX_BODY_BYTES = 64 * 1024
"""Request bodies beyond this get 413 before anything reads them whole."""


class BodyLimit:
    """ASGI middleware: 413 for an HTTP request whose body exceeds ``limit`` bytes, by its
    Content-Length or, without one, once the chunks read pass it (a body within the limit
    is read here and handed on whole)."""

    def __init__(self, app, limit: int = MAX_BODY_BYTES) -> None:
        self.app = app
        self.limit = limit

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        declared = dict(scope.get("headers") or ()).get(b"content-length")
        if declared is not None:
            try:
                if int(declared) > self.limit:
                    return await self._reject(send)
            except ValueError:
                pass
        chunks, size = [], 0
        while True:
            message = await receive()
            if message["type"] != "http.request":  # the client went away
                return
            chunks.append(message.get("body", b""))
            size += len(chunks[-1])
            if size > self.limit:
                return await self._reject(send)
            if not message.get("more_body", False):
                break
        body = b"".join(chunks)
        replayed = False

        async def replay():
            nonlocal replayed
            if not replayed:
                replayed = True
                return {"type": "http.request", "body": body, "more_body": False}
            return await receive()  # after the body: wait for a disconnect, as usual

        await self.app(scope, replay, send)

    async def _reject(self, send) -> None:
        body = b'{"detail":"request body over %d KiB"}' % (self.limit // 1024)
        await send({"type": "http.response.start", "status": 413,
                    "headers": [(b"content-type", b"application/json"),
                                (b"content-length", str(len(body)).encode())]})
        await send({"type": "http.response.body", "body": body})


LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1")
ALLOWED_HOSTS_ENV = "ORBIT_EMULATOR_ALLOWED_HOSTS"
"""Comma-separated host names the server answers to beside loopback (and its bind host)."""


def allowed_hosts(bind_host: str) -> frozenset[str]:
    """The host names a request's Host and Origin may name: loopback, the address bound
    (unless a wildcard) and those in $ORBIT_EMULATOR_ALLOWED_HOSTS."""
    extra = [h.strip().lower() for h in os.environ.get(ALLOWED_HOSTS_ENV, "").split(",")]
    names = set(LOOPBACK_HOSTS) | {h for h in extra if h}
    if bind_host not in ("0.0.0.0", "::", ""):
        names.add(bind_host.lower().strip("[]"))
    return frozenset(names)


def _host_name(authority: str) -> str:
    """'example.org:8000' -> 'example.org', '[::1]:8000' -> '::1'."""
    authority = authority.strip().lower()
    if authority.startswith("["):
        return authority[1:].split("]", 1)[0]
    return authority.rsplit(":", 1)[0] if authority.count(":") == 1 else authority


class SameOrigin:
    """ASGI middleware against DNS rebinding and cross-site requests (HTTP and websocket).

    The Host header must name an allowed host (400 otherwise): a page on a foreign name
    that resolves to this machine cannot reach the API. An Origin header, which browsers
    send with cross-site and state-changing requests, must name an allowed host too (403).
    A request with a body must declare ``application/json`` (415): a cross-site form or
    ``text/plain`` post, which browsers send without asking first, is refused.
    """

    def __init__(self, app, hosts: frozenset[str]) -> None:
        self.app = app
        self.hosts = hosts

    async def __call__(self, scope, receive, send):
        if scope["type"] not in ("http", "websocket"):
            return await self.app(scope, receive, send)
        headers = dict(scope.get("headers") or ())
        host = headers.get(b"host", b"").decode("latin-1")
        if _host_name(host) not in self.hosts:
            return await self._reject(scope, send, 400, f"host {host!r} is not allowed")
        origin = headers.get(b"origin")
        if origin is not None:
            authority = origin.decode("latin-1").split("://", 1)[-1]
            if _host_name(authority) not in self.hosts:
                return await self._reject(scope, send, 403,
                                          f"origin {origin.decode('latin-1')!r} is not allowed")
        if scope["type"] == "http" and _has_body(headers):
            kind = headers.get(b"content-type", b"").split(b";")[0].strip().lower()
            if kind != b"application/json":
                return await self._reject(scope, send, 415,
                                          "a request body must be application/json")
        return await self.app(scope, receive, send)

    @staticmethod
    async def _reject(scope, send, status: int, detail: str) -> None:
        if scope["type"] == "websocket":
            await send({"type": "websocket.close", "code": 1008})
            return
        body = json.dumps({"detail": detail}).encode()
        await send({"type": "http.response.start", "status": status,
                    "headers": [(b"content-type", b"application/json"),
                                (b"content-length", str(len(body)).encode())]})
        await send({"type": "http.response.body", "body": body})


def _has_body(headers: dict) -> bool:
    length = headers.get(b"content-length")
    if length is not None:
        return length.strip() not in (b"0", b"")
    return b"transfer-encoding" in headers


def create_app(
    viser_port: int = 0,
    host: str = "127.0.0.1",
    default_scenario: str | None = None,
    scene_rate_hz: float = 30.0,
) -> FastAPI:
    """The FastAPI app; its lifespan runs viser on `viser_port` (0: ephemeral) at `host`."""

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        import viser

        from app.backend.scene import EmulatorScene

        service = await asyncio.to_thread(EmulatorService, default_scenario)
        await asyncio.to_thread(service.start_thread)  # the loop process: first snapshot
        server = viser.ViserServer(host=host, port=viser_port, verbose=False)
        try:
            scene = await asyncio.to_thread(EmulatorScene, server, service, scene_rate_hz)
            app.state.service = service
            app.state.viser = server
            app.state.scene = scene
            app.state.viser_port = server.get_port()
            scene.start()
            log.info("viser on port %d", app.state.viser_port)
            yield
        finally:
            if getattr(app.state, "scene", None) is not None:
                app.state.scene.stop()
            service.shutdown()
            server.stop()

    app = FastAPI(
        title="orbit-emulator",
        description=(
            "On-orbit interaction emulator with two UR10e arms (Clohessy-Wiltshire ODS + "
            "VFDM). The 3D view is a viser server on its own port (GET /api/health "
            "gives it)."
        ),
        version="0.1.0",
        lifespan=lifespan,
    )
    app.add_middleware(BodyLimit)
    app.add_middleware(SameOrigin, hosts=allowed_hosts(host))

    def service(request: Request) -> EmulatorService:
        return request.app.state.service

    @app.exception_handler(RequestValidationError)
    async def _validation_error(_request: Request, exc: RequestValidationError):
        # never echo the input back: it may hold NaN, which JSON cannot carry
        return JSONResponse(
            status_code=422,
            content={"detail": _field_errors(exc.errors()),
                     "errors": [{"loc": list(e.get("loc", ())), "msg": e.get("msg"),
                                 "type": e.get("type")} for e in exc.errors()]},
        )

    def _http(status: int, err: Exception) -> HTTPException:
        return HTTPException(status_code=status, detail=str(err))

    errors_409 = {409: {"model": Message}, 422: {"model": Message}}

    # --- pages --------------------------------------------------------------------

    @app.get("/", include_in_schema=False)
    async def index():
        root = static_dir()
        if root is None:
            return HTMLResponse("<h1>orbit-emulator</h1><p>static/index.html missing; "
                                "see <a href='/docs'>/docs</a>.</p>")
        return FileResponse(root / "index.html")

    root = static_dir()
    if root is not None:
        app.mount("/static", StaticFiles(directory=root), name="static")

    # --- API --------------------------------------------------------------------------

    @app.exception_handler(RunnerError)
    async def _loop_down(_request: Request, exc: RunnerError):
        # the loop process is dead, stalled or did not answer: the server itself is fine
        return JSONResponse(status_code=503, content={
            "detail": f"{exc}; POST /api/reset or a start restarts the loop"})

    @app.get("/api/health", response_model=Health, tags=["status"],
             responses={503: {"model": Fault}})
    async def health(request: Request):
        svc = service(request)
        fault = svc.runner.fault()
        if fault is not None:
            return JSONResponse(status_code=503, content={"status": "fault", "reason": fault})
        alive = svc.runner.alive
        ratio = svc.runner.miss_ratio()
        late = ratio is not None and ratio > MAX_MISS_RATIO
        return {
            "status": "ok" if alive and not late else "degraded",
            "deadline_miss_ratio_10s": ratio,
            "viser_port": request.app.state.viser_port,
            "loop_alive": alive,
            "emulator_status": svc.runner.status,
            "scene_generation": request.app.state.scene.generation,
        }

    @app.get("/api/scenarios", response_model=list[ScenarioInfo], tags=["scenarios"])
    async def scenarios():
        return EmulatorService.scenarios()

    @app.post(
        "/api/scenarios/{name}/start", tags=["scenarios"],
        responses={404: {"model": Message}, **errors_409},
    )
    def start(
        name: str,
        request: Request,
        body: Annotated[
            dict[str, Any] | None,
            Body(description="config overrides, a JSON merge patch of the scenario (RFC "
                 "7396: a list replaces the list, null restores a default; an object of "
                 "item indices such as {\"0\": {...}} patches list items), and an "
                 "optional 'mode' ('hil' or 'ideal')", examples=[START_BODY_EXAMPLE]),
        ] = None,
    ) -> dict[str, Any]:
        """Start a scenario with optional overrides; returns the state once running.

        404: unknown scenario; 409: one is already running; 422: invalid overrides (the
        message names the field), or the scenario could not start (e.g. a start pose out
        of reach: the state then has status "error" and the reason).
        """
        svc = service(request)
        overrides = dict(body or {})
        mode = overrides.pop("mode", None)
        try:
            state = svc.start(name, overrides, mode=mode)
            if state["status"] in ("error", "safety_stop"):
                raise HTTPException(
                    status_code=422,
                    detail=f"scenario {name!r} could not start: {state['reason']}",
                )
            return json_safe(state)
        except UnknownScenario as err:
            raise _http(404, err) from None
        except RunnerBusy as err:
            raise _http(409, err) from None
        except InvalidRequest as err:
            raise _http(422, err) from None

    @app.post("/api/stop", tags=["control"])
    def stop(request: Request) -> dict[str, Any]:
        """Stop the running scenario (no-op when none runs)."""
        return json_safe(service(request).stop())

    @app.post("/api/reset", tags=["control"])
    def reset(request: Request) -> dict[str, Any]:
        """Stop and go back to a fresh, idle emulator of the current scenario."""
        return json_safe(service(request).reset())

    @app.get("/api/state", tags=["status"])
    async def state(request: Request) -> dict[str, Any]:
        """t_s, status, reason, satellites (ODS, in R), robots, loop timing."""
        return json_safe(service(request).state())

    @app.post("/api/push", tags=["control"], responses=errors_409)
    async def push(req: PushRequest, request: Request) -> dict[str, Any]:
        """A push through the COM of satellite `satellite` (1-based), force in R."""
        try:
            return service(request).push(req.satellite, req.force_N, req.duration_s)
        except InvalidRequest as err:
            raise _http(422, err) from None
        except RunnerBusy as err:
            raise _http(409, err) from None

    @app.get("/api/metrics", tags=["status"])
    def metrics(request: Request) -> dict[str, Any]:
        """The metrics.json of the current (or last) run."""
        try:
            return json_safe(jsonable_encoder(service(request).metrics()))
        except ImportError as err:  # pragma: no cover
            raise _http(503, err) from None

    @app.get("/api/telemetry", tags=["status"], response_class=PlainTextResponse)
    def telemetry(request: Request, format: Literal["csv"] = "csv"):
        """Telemetry of the current (or last) run as CSV (one row per cycle)."""
        text = service(request).telemetry_csv()
        return PlainTextResponse(
            text, media_type="text/csv",
            headers={"Content-Disposition": "attachment; filename=telemetry.csv"},
        )

    return app
