"""FastAPI app: REST API (OpenAPI at /docs), the static page, and the 3D viewer.

The lifespan starts the loop process's supervisor, viser on a loopback port that only this
app can use (app/backend/viewer.py: the viewer is served at /viewer/), and the scene, and
stops all three on shutdown. What may reach the app: app/backend/access.py.
"""

from __future__ import annotations

import asyncio
import logging
import os
import re
import time
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Annotated, Any, Literal

from fastapi import Body, FastAPI, HTTPException, Query, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import (
    FileResponse,
    HTMLResponse,
    JSONResponse,
    PlainTextResponse,
    Response,
    StreamingResponse,
)
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, ConfigDict, Field, StrictInt
from starlette.background import BackgroundTask

from app.backend import docs_ui, manual, openapi
from app.backend.access import (
    AccessError,
    BodyLimit,
    SameOrigin,
    TokenGate,
    allowed_hosts,
    check_token,
    is_loopback,
)
from app.backend.replay import replay_html, replay_title
from app.backend.ring import RingSpaceError
from app.backend.runner import RunnerError
from app.backend.service import (
    MAX_PUSH_DURATION_S,
    MAX_PUSH_FORCE_N,
    MAX_PUSH_TORQUE_NM,
    EmulatorService,
    InvalidRequest,
    RunnerBusy,
    StillStarting,
    StopQueued,
    UnknownScenario,
)
from app.backend.viewer import PATH as VIEWER_PATH
from app.backend.viewer import add_viewer_routes, start_viser
from app.config import MAX_SATELLITES
from app.runs.report import json_safe
from app.runs.store import (
    DEFAULT_KEEP_RUNS,
    DEFAULT_RUNS_DIR,
    BadRecord,
    BadRunName,
    RunNotFound,
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
    """A hand push on one satellite: force in frame R for duration_s, at point_m of the
    satellite (body axes, from its COM; the COM if left out)."""

    model_config = ConfigDict(extra="forbid")

    satellite: StrictInt = Field(ge=1, le=MAX_SATELLITES, description="1-based satellite index",
                                 examples=[1])
    force_N: list[FiniteFloat] = Field(
        min_length=3, max_length=3,
        description=f"force in R (N), magnitude at most {MAX_PUSH_FORCE_N:g} N, and with the "
                    "pushes still under way on the same satellite at most its push limit "
                    "(/api/state push_limits_N: the F/T sensor's range less the mockup's "
                    "weight, bias, noise and the hand; 422 beyond)",
        examples=[[0.0, 20.0, 0.0]],
    )
    duration_s: FiniteFloat = Field(
        gt=0.0, le=MAX_PUSH_DURATION_S,
        description="seconds. On a satellite an arm carries, the velocity change the push "
                    "gives (force_scale |force_N| duration_s / mass), with the pushes still "
                    "under way, is at most its limit (/api/state push_max_dv_mps: what the "
                    "arm can follow), and its course after the push must not leave the "
                    "arm's safety volume or reach sooner, within 60 s (or the run's time "
                    "left), than it did before; 422 beyond",
        examples=[0.3])
    point_m: list[FiniteFloat] | None = Field(
        default=None, min_length=3, max_length=3,
        description="where the hand pushes: a point of the satellite's box in its body axes "
                    "(m, from the COM); off the COM the push also turns it (r x F, scaled "
                    "by [orbit] torque_scale)",
        examples=[[0.1, 0.0, 0.0]],
    )
    torque_Nm: list[FiniteFloat] | None = Field(
        default=None, min_length=3, max_length=3,
        description=f"a twist with the push: torque in the satellite's body axes (N m, about "
                    f"its COM; none if left out), magnitude at most {MAX_PUSH_TORQUE_NM:g} "
                    "N m, and with the twists under way and the force's moment about the "
                    "sensor at most its twist limit (/api/state twist_limits_Nm: the F/T "
                    "sensor's torque range less the weight's moment, bias, noise and the "
                    "hand); scaled by [orbit] torque_scale. On a satellite an arm carries, "
                    "the angular-velocity change it can give (torque_scale (|torque_Nm| + "
                    "|point_m| |force_N|) duration_s / smallest inertia), with the pushes "
                    "under way, is at most /api/state push_max_dw_radps; 422 beyond",
        examples=[[0.0, 0.0, 1.0]],
    )


class ScenarioInfo(BaseModel):
    name: str
    description: str
    settings: dict[str, Any] = Field(
        default_factory=dict, description="what a start without overrides runs with: "
        "altitude_m, velocity_mps (satellite 1), kp_lin, kp_rot, duration_s, mode, and rails "
        "(per robot its rail: robot, axis_W, travel_m, start_m, speed_limit_mps, "
        "accel_limit_mps2, bandwidth_hz, damping_ratio, velocity_feedforward, delay_cycles; "
        "null without one; a start body sets any of them through robots.<i>.rail)")


NO_RUN = "no run to download yet: start one (a reset begins a new run)"
"""The downloads' 404: before the first cycle of the run that is there."""

MAX_MISS_RATIO = 0.01
"""Health turns "degraded" when more of the last 10 s of cycles missed their deadline."""


class Health(BaseModel):
    status: Literal["ok", "degraded"]
    deadline_miss_ratio_10s: float | None = Field(
        description="share of the cycles of the last 10 s that missed their deadline "
        "(null when none ran); above 0.01 the status is 'degraded'")
    viewer: str = Field(description="path of the 3D viewer (viser) on this server")
    loop_alive: bool
    emulator_status: str
    scene_generation: int | None = Field(
        description="generation of the run the 3D scene shows (see /api/state)"
    )
    last_stall_s: float | None = Field(
        default=None, description="how long the loop process's last stall that ended "
        "lasted (s; null if none): it answered again and has control back")


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


class CsvResponse(PlainTextResponse):
    media_type = "text/csv"


class ZipResponse(Response):
    media_type = "application/zip"


def download_name(state: dict, what: str, now_s: float | None = None) -> str:
    """A download's file name: scenario, mode and the UTC minute, then what it is, e.g.
    collision-hil-20261126T0530Z-run.zip (only [A-Za-z0-9._-]: safe in a header and on
    any file system)."""
    stamp = time.strftime("%Y%m%dT%H%MZ", time.gmtime(now_s))
    name = f"{state['scenario']}-{state['mode']}-{stamp}-{what}"
    return re.sub(r"[^A-Za-z0-9._-]", "_", name)


def attachment(filename: str) -> dict[str, str]:
    return {"Content-Disposition": f'attachment; filename="{filename}"'}


def _temporary_file(path: Path, filename: str, headers: dict | None = None) -> FileResponse:
    """A download built into a temporary file: streamed from disk in chunks, then deleted."""
    return FileResponse(path, media_type=ZipResponse.media_type, headers={
        **attachment(filename), **(headers or {})},
        background=BackgroundTask(path.unlink, missing_ok=True))


# --- the app ----------------------------------------------------------------------------


def create_app(
    viser_port: int = 0,
    host: str = "127.0.0.1",
    default_scenario: str | None = None,
    scene_rate_hz: float = 30.0,
    token: str | None = None,
    runs_dir: str | Path | None = DEFAULT_RUNS_DIR,
    keep_runs: int = DEFAULT_KEEP_RUNS,
    max_run_bytes: int | None = None,
    run_plots: bool = True,
) -> FastAPI:
    """The FastAPI app for a server bound to `host`; its lifespan runs viser on loopback
    port `viser_port` (0: any free one). With `token`, every request must carry it; a
    `host` beyond loopback requires one (AccessError). Every run is written to
    `runs_dir` as it goes (app/runs/store.py: the newest `keep_runs`, and at most
    `max_run_bytes`, kept; None: not written; `run_plots` False: their plots not drawn)."""
    if token is not None:
        check_token(token)
    elif not is_loopback(host):
        raise AccessError(f"host {host!r} is not loopback: a token is required")

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        from app.backend.scene import EmulatorScene

        service = await asyncio.to_thread(EmulatorService, default_scenario, runs_dir,
                                          keep_runs, max_run_bytes, run_plots)
        await asyncio.to_thread(service.start_thread)  # the loop process: first snapshot
        try:
            server, app.state.viewer_secret = await asyncio.to_thread(start_viser, viser_port)
        except BaseException:
            service.shutdown()
            raise
        try:
            scene = await asyncio.to_thread(EmulatorScene, server, service, scene_rate_hz)
            if service.recorder is not None:  # each run's replay kept in its folder
                scene.replay.on_finish = service.recorder.save_replay
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
            "VFDM). The 3D view (viser) is served at /viewer/. A server bound beyond "
            "loopback requires its token on every request: Authorization: Bearer <token>."
        ),
        version="0.1.0",
        lifespan=lifespan,
        docs_url=None,  # FastAPI's pages load from a CDN: /docs is app/backend/docs_ui.py
        redoc_url=None,
    )
    openapi.install(app, token_required=token is not None)
    docs_ui.install(app)
    manual.install(app)
    # outermost last: Host/Origin, then the token, then the body's size
    app.add_middleware(BodyLimit)
    if token is not None:
        app.add_middleware(TokenGate, token=token)
    app.add_middleware(SameOrigin, hosts=allowed_hosts(host))
    add_viewer_routes(app)

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
    no_run_404 = {404: {"model": Message, "content": {"application/json": {}}}}

    def the_run(request: Request):
        """The service, when a run is there to download (a cycle of the current run has
        gone: not before the first start, nor right after a reset); else 404."""
        svc = service(request)
        if svc.state()["loop"]["cycles"] == 0:
            raise HTTPException(status_code=404, detail=NO_RUN)
        return svc

    # --- pages --------------------------------------------------------------------

    @app.get("/", include_in_schema=False)
    async def index():
        root = static_dir()
        if root is None:
            return HTMLResponse("<h1>orbit-emulator</h1><p>static/index.html missing; "
                                "see <a href='/docs'>/docs</a>.</p>")
        return FileResponse(root / "index.html")

    @app.get("/favicon.ico", include_in_schema=False)
    async def favicon():
        root = static_dir()
        if root is None or not (root / "favicon.svg").is_file():
            return Response(status_code=404)
        return FileResponse(root / "favicon.svg", media_type="image/svg+xml")

    root = static_dir()
    if root is not None:
        app.mount("/static", StaticFiles(directory=root), name="static")

    # --- API --------------------------------------------------------------------------

    @app.exception_handler(RunnerError)
    async def _loop_down(_request: Request, exc: RunnerError):
        # the loop process is dead, stalled or did not answer: the server itself is fine
        return JSONResponse(status_code=503, content={
            "detail": f"{exc}; POST /api/reset or a start restarts the loop"})

    @app.exception_handler(RingSpaceError)
    async def _no_room(_request: Request, exc: RingSpaceError):
        # a start or reset whose telemetry ring does not fit in /dev/shm (checked again
        # as the ring is made): refused, nothing changed
        return JSONResponse(status_code=422, content={"detail": str(exc)})

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
            "viewer": VIEWER_PATH,
            "loop_alive": alive,
            "emulator_status": svc.runner.status,
            "scene_generation": request.app.state.scene.generation,
            "last_stall_s": (None if svc.runner.last_stall is None
                             else round(svc.runner.last_stall["duration_s"], 3)),
        }

    @app.get("/api/scenarios", response_model=list[ScenarioInfo], tags=["scenarios"])
    async def scenarios():
        return EmulatorService.scenarios()

    queued_202 = {202: {"description": "accepted, not done yet: the state, and in "
                        "`detail` what happens next"}}

    @app.post(
        "/api/scenarios/{name}/start", tags=["scenarios"],
        responses={404: {"model": Message}, **errors_409, **queued_202},
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

        200 only for a run that started (status "running", or "finished" for a run that
        ended before the answer). 404: unknown scenario; 409: one is already running, or
        this start did not start after all (overtaken by a reset or another start, or
        stopped during its start-up; the message says which); 422: invalid overrides (the
        message names the field), or the scenario could not start (e.g. a start pose out
        of reach: the state then has status "error" and the reason); 202: still starting
        after 60 s.
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
        except StillStarting as err:
            return JSONResponse(status_code=202,
                                content=json_safe({**err.state, "detail": str(err)}))

    @app.get("/api/scenarios/{name}/forecast", tags=["scenarios"],
             responses={404: {"model": Message}, 422: {"model": Message}})
    def forecast(name: str, request: Request,
                 mode: Literal["hil", "ideal"] | None = None) -> dict[str, Any]:
        """Before Start: the pre-flight of the scenario as it would start, with the
        restitution's forecast spread for its contact and sensing chain
        (``collision_forecast``: restitution_sd, peak_force_N, noise_force_N,
        peak_to_noise; null without a contact or in ideal mode) and how long it took
        (``wall_s``, a few seconds; cached per configuration and mode, the last 32).

        404: unknown scenario; 422: the pre-flight refuses it (as Start would).
        """
        try:
            return json_safe(service(request).forecast(name, mode=mode))
        except UnknownScenario as err:
            raise _http(404, err) from None
        except InvalidRequest as err:
            raise _http(422, err) from None

    @app.post("/api/stop", tags=["control"], responses=queued_202)
    def stop(request: Request) -> dict[str, Any]:
        """Stop the running scenario (no-op when none runs). 202 while the loop process is
        stalled: the stop is queued and ends the run as soon as the loop runs again."""
        try:
            return json_safe(service(request).stop())
        except StopQueued as err:
            return JSONResponse(status_code=202,
                                content=json_safe({**err.state, "detail": str(err)}))

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
        """A push on satellite `satellite` (1-based), force in R, through its COM or at
        point_m (body axes)."""
        try:
            return service(request).push(req.satellite, req.force_N, req.duration_s,
                                         req.point_m, req.torque_Nm)
        except InvalidRequest as err:
            raise _http(422, err) from None
        except RunnerBusy as err:
            raise _http(409, err) from None

    @app.get("/api/metrics", tags=["status"], responses=no_run_404)
    def metrics(request: Request) -> dict[str, Any]:
        """The metrics.json of the current (or last) run; 404 before its first cycle."""
        svc = the_run(request)
        try:
            return JSONResponse(json_safe(jsonable_encoder(svc.metrics())), headers=attachment(
                download_name(svc.state(), "metrics.json")))
        except ImportError as err:  # pragma: no cover
            raise _http(503, err) from None

    @app.get("/api/telemetry", tags=["status"], response_class=CsvResponse,
             responses=no_run_404)
    def telemetry(request: Request, format: Literal["csv"] = "csv"):
        """Telemetry of the current (or last) run as CSV (one row per cycle); 404 before
        its first cycle."""
        svc = the_run(request)
        return StreamingResponse(
            svc.telemetry_csv(), media_type=CsvResponse.media_type,
            headers=attachment(download_name(svc.state(), "telemetry.csv")))

    @app.get("/api/run.zip", tags=["status"], response_class=ZipResponse,
             responses=no_run_404)
    def run_zip(request: Request):
        """The current (or last) run to take home: telemetry.csv, metrics.json,
        summary.txt, config.json and plots/*.png (the headless run's figures), zipped;
        404 before its first cycle."""
        svc = the_run(request)
        name = download_name(svc.state(), "run.zip")
        return _temporary_file(svc.run_archive(), name)

    @app.get("/api/replay.html", tags=["status"], response_class=HTMLResponse,
             responses=no_run_404)
    def replay(request: Request):
        """The 3D replay of the current (or last) run: one HTML file (viser's viewer with
        the recording inside) that plays in a browser from disk, without this server.
        404 before its first cycle. At most the first 10 minutes of a run are kept."""
        svc = the_run(request)
        recording = svc.exclusive(request.app.state.scene.replay.current)
        if recording is None or recording[0] != svc.state()["generation"]:
            raise HTTPException(status_code=404, detail=NO_RUN)
        generation, data, truncated = recording
        snap = service(request).state()
        title = replay_title(snap["scenario"], snap["mode"], truncated)
        page = service(request).exclusive(lambda: replay_html(data, title))
        return HTMLResponse(page, headers=attachment(download_name(snap, "replay.html")))

    runs_routes(app, service)

    @app.get("/api/bag", tags=["status"], response_class=ZipResponse, responses=no_run_404)
    def bag(request: Request,
            rate_hz: Annotated[float, Query(gt=0.0, le=1000.0, description=(
                "at most this many messages per topic and second of scenario time"))] = 100.0):
        """The current (or last) run as a ROS 2 bag in MCAP storage (bag/metadata.yaml,
        bag/bag.mcap), zipped: joint states, tf, raw F/T, the ODS's input wrench, the
        true contact force and the satellites' twists, in standard messages (Foxglove,
        PlotJuggler, ros2 bag play). A long run's bag is thinned to about 60,000 messages;
        the X-Bag-Rate-Hz header says the rate it was written at."""
        svc = the_run(request)
        name = download_name(svc.state(), "bag.zip")
        path, written_hz = svc.run_bag(rate_hz)
        return _temporary_file(path, name, {"X-Bag-Rate-Hz": f"{written_hz:.6g}"})

    return app


# --- the runs kept on disk (app/runs/store.py) ------------------------------------------

NO_STORE = "this server keeps no runs (started without a runs directory)"
RunId = Annotated[str, Query(description="a run's id (GET /api/runs)",
                             examples=["20261126T052345123Z-collision"])]
FigureName = Annotated[str, Query(description=(
    "which figure (app/runs/plots.py FIGURES): forces, contact_closeup, velocity, "
    "position, tracking_error, ..."), examples=["contact_closeup"])]


def runs_routes(app: FastAPI, service) -> None:
    """GET /api/runs, /api/runs/{id}, /api/runs/{id}/files/{name}, /api/runs/{id}/bag,
    /api/runs/compare and /api/runs/compare/plot; DELETE /api/runs/{id} (a mutating
    request: the token and the same-origin rule as any POST)."""

    def recorder(request: Request):
        rec = service(request).recorder
        if rec is None:
            raise HTTPException(status_code=404, detail=NO_STORE)
        return rec

    def store_call(fn, *args):
        try:
            return fn(*args)
        except (BadRunName, BadRecord) as err:
            raise HTTPException(status_code=422, detail=str(err)) from None
        except RunNotFound as err:
            raise HTTPException(status_code=404, detail=str(err)) from None

    bad = {404: {"model": Message}, 422: {"model": Message}}

    # (declared before /api/runs/{run_id}, which would take "compare" for a run's id)
    @app.get("/api/runs/compare", tags=["runs"], responses=bad)
    def compare_runs(a: RunId, b: RunId, request: Request) -> dict[str, Any]:
        """Two runs compared: the settings that differ (``settings``: [{key, a, b}], by
        dotted key of config.json, its scenario and mode included), the figures either run
        has drawn (``figures``, each to overlay with /api/runs/compare/plot) and every
        figure name (``all_figures``). 422: not a run id; 404: no such run."""
        from app.runs.compare import figure_names, settings_diff
        from app.runs.plots import figures_of

        store = recorder(request).store
        folders = [store_call(store.folder, run_id) for run_id in (a, b)]
        saved = [store_call(store.run, run_id)["config"] or {} for run_id in (a, b)]
        drawn = {f["name"] for folder in folders for f in figures_of(folder)}
        return json_safe({"a": a, "b": b, "settings": settings_diff(*saved),
                          "figures": [n for n in figure_names() if n in drawn],
                          "all_figures": figure_names()})

    @app.get("/api/runs/compare/plot", tags=["runs"], response_class=Response,
             responses={**bad, 200: {"description": "the overlay", "content": {
                 "image/png": {}}}})
    def compare_plot(a: RunId, b: RunId, figure: FigureName, request: Request):
        """Figure ``figure`` of runs ``a`` and ``b`` on the same axes (a solid, b dashed;
        each panel's legend names the runs), drawn from their telemetry.csv (a long run's
        every k-th row: at most 50,000 of each), as a PNG. 422: not a run id, or not a
        figure's name (the message lists them); 404: no such run, or neither run has the
        figure."""
        from app.runs.compare import UnknownFigure, check_figure, compare_png

        rec = recorder(request)
        folders = [store_call(rec.store.folder, run_id) for run_id in (a, b)]
        try:
            check_figure(figure)
        except UnknownFigure as err:
            raise HTTPException(status_code=422, detail=str(err)) from None
        png = rec.in_worker(compare_png, *map(str, folders), figure)
        if png is None:
            raise HTTPException(status_code=404, detail=(
                f"neither run {a!r} nor run {b!r} has a {figure!r} figure"))
        return Response(png, media_type="image/png", headers={"Cache-Control": "no-cache"})

    @app.get("/api/runs", tags=["runs"], responses={404: {"model": Message}})
    def list_runs(request: Request) -> dict[str, Any]:
        """The runs kept on disk, newest first: id, scenario, mode, seed, started_at,
        ended_at, duration_s (simulated), status (running, finished, stopped,
        safety_stop, error, fault; interrupted: its server stopped first), reason and
        the headline figures; with the store's directory and retention."""
        rec = recorder(request)
        return json_safe({**rec.info(), "runs": rec.store.runs()})

    @app.get("/api/runs/{run_id}", tags=["runs"], responses=bad)
    def get_run(run_id: str, request: Request) -> dict[str, Any]:
        """One run: its run.json, its metrics.json (null until it ended), config.json and
        the names of its files. 422: not a run id; 404: no such run."""
        return json_safe(store_call(recorder(request).store.run, run_id))

    @app.get("/api/runs/{run_id}/files/{name}", tags=["runs"], response_class=FileResponse,
             responses={**bad, 200: {"description": "the file", "content": {
                 t: {} for t in ("image/png", "text/csv", "application/json", "text/plain",
                                 "application/octet-stream")}}})
    def get_run_file(run_id: str, name: str, request: Request):
        """A file of a run's folder (telemetry.csv, metrics.json, a plot ...). 422: not a
        run id or not a file name; 404: no such run, or no such file in its folder."""
        path = store_call(recorder(request).store.file, run_id, name)
        return FileResponse(path, headers={"Cache-Control": "no-cache"})

    @app.get("/api/runs/{run_id}/bag", tags=["runs"], response_class=ZipResponse,
             responses=bad)
    def get_run_bag(run_id: str, request: Request,
                    rate_hz: Annotated[float, Query(gt=0.0, le=1000.0, description=(
                        "at most this many messages per topic and second of scenario "
                        "time"))] = 100.0):
        """A run kept on disk as a ROS 2 bag in MCAP storage (bag/metadata.yaml,
        bag/bag.mcap), zipped, built on demand from its telemetry.csv as /api/bag builds
        the current run's (the same topics; a long run's thinned to about 60,000 messages;
        X-Bag-Rate-Hz says the rate written). Built by a worker process into a temporary
        file that is streamed from disk: the web process holds neither the rows nor the
        bag. 422: not a run id; 404: no such run."""
        folder = store_call(recorder(request).store.folder, run_id)
        path, written_hz = service(request).stored_bag(folder, rate_hz)
        return _temporary_file(path, f"{run_id}-bag.zip",
                               {"X-Bag-Rate-Hz": f"{written_hz:.6g}"})

    @app.delete("/api/runs/{run_id}", tags=["runs"],
                responses={**bad, 409: {"model": Message}})
    def delete_run(run_id: str, request: Request) -> dict[str, Any]:
        """Delete a run from the disk. 409: it is being recorded."""
        rec = recorder(request)
        store_call(rec.store.folder, run_id)
        if rec.active_id() == run_id:
            raise HTTPException(status_code=409, detail=(
                f"run {run_id!r} is being recorded; stop it (or start another) first"))
        store_call(rec.store.delete, run_id)
        return {"deleted": run_id}
