"""``GET /metrics``: the daemon's counters in the Prometheus text format (``prometheus_client``).

:class:`DaemonCollector` counts nothing itself: at scrape time it reads the counters and
latency histograms the pipeline, worker pool, hub and stream manager already keep.  Names follow
the Prometheus conventions (``tactiled_`` prefix, ``_total``, the unit in the name, labels
``sensor``, ``gate``, ``reason``, ``process``); docs/reference/metrics.md lists them all.
"""
# So nothing is counted twice and the frame path is untouched; the histograms are
# tactiled.pipeline.meters.Histogram, filled where the latencies are measured.  Each Metrics has
# a registry of its own, not the library's global one: a process may run several services one
# after another (the tests do), and each must expose only its own daemon.

from __future__ import annotations

import os
from collections.abc import Callable, Iterator

from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, generate_latest
from prometheus_client.core import (
    CounterMetricFamily,
    GaugeMetricFamily,
    HistogramMetricFamily,
    InfoMetricFamily,
    Metric,
)
from prometheus_client.process_collector import ProcessCollector
from prometheus_client.registry import Collector

from tactiled import __version__
from tactiled.heapstats import rss_mb
from tactiled.pipeline import Daemon
from tactiled.pipeline.meters import Histogram
from tactiled.pipeline.sensor_stats import SensorStats
from tactiled_service.health import REJECTED_KEYS, SEVERITY, HealthMonitor
from tactiled_service.inbound import HttpStats
from tactiled_service.stream import StreamManager

#: Content type of the exposition (text format 0.0.4).
CONTENT_TYPE = CONTENT_TYPE_LATEST

#: Per-sensor counters read from ``Daemon.sensor_stats(name)``: metric name (without
#: ``_total``), help text, and how to read the value from the :class:`SensorStats`.
SENSOR_COUNTERS: tuple[tuple[str, str, Callable[[SensorStats], float]], ...] = (
    ("tactiled_frames", "Frames decoded from the sensor's source.",
     lambda st: st.frames),
    ("tactiled_frames_lost", "Frames missing from the sequence (gaps in seq seen by the "
     "decoder).", lambda st: st.decoded("lost")),
    ("tactiled_frames_duplicated", "Frames received twice (repeated seq).",
     lambda st: st.decoded("duplicated")),
    ("tactiled_crc_errors", "Wire chunks whose CRC-32 did not match.",
     lambda st: st.decoded("crc_errors")),
    ("tactiled_chunks_rejected", "Wire chunks the decoder rejected for any reason (CRC, "
     "COBS, length, version, truncated, oversize, a vendor format's parse errors).",
     lambda st: sum(st.decoded(k) for k in REJECTED_KEYS)),
    ("tactiled_frames_dropped", "Decoded frames the pipeline dropped (another sensor's wire "
     "id, wrong shape, a pipeline error).",
     lambda st: st.dropped),
    ("tactiled_fits", "Fits answered by a worker (including those whose fitter raised).",
     lambda st: st.fitted),
    ("tactiled_frames_superseded", "Frames replaced by a newer one while waiting for a fit "
     "(latest frame wins).", lambda st: st.superseded),
    ("tactiled_estimates_reused", "Estimates that repeat the last fit for a frame unchanged "
     "within noise (gate 'unchanged').", lambda st: st.skipped.get("unchanged", 0)),
    ("tactiled_estimates_no_contact", "No-contact estimates published without a fit (gate "
     "'no_contact').", lambda st: st.skipped.get("no_contact", 0)),
    ("tactiled_estimates_published", "Estimates published, every gate.",
     lambda st: st.published),
    ("tactiled_estimates_stale_dropped", "Fit results dropped because a later frame's "
     "estimate was already out.", lambda st: st.stale_dropped),
    ("tactiled_fit_errors", "Fits whose fitter raised (the frame is lost, not the worker).",
     lambda st: st.fit_errors),
    ("tactiled_fits_budget_spent", "Fits their budget stopped short of the least-squares "
     "minimum (not converged: a frame the model cannot explain).",
     lambda st: st.fits_budget_spent),
    ("tactiled_fits_lost", "Fits lost with their worker (died, hung, or stopped).",
     lambda st: st.fit_failed),
    ("tactiled_source_errors", "Failures of the sensor's source (open failed, device lost).",
     lambda st: st.source_errors),
    ("tactiled_source_reconnects", "Times the source came back after being lost.",
     lambda st: st.reconnects),
)


def _histogram(name: str, doc: str, labels: list[str]) -> HistogramMetricFamily:
    return HistogramMetricFamily(name, doc, labels=labels)


def _add_histogram(family: HistogramMetricFamily, values: list[str], hist: Histogram) -> None:
    buckets = [("+Inf" if bound == float("inf") else repr(bound), count)
               for bound, count in hist.cumulative()]
    family.add_metric(values, buckets, hist.sum)


