"""``GET /metrics`` against a real server, read with prometheus_client's own parser: every
family docs/reference/metrics.md lists is served with the conventions (``tactiled_`` prefix, ``_total``
counters, units in the names), the values agree with the daemon's own counters, the latency
histograms are well formed and count every estimate once, and each process's memory is there.
The token rule is tested with the other endpoints (test_security.py)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from prometheus_client.parser import text_string_to_metric_families
from svc_helpers import http, wait_for

from tactiled_service.metrics import CONTENT_TYPE

ROOT = Path(__file__).resolve().parents[2]


def scrape(server) -> dict:
    r = http(server.url, "GET", "/metrics")
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == CONTENT_TYPE
    return {f.name: f for f in text_string_to_metric_families(r.text)}


def samples(family, **labels) -> list:
    return [s for s in family.samples if all(s.labels.get(k) == v for k, v in labels.items())]


def value(family, name: str, **labels) -> float:
    found = [s.value for s in samples(family, **labels) if s.name == name]
    assert len(found) == 1, (name, labels, family.samples)
    return found[0]


def documented_metrics() -> set[str]:
    """The metric names docs/reference/metrics.md lists in its metrics table."""
    text = (ROOT / "docs" / "reference" / "metrics.md").read_text()
    return set(re.findall(r"^\| `((?:tactiled|process)_[a-z_]+)`", text, re.MULTILINE))


def test_every_documented_family_is_served_and_every_served_one_documented(shared_server):
    wait_for(lambda: "tactiled_fit_latency_seconds" in scrape(shared_server)
             and value(scrape(shared_server)["tactiled_fits"], "tactiled_fits_total",
                       sensor="finger0") > 0, 20, what="a fit counted")
    families = scrape(shared_server)
    served = set()
    for name, f in families.items():
        # The parser names a counter family without its _total; the exposition has it.
        served.add(name + {"counter": "_total", "info": "_info"}.get(f.type, ""))
        assert name.startswith(("tactiled_", "process_")), name
        if f.type == "counter":
            assert all(s.name.endswith(("_total", "_created")) for s in f.samples), name
    docs = documented_metrics()
    assert docs, "docs/reference/metrics.md lists no metric"
    # Gauges with no value to give have no sample (no sensor of this server has a rate_hz;
    # the hysteresis is learnt only after seconds of tracked contact).
    served |= {"tactiled_frame_rate_nominal_hertz", "tactiled_hysteresis_fraction",
               "tactiled_hysteresis_tau_seconds"} & docs
    # process_* are the library's standard process metrics; those it serves are listed too.
    assert served - docs == set(), f"served but not in docs/reference/metrics.md: {sorted(served - docs)}"
    assert docs - served == set(), f"in docs/reference/metrics.md but not served: {sorted(docs - served)}"


def test_values_agree_with_the_daemons_counters(shared_server):
    def snapshot():
        return shared_server.call(lambda: (shared_server.service.ctx.metrics.render().decode(),
                                           shared_server.service.daemon.stats()))

    text, stats = snapshot()  # one loop turn: the two are taken at the same instant
    families = {f.name: f for f in text_string_to_metric_families(text)}
    for name, st in stats["sensors"].items():
        assert value(families["tactiled_frames"], "tactiled_frames_total",
                     sensor=name) == st["frames"]
        assert value(families["tactiled_frames_superseded"],
                     "tactiled_frames_superseded_total", sensor=name) == st["superseded"]
        assert value(families["tactiled_estimates_reused"], "tactiled_estimates_reused_total",
                     sensor=name) == st["skipped"]["unchanged"]
        assert value(families["tactiled_estimates_no_contact"],
                     "tactiled_estimates_no_contact_total",
                     sensor=name) == st["skipped"]["no_contact"]
        assert value(families["tactiled_fits"], "tactiled_fits_total",
                     sensor=name) == st["fitted"]
        # Every published estimate is in exactly one latency histogram (by its gate).
        latency = families["tactiled_estimate_latency_seconds"]
        counted = sum(s.value for s in samples(latency, sensor=name)
                      if s.name == "tactiled_estimate_latency_seconds_count")
        assert counted == st["published"] > 0
        fit = families["tactiled_fit_latency_seconds"]
        assert value(fit, "tactiled_fit_latency_seconds_count", sensor=name) == (
            st["fitted"] - st["fit_errors"])
        assert value(families["tactiled_hysteresis_compensating"],
                     "tactiled_hysteresis_compensating",
                     sensor=name) == float(st["hysteresis"]["compensating"])
    assert value(families["tactiled_worker_fits"], "tactiled_worker_fits_total") == \
        stats["workers"]["fits"]


def test_histograms_are_cumulative_with_an_inf_bucket(shared_server):
    families = scrape(shared_server)
    for name in ("tactiled_estimate_latency_seconds", "tactiled_fit_latency_seconds"):
        f = families[name]
        assert f.type == "histogram"
        series: dict[tuple, list] = {}
        for s in f.samples:
            if s.name == f"{name}_bucket":
                key = tuple(sorted((k, v) for k, v in s.labels.items() if k != "le"))
                series.setdefault(key, []).append((float(s.labels["le"]), s.value))
        assert series
        for key, buckets in series.items():
            bounds = [b for b, _ in buckets]
            counts = [c for _, c in buckets]
            assert bounds == sorted(bounds) and bounds[-1] == float("inf")
            assert counts == sorted(counts), (key, buckets)  # cumulative
            count = value(f, f"{name}_count", **dict(key))
            assert counts[-1] == count


def test_every_process_resident_memory(shared_server):
    families = scrape(shared_server)
    rss = families["tactiled_process_resident_memory_bytes"]
    by_process = {s.labels["process"]: s.value for s in rss.samples}
    workers = shared_server.worker_pids()
    assert set(by_process) == {"daemon"} | {f"fit_worker_{i}" for i in range(len(workers))}
    assert all(v > 10 * 2**20 for v in by_process.values()), by_process  # tens of MB each
    assert families["process_resident_memory_bytes"].samples[0].value > 0


@pytest.mark.parametrize("path", ["/metrics"])
def test_open_on_loopback_and_refuses_a_foreign_host(shared_server, path):
    # Open mode: no token needed on loopback; a non-loopback Host is refused (DNS rebinding).
    assert http(shared_server.url, "GET", path).status_code == 200
    r = http(shared_server.url, "GET", path, headers={"Host": "evil.example"})
    assert r.status_code == 403
