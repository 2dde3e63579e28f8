"""The FastAPI app: REST under ``/v1``, the stream at ``/v1/stream``, the dashboard at ``/``.

Every handler is ``async def`` so it runs on the loop that runs the pipeline (the daemon's
objects are not thread-safe).  Errors are ``{"detail": "<precise message>"}``: 404 for an
unknown sensor, 400/415/422 for a malformed request (the message starts with the offending
key), 408/413 for a body too slow or too large, 401/403 for credentials; never a 5xx for
anything a client sent.  Bodies are read and decoded by :mod:`tactiled_service.inbound`.
"""

from __future__ import annotations

import hashlib
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fastapi import Depends, FastAPI, HTTPException, Request
from fastapi.exception_handlers import http_exception_handler
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, Response
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import Match, WebSocketRoute

from tactiled import __version__
from tactiled.calibration.identified import constants_report
from tactiled.errors import ConfigError
from tactiled.pipeline import Daemon, UnknownSensorError
from tactiled.settings import Settings
from tactiled_service import dashboard
from tactiled_service.auth import AuthPolicy, Cors, Denial, HostGuard
from tactiled_service.health import HealthMonitor
from tactiled_service.inbound import (
    BadJson,
    ClientGone,
    HttpStats,
    decode_json,
    encodable,
    read_body,
)
from tactiled_service.json_messages import Encoder
from tactiled_service.metrics import CONTENT_TYPE as METRICS_CONTENT_TYPE
from tactiled_service.metrics import Metrics
from tactiled_service.options import ServiceOptions
from tactiled_service.schemas import (
    ConfigResponse,
    ErrorResponse,
    EstimateMessage,
    FrameMessage,
    HealthResponse,
    SensorsResponse,
    TareResponse,
    VersionResponse,
    config_patch_schema,
)
from tactiled_service.stream import StreamEndpoint, StreamManager

log = logging.getLogger(__name__)


@dataclass
class Context:
    """Everything the handlers share (one per server)."""

    daemon: Daemon
    settings: Settings
    options: ServiceOptions
    auth: AuthPolicy
    encoder: Encoder
    manager: StreamManager
    health: HealthMonitor
    calibrations: dict[str, dict[str, Any]]
    metrics: Metrics
    http: HttpStats


def _calibration(path: str | None, table: Any) -> dict[str, Any]:
    """``{"id", "file", "created"}``: the id is a digest of the file, so two hosts can tell
    whether they run the same calibration."""
    if path is None or table is None:
        return {"id": "nominal", "file": None, "created": None}
    try:
        digest = hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]
        cal_id = f"sha256:{digest}"
    except OSError:
        cal_id = "unreadable"
    return {"id": cal_id, "file": str(path), "created": getattr(table, "created", None)}


def build_context(daemon: Daemon, options: ServiceOptions, auth: AuthPolicy) -> Context:
    """Wire the service's parts around ``daemon`` (no I/O but reading calibration files)."""
    physics = {}
    calibrations = {}
    for name, pipe in daemon.sensors.items():
        model = pipe.sensor_model
        physics[name] = (model.geometry.finger_radius, model.material.compliance)
        calibrations[name] = _calibration(pipe.settings.calibration, pipe.table)
    encoder = Encoder(physics)
    manager = StreamManager(daemon, options, auth, encoder)
    health = HealthMonitor(daemon, manager, options)
    http = HttpStats()
    return Context(daemon, daemon.settings, options, auth, encoder, manager, health,
                   calibrations, Metrics(daemon, manager, health, http), http)


def _raise(denial: Denial | None) -> None:
    if denial is not None:
        raise HTTPException(denial.status, denial.message, dict(denial.headers) or None)


#: Largest PATCH body accepted, bytes (a config patch is a few hundred).
MAX_BODY = 64 * 1024

ERRORS: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorResponse} for code in (400, 401, 403, 404, 415, 422)}


def path_methods(app: FastAPI, scope: dict[str, Any]) -> set[str]:
    """Every method some route serves at the request's path (empty: no such path)."""
    allowed: set[str] = set()
    for route in app.router.routes:
        methods = getattr(route, "methods", None)
        if methods and route.matches(scope)[0] != Match.NONE:
            allowed |= methods
    return allowed