class DaemonCollector(Collector):
    """Reads the daemon's (and the service's) counters when Prometheus scrapes."""

    def __init__(self, daemon: Daemon, manager: StreamManager | None = None,
                 health: HealthMonitor | None = None, http: HttpStats | None = None) -> None:
        self.daemon = daemon
        self.manager = manager
        self.health = health
        self.http = http

    def collect(self) -> Iterator[Metric]:
        daemon = self.daemon
        info = InfoMetricFamily("tactiled_build", "The tactiled release serving.")
        info.add_metric([], {"version": __version__})
        yield info
        yield from self._sensors(daemon)
        yield from self._pool(daemon)
        yield from self._memory(daemon)
        if self.manager is not None:
            yield from self._subscribers(self.manager)
        if self.http is not None:
            yield from self._http(self.http)

    # -- sensors --------------------------------------------------------------------------------

    def _sensors(self, daemon: Daemon) -> Iterator[Metric]:
        names = list(daemon.sensors)
        stats = {name: daemon.sensor_stats(name) for name in names}
        for metric, doc, read in SENSOR_COUNTERS:
            family = CounterMetricFamily(metric, doc, labels=["sensor"])
            for name in names:
                family.add_metric([name], float(read(stats[name])))
            yield family
        connected = GaugeMetricFamily("tactiled_sensor_connected",
                                      "1 while the sensor's source is connected.",
                                      labels=["sensor"])
        backlog = GaugeMetricFamily("tactiled_read_backlog_bytes",
                                    "Bytes read from the device and not yet decoded.",
                                    labels=["sensor"])
        backlog_peak = GaugeMetricFamily("tactiled_read_backlog_peak_bytes",
                                         "The most bytes read and not yet decoded at once, "
                                         "since start.", labels=["sensor"])
        age = GaugeMetricFamily("tactiled_frame_age_seconds",
                                "Time since the sensor's last frame arrived.",
                                labels=["sensor"])
        rate = GaugeMetricFamily("tactiled_frame_rate_hertz",
                                 "Frames received over the last second.", labels=["sensor"])
        nominal = GaugeMetricFamily("tactiled_frame_rate_nominal_hertz",
                                    "The sensor's configured nominal frame rate (rate_hz).",
                                    labels=["sensor"])
        for name in names:
            st = stats[name]
            connected.add_metric([name], 1.0 if st.connected else 0.0)
            backlog.add_metric([name], float(st.read_backlog_bytes))
            backlog_peak.add_metric([name], float(st.read_backlog_peak_bytes))
            if st.last_frame_age_s is not None:
                age.add_metric([name], float(st.last_frame_age_s))
            rate.add_metric([name], float(st.frame_rate_hz))
            if st.rate_hz:
                nominal.add_metric([name], float(st.rate_hz))
        yield from (connected, backlog, backlog_peak, age, rate, nominal)
        yield from self._hysteresis(names, stats)
        latency = _histogram("tactiled_estimate_latency_seconds",
                             "Frame arrival on the host to estimate published, by gate.",
                             ["sensor", "gate"])
        fit = _histogram("tactiled_fit_latency_seconds",
                         "A fit's round trip to its worker process: request sent to answer "
                         "received.", ["sensor"])
        for name in names:
            pipe = daemon.sensors[name]
            for gate, hist in pipe.latency_hist.items():
                _add_histogram(latency, [name, gate], hist)
            _add_histogram(fit, [name], pipe.fit_hist)
        yield latency
        yield fit
        if self.health is not None:
            report = self.health.report()
            status = GaugeMetricFamily("tactiled_sensor_status",
                                       "1 for the sensor's health status (GET /v1/health), 0 "
                                       "for the others.", labels=["sensor", "status"])
            share = GaugeMetricFamily("tactiled_frames_superseded_ratio",
                                      "Share of the last 10 s of frames superseded while "
                                      "waiting for a fit.", labels=["sensor"])
            for name, s in report["sensors"].items():
                for value in SEVERITY:
                    status.add_metric([name, value], 1.0 if s["status"] == value else 0.0)
                if s.get("superseded_share_10s") is not None:
                    share.add_metric([name], float(s["superseded_share_10s"]))
            yield status
            yield share

    @staticmethod
    def _hysteresis(names: list[str], stats: dict[str, SensorStats]) -> Iterator[Metric]:
        fraction = GaugeMetricFamily("tactiled_hysteresis_fraction",
                                     "The rubber's hysteresis fraction the zeroer has learnt "
                                     "(absent before it has learnt any).", labels=["sensor"])
        tau = GaugeMetricFamily("tactiled_hysteresis_tau_seconds",
                                "The time constant of the rubber's hysteresis the zeroer has "
                                "learnt.", labels=["sensor"])
        on = GaugeMetricFamily("tactiled_hysteresis_compensating",
                               "1 while the zeroer takes the learnt hysteresis out of the "
                               "frames.", labels=["sensor"])
        for name in names:
            h = stats[name].hysteresis
            if h is None:
                continue
            if h["fraction"] is not None:
                fraction.add_metric([name], float(h["fraction"]))
                tau.add_metric([name], float(h["tau_s"]))
            on.add_metric([name], 1.0 if h["compensating"] else 0.0)
        yield from (fraction, tau, on)

    # -- the worker pool ------------------------------------------------------------------------

    def _pool(self, daemon: Daemon) -> Iterator[Metric]:
        pool = daemon.pool.stats()
        restarts = CounterMetricFamily("tactiled_worker_restarts",
                                       "Fit workers lost and replaced, by reason (died, hung, "
                                       "startup, protocol).", labels=["reason"])
        for reason in ("died", "hung", "startup", "protocol"):
            restarts.add_metric([reason], float(pool["restarts_by_reason"].get(reason, 0)))
        for reason, n in pool["restarts_by_reason"].items():
            if reason not in ("died", "hung", "startup", "protocol"):
                restarts.add_metric([reason], float(n))
        yield restarts
        yield CounterMetricFamily("tactiled_worker_recycles",
                                  "Fit workers replaced after fit.max_fits_per_worker fits "
                                  "(successor started first; no fit lost).",
                                  value=float(pool.get("recycles", 0)))
        yield CounterMetricFamily("tactiled_worker_deadline_extended",
                                  "Requests given more time because their worker, runnable, "
                                  "was starved of CPU by other processes (not hung).",
                                  value=float(pool.get("deadline_extended", 0)))
        yield CounterMetricFamily("tactiled_worker_fits", "Fits answered by the pool's "
                                  "workers, every sensor.", value=float(pool["fits"]))
        yield GaugeMetricFamily("tactiled_fit_workers", "Fit worker processes configured.",
                                value=float(pool["size"]))
        yield GaugeMetricFamily("tactiled_fit_workers_ready", "Fit workers ready to fit.",
                                value=float(sum(w["state"] == "ready"
                                                for w in pool["workers"])))

    # -- memory ---------------------------------------------------------------------------------

    def _memory(self, daemon: Daemon) -> Iterator[Metric]:
        rss = GaugeMetricFamily("tactiled_process_resident_memory_bytes",
                                "Resident memory of each process of the daemon: the daemon "
                                "itself and every fit worker (by slot).", labels=["process"])
        own = rss_mb(os.getpid())
        if own is not None:
            rss.add_metric(["daemon"], own * 2**20)
        for w in daemon.pool.stats()["workers"]:
            pid = w.get("pid")
            mb = rss_mb(pid) if pid else None
            if mb is not None:
                rss.add_metric([f"fit_worker_{w['slot']}"], mb * 2**20)
        yield rss

    # -- subscribers ----------------------------------------------------------------------------

    def _subscribers(self, manager: StreamManager) -> Iterator[Metric]:
        st = manager.stats()
        yield GaugeMetricFamily("tactiled_subscribers", "WebSocket stream subscribers "
                                "connected.", value=float(st["count"]))
        yield GaugeMetricFamily("tactiled_subscribers_limit", "Most subscribers accepted at "
                                "once (max_subscribers).", value=float(st["limit"]))
        yield CounterMetricFamily("tactiled_subscribers_stalled_closes",
                                  "Subscribers closed (1013) for not reading.",
                                  value=float(st["stalled"]))
        refused = CounterMetricFamily("tactiled_subscribers_refused",
                                      "Stream handshakes refused, by reason.",
                                      labels=["reason"])
        for reason, n in sorted(st["refused"].items()):
            refused.add_metric([reason], float(n))
        yield refused
        yield GaugeMetricFamily("tactiled_subscriber_messages_queued",
                                "Messages waiting in the subscribers' queues.",
                                value=float(sum(c.get("queued", 0) for c in st["clients"])))

    # -- HTTP requests --------------------------------------------------------------------------

    @staticmethod
    def _http(http: HttpStats) -> Iterator[Metric]:
        yield CounterMetricFamily("tactiled_http_client_disconnects",
                                  "HTTP requests whose client went away before sending the "
                                  "whole body.", value=float(http.disconnects))
        refused = CounterMetricFamily("tactiled_http_refused",
                                      "HTTP requests refused for what arrived, by reason "
                                      "(too_large, read_timeout, bad_json).", labels=["reason"])
        for reason, n in http.refused.items():
            refused.add_metric([reason], float(n))
        yield refused


class Metrics:
    """The registry of one service: the daemon's collector and the standard process metrics
    of this process (``process_*``: CPU seconds, resident memory, descriptors, start time)."""

    def __init__(self, daemon: Daemon, manager: StreamManager | None = None,
                 health: HealthMonitor | None = None, http: HttpStats | None = None) -> None:
        self.registry = CollectorRegistry(auto_describe=False)
        self.registry.register(DaemonCollector(daemon, manager, health, http))
        ProcessCollector(registry=self.registry)

    def render(self) -> bytes:
        """The exposition text."""
        return generate_latest(self.registry)
