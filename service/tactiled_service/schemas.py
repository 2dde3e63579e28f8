"""Pydantic schemas of the API: what clients send, what the REST endpoints return.

They document the API (OpenAPI at ``/v1/openapi.json``) and validate requests; responses
are built as plain dicts by the handlers and checked against these on the way out.  Units:
mm, N, degrees, Hz, seconds, milliseconds where the name says ``_ms``.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError
from pydantic.json_schema import SkipJsonSchema

SCHEMA_VERSION = 2  # same as messages.SCHEMA_VERSION (kept import-free for clients)


def format_validation_error(err: ValidationError, prefix: str = "") -> str:
    """One line naming each offending key: ``streams.0: Input should be 'estimates',
    'frames' or 'slip'; max_rate: Input should be greater than 0``."""
    parts = []
    for e in err.errors(include_url=False):
        loc = ".".join(str(p) for p in e.get("loc", ()) if p != "body")
        where = f"{prefix}{loc}" if loc else (prefix.rstrip(".") or "message")
        parts.append(f"{where}: {e.get('msg', 'invalid')}")
    return "; ".join(parts) or "invalid request"


# -- WebSocket: client -> server -----------------------------------------------------------------


class SubscribeRequest(BaseModel):
    """``{"type": "subscribe", "sensors": [...]|null, "streams": [...], "max_rate": Hz|null}``.

    ``sensors`` null (or absent): every sensor.  ``streams``: ``estimates`` (default),
    ``frames``, ``slip`` (a 3-axis array's slip events), any of them.  ``max_rate``: at most
    this many messages per second per sensor and stream (the newest wins); null: every item.
    Slip events are never paced: each one is sent.
    """

    model_config = ConfigDict(extra="forbid")

    type: Literal["subscribe"]
    sensors: list[str] | None = Field(default=None, min_length=1)
    streams: list[Literal["estimates", "frames", "slip"]] = Field(default=["estimates"], min_length=1)
    max_rate: float | None = Field(default=None, gt=0, allow_inf_nan=False, strict=True)


# -- REST responses ------------------------------------------------------------------------------


class ErrorResponse(BaseModel):
    """Every 4xx/5xx answer: ``detail`` says precisely what was wrong."""

    detail: str


class VersionResponse(BaseModel):
    name: str = "tactiled"
    version: str
    api: str = "v1"
    schema_version: int = SCHEMA_VERSION


class Ellipse(BaseModel):
    """The contact ellipse: semi-axes ``a_mm >= b_mm``, major axis at ``theta_deg`` from +x
    toward +y."""

    a_mm: float
    b_mm: float
    theta_deg: float


class LineInfo(BaseModel):
    """A line contact (a cylinder on a flat array, docs/concepts/model.md): its load per length and its
    signed distance from the array's centre along the normal of ``angle_deg``, with 1-sigma
    bounds.  Its total force and its position along the line do not exist."""

    load_n_per_mm: float | None
    offset_mm: float | None
    load_n_per_mm_std: float | None
    offset_mm_std: float | None


class ContactInfo(BaseModel):
    """One contact of an estimate's ``contacts``: the keys of a single contact's estimate
    (the values, ``std``, ``reasons``, ``ellipse``, ``line``, rates, ...) and its id."""

    model_config = ConfigDict(extra="allow")

    contact_id: int = Field(description="stable while the contact is held (docs/reference/api.md)")
    contact: bool
    model: str | None
    label: str | None
    x_mm: float | None
    y_mm: float | None
    force_n: float | None
    r1_mm: float | None
    r2_mm: float | None
    angle_deg: float | None
    std: dict[str, float | None]
    reasons: dict[str, str]


class EstimateMessage(BaseModel):
    """An estimate (REST and WebSocket): the envelope, every key of a ``tactiled fit`` line
    (contact, model, x_mm, y_mm, force_n, r1_mm, r2_mm, angle_deg, rms, std, fit_ms, label,
    converged, iterations, condition, peak, reasons, message), and ``ellipse``."""

    model_config = ConfigDict(extra="allow")

    type: Literal["estimate"]
    v: int
    sensor: str
    sensor_id: int
    seq: int
    device_time_us: int
    host_time: float | None = Field(description="CLOCK_MONOTONIC s when the frame arrived")
    time: float | None = Field(description="Unix time s of publication")
    latency_ms: float | None
    worker_ms: float | None
    gate: Literal["fit", "no_contact", "unchanged"]
    fitted_seq: int | None
    contact: bool
    model: str | None
    x_mm: float | None
    y_mm: float | None
    force_n: float | None
    r1_mm: float | None
    r2_mm: float | None = Field(description="null: infinite (a cylinder)")
    angle_deg: float | None = Field(description="R2 axis from +x toward +y, [0, 180)")
    rms: float | None
    std: dict[str, float | None] = Field(
        description="1-sigma of each value and rate, same keys")
    fit_ms: float | None
    ellipse: Ellipse | None
    line: LineInfo | None = Field(
        default=None, description="a line contact's own quantities (a cylinder on a flat array); "
        "absent otherwise")
    frames_used: int = Field(
        description="frames the estimate rests on (0: no contact; 1: one frame's fit)")
    vx_mm_s: float | None = Field(description="contact centre's rate along x, mm/s")
    vy_mm_s: float | None = Field(description="contact centre's rate along y, mm/s")
    angle_rate_deg_s: float | None = Field(description="rate of angle_deg, deg/s")
    force_rate_n_s: float | None = Field(description="rate of force_n, N/s")
    contact_id: int | None = Field(
        description="the top-level contact's id (the strongest contact); null: no contact")
    contacts: list[ContactInfo] = Field(
        description="every contact on the array, the strongest first (empty: no contact)")


class FrameMessage(BaseModel):
    """A linearised, zeroed strain frame (dimensionless, positive under compression);
    ``strain[m][n]`` is the tactel at x = m dx, y = n dy."""

    model_config = ConfigDict(extra="allow")

    type: Literal["frame"]
    v: int
    sensor: str
    sensor_id: int
    seq: int
    device_time_us: int
    host_time: float | None
    contact: bool
    statistic: float | None
    rows: int
    cols: int
    strain: list[list[float]]


class Calibration(BaseModel):
    id: str = Field(description="'nominal' (the linear table) or 'sha256:<16 hex>' of the file")
    file: str | None
    created: str | None


class ModelErrorInfo(BaseModel):
    strain: float = Field(description="absolute part of the model-error floor, strain")
    relative: float = Field(description="part proportional to the tactel's strain (0.01 = 1 %)")


class ConstantsInfo(BaseModel):
    """The contact model's constants in use for this sensor (docs/concepts/model.md)."""

    depth_x: float = Field(description="impulse response depth along x, mm")
    nu_x: float = Field(description="impulse response ratio along x")
    depth_y: float = Field(description="impulse response depth along y, mm")
    nu_y: float = Field(description="impulse response ratio along y")
    modulus: float = Field(description="rubber modulus E, N/mm^2")
    model_error: ModelErrorInfo
    positions_identified: int = Field(description="tactels whose identified position is used")
    source: str = Field(description="'paper' (docs/concepts/model.md), 'description: <name>' (a sensor "
                        "description's nominal cover) or 'identified: <calibration file>'")
    sigma: dict[str, float | None] = Field(description="1-sigma bound of each identified constant (null: not identified or held)")
    held: dict[str, str] = Field(description="constants held at the paper's value, and why")


class SensorInfo(BaseModel):
    name: str
    sensor_id: int | None
    url: str
    connected: bool
    rows: int
    cols: int
    dx_mm: float
    dy_mm: float
    finger_radius_mm: float | None = Field(description="the surface's radius around y; null: a flat array")
    description: str = Field(description="the sensor description's name (docs/howto/sensors.md)")
    pitch_x_mm: float = Field(description="the description's tactel spacing along x (rows "
                              "index), mm; the same value as dx_mm")
    pitch_y_mm: float = Field(description="the description's tactel spacing along y (columns "
                              "index), mm; the same value as dy_mm")
    surface_radius_mm: float | None = Field(
        description="the description's surface radius around y, mm; null: a flat array (the "
                    "same value as finger_radius_mm)")
    model: str
    calibration: Calibration
    constants: ConstantsInfo


class SensorsResponse(BaseModel):
    sensors: list[SensorInfo]


class TareResponse(BaseModel):
    sensor: str
    status: Literal["scheduled"]
    message: str


class ConfigResponse(BaseModel):
    """The settings changeable at run time (see PATCH)."""

    model_config = ConfigDict(extra="allow")

    sensors: dict[str, dict[str, Any]]
    fit: dict[str, Any]


def _optional_keys(schema: dict[str, Any]) -> None:
    """Document every key as optional without a ``null`` default: a PATCH leaves out what it
    does not change, and ``null`` is not a value of any of them (the daemon answers 422)."""
    schema.pop("required", None)
    for prop in schema.get("properties", {}).values():
        prop.pop("default", None)


# The PATCH body, key by key, as Daemon.update_config checks it (tactiled.settings field
# checks: same bounds), so that a schema-valid value is a value the daemon accepts, and any
# other key is refused (422) rather than ignored.  Sensor names are the running daemon's.


class SensorConfigPatch(BaseModel):
    """The run-time settings of one sensor (``sensors.<name>``)."""

    model_config = ConfigDict(extra="forbid", json_schema_extra=_optional_keys)

    model: Literal["auto", "cylinder", "sphere", "general"] | SkipJsonSchema[None] = None
    window: Annotated[int, Field(ge=2, le=255)] | SkipJsonSchema[None] = Field(
        default=None, description="tactels")
    noise_sigma: Annotated[float, Field(ge=1e-8, le=0.1)] | SkipJsonSchema[None] = Field(
        default=None, description="strain, 1 sigma")
    false_rate: Annotated[float, Field(ge=1e-12, le=0.5)] | SkipJsonSchema[None] = Field(
        default=None, description="false contacts per noise-only frame")
    reuse_unchanged: bool | SkipJsonSchema[None] = None
    unchanged_z: Annotated[float, Field(ge=0.0, le=1e6)] | SkipJsonSchema[None] = Field(
        default=None, description="z-score")
    track: bool | SkipJsonSchema[None] = Field(
        default=None, description="follow the contact through time (tracker)")
    hysteresis: bool | SkipJsonSchema[None] = Field(
        default=None, description="learn the rubber's hysteresis and take it out")


Seconds = Annotated[float, Field(ge=0.05, le=3600.0)]  # settings.MIN/MAX_FIT_TIME_S


class FitConfigPatch(BaseModel):
    """The run-time settings of the fit worker pool (``fit``), seconds."""

    model_config = ConfigDict(extra="forbid", json_schema_extra=_optional_keys)

    timeout: Seconds | SkipJsonSchema[None] = None
    ping_interval: Seconds | SkipJsonSchema[None] = None
    ping_timeout: Seconds | SkipJsonSchema[None] = None


class ConfigPatch(BaseModel):
    """A partial config: ``{"sensors": {"finger0": {"model": "sphere"}}, "fit":
    {"timeout": 0.5}}``.  Keys not given are left alone; all or nothing."""

    model_config = ConfigDict(extra="forbid", json_schema_extra=_optional_keys)

    sensors: dict[str, SensorConfigPatch] | SkipJsonSchema[None] = None
    fit: FitConfigPatch | SkipJsonSchema[None] = None


def inline_json_schema(model: type[BaseModel]) -> dict[str, Any]:
    """``model``'s JSON schema with its ``$defs`` substituted in place: for a schema embedded
    in the OpenAPI document (``openapi_extra``), where ``#/$defs/...`` would not resolve.
    (The models given here are not recursive.)"""
    schema = model.model_json_schema()
    defs = schema.pop("$defs", {})

    def resolve(node: Any) -> Any:
        if isinstance(node, dict):
            ref = node.get("$ref")
            if isinstance(ref, str) and ref.startswith("#/$defs/"):
                return resolve(defs[ref.removeprefix("#/$defs/")])
            return {key: resolve(value) for key, value in node.items()}
        if isinstance(node, list):
            return [resolve(value) for value in node]
        return node

    return resolve(schema)


def config_patch_schema(sensor_names: list[str]) -> dict[str, Any]:
    """The JSON schema of a ``PATCH /v1/config`` body on a daemon with ``sensor_names``:
    :class:`ConfigPatch` with ``sensors`` keyed by those names only (an enum of the names, and
    each one's keys), so a generated request that validates is one the daemon accepts."""
    schema = inline_json_schema(ConfigPatch)
    sensors = schema["properties"]["sensors"]
    one = sensors.pop("additionalProperties")
    sensors["properties"] = {name: one for name in sensor_names}
    sensors["propertyNames"] = {"enum": list(sensor_names)}
    sensors["additionalProperties"] = False
    return schema


Status = Literal["OK", "WARN", "DEGRADED", "STALE", "ERROR"]


class SensorHealth(BaseModel):
    model_config = ConfigDict(extra="allow")

    status: Status
    reason: str = Field(description="why the status is not OK ('' when OK)")
    connected: bool
    frame_rate_hz: float
    fit_rate_hz: float = Field(description="fits the workers returned in the last second "
                               "(frame fits and the tracker's relinearisations)")
    tracked_rate_hz: float = Field(0.0, description="contact frames per second the tracker "
                                   "measured without a fit of their own (last second)")
    frames: int
    crc_errors: int
    rejected_chunks: int
    lost_frames: int
    duplicated_frames: int
    superseded_frames: int
    published: int
    fit_errors: int
    fits_lost: int
    worker_restarts: int
    last_frame_age_s: float | None
    last_estimate_age_s: float | None
    read_backlog_bytes: int = Field(
        description="bytes read from the device and not yet decoded, now")
    read_backlog_peak_bytes: int = Field(description="the most read_backlog_bytes has been")
    rate_hz: float | None = Field(description="nominal frame rate (null: not configured)")
    superseded_share_10s: float | None = Field(
        description="share of the last 10 s of frames superseded while waiting for a fit")
    tracked: int = Field(0, description="contact frames the tracker measured without a fit")
    predicted: int = Field(0, description="contact frames the tracker could only predict")
    track_resets: int = Field(0, description="tracker restarts on a change (a step, a jump)")
    track_skipped: int = Field(0, description="frames with non-finite tactels kept out of "
                                              "the tracked estimate")


class SubscriberHealth(BaseModel):
    model_config = ConfigDict(extra="allow")

    id: int
    peer: str
    connected_s: float
    subscription: dict[str, Any] | None
    sent: int
    queued: int
    dropped: int
    coalesced: int


class SubscribersHealth(BaseModel):
    count: int
    limit: int
    refused: dict[str, int]
    stalled: int
    clients: list[SubscriberHealth]


class ZenohHealth(BaseModel):
    """The Zenoh front end (docs/howto/zenoh.md); the health document's ``zenoh`` is null when
    ``[zenoh] enabled`` is false."""

    model_config = ConfigDict(extra="allow")

    state: Literal["new", "connecting", "open", "closed"]
    mode: str
    prefix: str
    zid: str | None
    peers: int
    routers: int
    published: dict[str, int] = Field(description="puts handed to Zenoh, by kind "
                                                  "(estimate, frame, health)")
    dropped: int = Field(description="items dropped because the publishing thread fell "
                                     "queue_size behind (oldest first)")
    queued: int
    queue_size: int
    put_errors: int
    put_ms: dict[str, float | None]
    queries: int
    query_errors: int
    last_error: str


class HealthResponse(BaseModel):
    model_config = ConfigDict(extra="allow")

    status: Status
    version: str
    state: str
    uptime_s: float | None
    sensors: dict[str, SensorHealth]
    workers: dict[str, Any]
    process: dict[str, Any] = Field(description="the daemon's pid and resident memory (MB)")
    subscribers: SubscribersHealth
    zenoh: ZenohHealth | None = None
