"""A sensor's counters and rates as one typed record: :class:`SensorStats`.

The service (metrics, health) reads it by attribute; :meth:`SensorStats.to_json_dict` is the
one place it becomes the JSON of ``GET /v1/sensors/{name}/stats`` and ``tactiled status``
(same keys, same order).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from tactiled.pipeline.sensor import SensorPipeline

#: A window mean's summary (:meth:`tactiled.pipeline.meters.WindowMean.summary`), in ms.
Summary = dict[str, float | None]


@dataclass(slots=True, frozen=True)
class SensorStats:
    """One sensor's counters since start and its rates now (Hz; ages in s; times in ms).

    ``decoder`` holds the framer's counters (``crc_errors``, ``lost``, ``duplicated``...: a
    framer's own set), ``skipped`` the estimates published without a fit by gate
    (``no_contact``, ``unchanged``), ``learned_state`` the learned flat field's file
    (``loaded_fits``, ``refused``, ``refusal``).
    """

    sensor: str
    sensor_id: int | None
    url: str
    connected: bool
    finished: bool
    last_error: str
    reconnects: int
    disconnects: int
    source_errors: int
    frames: int
    frame_rate_hz: float
    fit_rate_hz: float
    tracked_rate_hz: float
    last_frame_age_s: float | None
    #: bytes read from the device and not yet decoded: now, and the most at once
    read_backlog_bytes: int
    read_backlog_peak_bytes: int
    decoder: dict[str, Any]
    superseded: int
    fitted: int
    fits_budget_spent: int
    learned_state: dict[str, Any]
    published: int
    skipped: dict[str, int]
    stale_dropped: int
    reuse_refused: int
    track: bool
    tracked: int
    track_resets: int
    track_skipped: int
    predicted: int
    relinearized: int
    relinearize_lost: int
    drift_followed: int
    pressed_elsewhere: int
    signal_grown: int
    hysteresis: dict[str, Any] | None
    pending: int
    #: frames received and neither answered nor counted yet (waiting for a fit)
    in_hand: int
    fit_failed: int
    fit_errors: int
    wrong_sensor: int
    bad_shape: int
    errors: int
    nonfinite_frames: int
    in_contact: bool
    waiting: bool
    in_flight: bool
    latency_ms: Summary
    worker_ms: Summary
    worker_restarts: int
    rate_hz: float | None
    recorded: int
    record_errors: int
    model: str
    shear: dict[str, Any] | None

    @classmethod
    def of(cls, pipe: SensorPipeline) -> SensorStats:
        """The stats of ``pipe`` now."""
        now = time.monotonic()
        src = pipe.source.status()
        zeroer = pipe.stage.zeroer if pipe.stage is not None else None
        tracking = pipe.tracking
        return cls(
            sensor=pipe.name,
            sensor_id=pipe.sensor_id,
            url=src.url,
            connected=bool(src.connected),
            finished=pipe.finished,
            last_error=pipe.last_error or src.last_error,
            reconnects=src.reconnects,
            disconnects=src.disconnects,
            source_errors=pipe.source_errors,
            frames=pipe.frames,
            frame_rate_hz=pipe.frame_rate.rate(now),
            fit_rate_hz=pipe.fit_rate.rate(now),
            tracked_rate_hz=pipe.tracked_rate.rate(now),
            last_frame_age_s=None if pipe.last_frame_at is None else now - pipe.last_frame_at,
            read_backlog_bytes=pipe.source.read_backlog_now,
            read_backlog_peak_bytes=pipe.source.read_backlog,
            decoder=dict(src.decoder),
            superseded=pipe.superseded,
            fitted=pipe.fitted,
            fits_budget_spent=pipe.fits_budget_spent,
            learned_state=pipe.learned.summary(),
            published=pipe.published,
            skipped=dict(pipe.skipped),
            stale_dropped=pipe.stale_dropped,
            reuse_refused=pipe.reuse_refused,
            track=pipe.settings.track,
            tracked=tracking.tracked,
            track_resets=tracking.tracker.resets,
            track_skipped=tracking.tracker.skipped,
            predicted=tracking.predicted,
            relinearized=tracking.relinearized,
            relinearize_lost=pipe.relinearize_lost,
            drift_followed=tracking.drift_followed,
            pressed_elsewhere=tracking.pressed_elsewhere,
            signal_grown=tracking.signal_grown,
            hysteresis=None if zeroer is None else zeroer.hysteresis_summary(),
            pending=len(tracking.pending),
            in_hand=(len(tracking.pending) if pipe.settings.track
                     else int(pipe._waiting is not None) + int(pipe._in_flight is not None)),
            fit_failed=pipe.fit_failed,
            fit_errors=pipe.fit_errors,
            wrong_sensor=pipe.wrong_sensor,
            bad_shape=pipe.bad_shape,
            errors=pipe.errors,
            nonfinite_frames=0 if zeroer is None else zeroer.nonfinite_frames,
            in_contact=bool(zeroer is not None and zeroer.in_contact),
            waiting=pipe._waiting is not None,
            in_flight=pipe._in_flight is not None,
            latency_ms=pipe.latency_ms.summary(now),
            worker_ms=pipe.worker_ms.summary(now),
            worker_restarts=pipe.pool.restarts,
            rate_hz=pipe.settings.rate_hz,
            recorded=0 if pipe._recorder is None else pipe._recorder.frames_written,
            record_errors=pipe.record_errors,
            model=pipe.model,
            shear=None if pipe.shear is None else pipe.shear.stats(),
        )

    def decoded(self, key: str) -> int:
        """The framer's counter ``key`` (0 when this framer keeps none of that name)."""
        return int(self.decoder.get(key, 0))

    @property
    def dropped(self) -> int:
        """Decoded frames the pipeline dropped: another sensor's wire id, a wrong shape, a
        pipeline error."""
        return self.wrong_sensor + self.bad_shape + self.errors

    def to_json_dict(self) -> dict[str, Any]:
        """The JSON of the stats endpoint: every field by name, nested dicts copied."""
        out: dict[str, Any] = {}
        for f in _FIELDS:
            value = getattr(self, f)
            out[f] = dict(value) if isinstance(value, dict) else value
        return out


_FIELDS = tuple(f.name for f in fields(SensorStats))
