"""A sensor's stats are one typed record (``SensorStats``): the counters the pipeline keeps,
read by attribute, and the same JSON the stats endpoint has always carried (its keys, in their
order), driven by a real SensorPipeline on physics-true frames."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
from pipeline_helpers import InProcessPool as Pool
from pipeline_helpers import answer, contact_path, make_frames

from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.pipeline.hub import Hub
from tactiled.pipeline.sensor import SensorPipeline
from tactiled.pipeline.sensor_stats import SensorStats
from tactiled.settings import SensorSettings

#: The keys of ``GET /v1/sensors/{name}/stats`` (docs/reference/api.md), in order: a client's
#: contract, so a field renamed or moved in SensorStats fails here.
JSON_KEYS = (
    "sensor", "sensor_id", "url", "connected", "finished", "last_error", "reconnects",
    "disconnects", "source_errors", "frames", "frame_rate_hz", "fit_rate_hz",
    "tracked_rate_hz", "last_frame_age_s", "read_backlog_bytes", "read_backlog_peak_bytes",
    "decoder", "superseded", "fitted", "fits_budget_spent", "learned_state", "published",
    "skipped", "stale_dropped", "reuse_refused", "track", "tracked", "track_resets", "track_skipped",
    "predicted", "relinearized", "relinearize_lost", "drift_followed", "pressed_elsewhere",
    "signal_grown", "hysteresis", "pending", "in_hand", "fit_failed", "fit_errors", "wrong_sensor",
    "bad_shape", "errors", "nonfinite_frames", "in_contact", "waiting", "in_flight",
    "latency_ms", "worker_ms", "worker_restarts", "rate_hz", "recorded", "record_errors",
    "model", "shear",
)


def test_stats_are_a_typed_record_with_the_endpoints_json() -> None:
    pool = Pool()
    p = SensorPipeline(SensorSettings(name="f", url="sim://", noise_sigma=0.0005,
                                      model="cylinder"), pool=pool, hub=Hub())
    fitter = Fitter(pool.sensor, FitOptions(**dict(pool.options)))
    frames = make_frames(contact_path(40), sensor_id=0, tail=5)
    for frame in frames:
        p.on_frame(frame)
        while p._waiting is not None and p._in_flight is None:
            answer(p, fitter, p.take_job())
    st = p.stats()
    assert isinstance(st, SensorStats)
    with np.testing.assert_raises(dataclasses.FrozenInstanceError):
        st.frames = 0  # type: ignore[misc]
    # the counters are the pipeline's and its tracking's, read by attribute
    assert st.frames == len(frames) == p.frames
    assert st.published == p.published and st.fitted == p.fitted >= 1
    assert st.tracked == p.tracking.tracked >= 1  # the held contact was tracked between fits
    assert st.published + st.superseded + st.in_hand == len(frames)  # every frame accounted
    assert st.skipped["no_contact"] >= 60 and st.dropped == 0
    assert st.decoded("no such counter") == 0
    # the JSON: the endpoint's keys in order, every value the attribute's, strict JSON
    out = st.to_json_dict()
    assert tuple(out) == JSON_KEYS
    assert all(out[k] == getattr(st, k) for k in JSON_KEYS)
    json.dumps(out, allow_nan=False)
    out["skipped"]["no_contact"] = -1  # a copy: the record is not changed through its JSON
    assert st.skipped["no_contact"] >= 60