def create_app(ctx: Context) -> FastAPI:
    """The ASGI app for ``ctx``."""
    app = FastAPI(title="tactiled", version=__version__,
                  description="Tactile curvature sensing daemon: REST and WebSocket API "
                              "(docs/reference/api.md).",
                  openapi_url="/v1/openapi.json", docs_url=None, redoc_url=None)
    app.state.ctx = ctx
    auth = ctx.auth

    def read_access(request: Request) -> None:
        _raise(auth.check_read(request.scope))

    def control_access(request: Request) -> None:
        _raise(auth.check_control(request.scope))

    def sensor(name: str) -> str:
        if name not in ctx.daemon.sensors:
            raise HTTPException(404, f"unknown sensor {name!r}; known: "
                                     f"{', '.join(ctx.daemon.sensors)}")
        return name

    # -- errors ---------------------------------------------------------------------------------

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        parts = []
        for e in exc.errors():
            loc = ".".join(str(p) for p in e.get("loc", ()))
            parts.append(f"{loc}: {e.get('msg', 'invalid')}")
        return JSONResponse({"detail": encodable("; ".join(parts) or "invalid request")},
                            status_code=422)

    @app.exception_handler(StarletteHTTPException)
    async def _http_error(request: Request, exc: StarletteHTTPException) -> Response:
        if exc.status_code == 405:
            # Starlette's Allow names the methods of the first route of the path only, and
            # /v1/config has one route per method: RFC 9110 wants all the path's methods.
            allowed = path_methods(app, request.scope)
            exc.headers = {**(exc.headers or {}), "Allow": ", ".join(sorted(allowed))}
        if isinstance(exc.detail, str):
            exc.detail = encodable(exc.detail)  # whatever a message echoes, it encodes
        return await http_exception_handler(request, exc)

    @app.exception_handler(ClientGone)
    async def _client_gone(request: Request, exc: ClientGone) -> Response:
        # Counted and logged by read_body; nobody is left to read this.
        return Response(status_code=400)

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
        log.exception("%s %s failed", request.method, request.url.path)
        return JSONResponse({"detail": f"internal error: {type(exc).__name__}"},
                            status_code=500)

    app.add_middleware(Cors, auth=auth, methods=lambda scope: path_methods(app, scope))
    app.add_middleware(HostGuard, auth=auth)  # added last: runs first

    # -- REST -----------------------------------------------------------------------------------

    @app.get("/v1/version", response_model=VersionResponse, tags=["service"])
    async def version() -> dict[str, Any]:
        """Release and API version."""
        return VersionResponse(version=__version__).model_dump()

    @app.get("/v1/health", response_model=HealthResponse, tags=["service"])
    async def health() -> dict[str, Any]:
        """Overall and per-sensor status (OK, WARN, STALE, ERROR) with rates and counters."""
        return ctx.health.report()

    @app.get("/metrics", response_class=Response, tags=["service"],
             dependencies=[Depends(read_access)],
             responses={**ERRORS, 200: {"description": "Prometheus text format 0.0.4",
                                        "content": {"text/plain": {"schema": {
                                            "type": "string"}}}}})
    async def metrics() -> Response:
        """Counters, gauges and latency histograms in the Prometheus text format
        (docs/reference/metrics.md lists them); the same credentials as the other data endpoints."""
        return Response(ctx.metrics.render(), media_type=METRICS_CONTENT_TYPE)

    @app.get("/v1/sensors", response_model=SensorsResponse, responses=ERRORS,
             dependencies=[Depends(read_access)], tags=["sensors"])
    async def sensors() -> dict[str, Any]:
        """Every sensor with its geometry (mm) and calibration."""
        out = []
        for name, pipe in ctx.daemon.sensors.items():
            g = pipe.sensor_model.geometry
            status = pipe.source.status()
            out.append({
                "name": name, "sensor_id": pipe.sensor_id, "url": status.url,
                "connected": bool(status.connected), "rows": g.rows, "cols": g.cols,
                "dx_mm": g.dx, "dy_mm": g.dy,
                "finger_radius_mm": None if g.flat else g.finger_radius,
                "description": pipe.description.name,
                # the description's own keys (docs/howto/sensors.md), what the dashboard lays out by
                "pitch_x_mm": pipe.description.pitch_x_mm,
                "pitch_y_mm": pipe.description.pitch_y_mm,
                "surface_radius_mm": (None if pipe.description.flat
                                      else pipe.description.surface_radius_mm),
                "model": pipe.model, "calibration": ctx.calibrations[name],
                "constants": constants_report(pipe.sensor_model,
                                              pipe.calibration.model if pipe.calibration else None,
                                              pipe.settings.calibration, pipe.description.name),
            })
        return {"sensors": out}

    @app.get("/v1/sensors/{name}/estimate", response_model=EstimateMessage,
             responses={**ERRORS, 503: {"model": ErrorResponse}},
             dependencies=[Depends(read_access)], tags=["sensors"])
    async def estimate(name: str = Depends(sensor)) -> Any:
        """The latest estimate of sensor ``name`` (the stream's estimate message)."""
        est = ctx.daemon.hub.latest_estimate(name)
        if est is None:
            raise HTTPException(503, f"no estimate published yet for sensor {name!r}",
                                {"Retry-After": "1"})
        return JSONResponse(ctx.encoder.message(est))

    @app.get("/v1/sensors/{name}/frame", response_model=FrameMessage,
             responses={**ERRORS, 503: {"model": ErrorResponse}},
             dependencies=[Depends(read_access)], tags=["sensors"])
    async def frame(name: str = Depends(sensor)) -> Any:
        """The latest linearised, zeroed strain frame of sensor ``name``."""
        fr = ctx.daemon.hub.latest_frame(name)
        if fr is None:
            raise HTTPException(503, f"no frame received yet from sensor {name!r}",
                                {"Retry-After": "1"})
        return JSONResponse(ctx.encoder.message(fr))

    @app.post("/v1/sensors/{name}/tare", response_model=TareResponse, responses=ERRORS,
              dependencies=[Depends(control_access)], tags=["control"])
    async def tare(name: str = Depends(sensor)) -> dict[str, Any]:
        """Re-zero sensor ``name`` on its next frame (nothing may touch it then)."""
        try:
            ctx.daemon.tare(name)
        except UnknownSensorError as err:  # removed since the check: cannot happen today
            raise HTTPException(404, str(err)) from None
        return {"sensor": name, "status": "scheduled",
                "message": "the sensor re-zeroes on its next frame; nothing may touch it"}

    @app.get("/v1/config", response_model=ConfigResponse, responses=ERRORS,
             dependencies=[Depends(read_access)], tags=["control"])
    async def get_config() -> dict[str, Any]:
        """Thresholds and model choice, as PATCH accepts them."""
        return ctx.daemon.get_config()

    patch_schema = config_patch_schema(list(ctx.daemon.sensors))

    @app.patch("/v1/config", response_model=ConfigResponse,
               responses={**ERRORS, 408: {"model": ErrorResponse},
                          413: {"model": ErrorResponse}},
               dependencies=[Depends(control_access)], tags=["control"],
               openapi_extra={"requestBody": {"required": True, "content": {
                   "application/json": {"schema": patch_schema},
                   "application/merge-patch+json": {"schema": patch_schema}}}})
    async def patch_config(request: Request) -> dict[str, Any]:
        """Change thresholds / model choice at run time, all or nothing; 422 names the key."""
        ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
        if ctype not in ("application/json", "application/merge-patch+json"):
            raise HTTPException(415, "Content-Type must be application/json, got "
                                     f"{ctype or 'none'!r}")
        raw = await read_body(request, MAX_BODY, ctx.options.read_timeout_s, ctx.http)
        try:
            patch = decode_json(raw, "body", integral_floats=True)
        except BadJson as err:
            ctx.http.refused["bad_json"] += 1
            raise HTTPException(400, str(err)) from None
        if not isinstance(patch, dict):
            raise HTTPException(422, "body: expected a JSON object like {\"sensors\": "
                                     "{\"<name>\": {\"model\": \"sphere\"}}}, got "
                                     f"{type(patch).__name__}")
        try:
            return ctx.daemon.update_config(patch)
        except ConfigError as err:
            raise HTTPException(422, str(err)) from None
        except (TypeError, ValueError, ArithmeticError) as err:  # not foreseen by the checks
            raise HTTPException(422, f"config: {err}") from None

    # -- stream and dashboard -------------------------------------------------------------------

    app.router.routes.append(WebSocketRoute("/v1/stream", StreamEndpoint(lambda: ctx.manager),
                                            name="stream"))
    dashboard.mount(app, auth)
    return app
