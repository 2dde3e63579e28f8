"""A fit worker's memory does not grow with the contacts it meets (docs/performance/reliability.md,
"Soak").  The cause found: the quadrature-rule cache kept a rule for every pair of
node counts a fit visited, so a worker's heap grew for hours as new contact sizes came; now
every rule a process keeps is built by ``warm_rules`` at start and nothing is added later.

Checked in a process (fits of the busy scene keep no new rule) and in a real worker, through
the worker protocol's ``memory`` request: after the warm-up fits, hundreds more fits of new
contacts leave the rule caches exactly as they were and malloc's bytes in use flat.  The
hour-long figures come from the soak (``tactiled_bench.reliability``); the probe
``python -m tactiled_bench.worker_memory`` measures a busy fitter alone."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import numpy as np
from rel_helpers import figures

from tactiled_bench.scenes import busy_scene
from tactiled.sensors.model import NoiseModel, SensorModel
from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.pipeline.sensor import worker_fit_options
from tactiled.heapstats import fitter_cache_figures
from tactiled.pipeline import Daemon
from tactiled.io.recording import Recorder
from tactiled.settings import load_settings
from tactiled.sim import FingerSimulator

CACHE_KEYS = ("cache_rule_u", "cache_rule_s", "cache_disk_rule", "cache_rule_mb")


def busy_frames(n: int, rate_hz: float = 100.0) -> list:
    """``n`` frames of the busy scene (its contact never holds still), ``rate_hz`` apart."""
    sim = FingerSimulator(scene=busy_scene(), seed=4, rate_hz=rate_hz, drift=None)
    return [sim.step() for _ in range(n)]


def test_fits_of_new_contact_sizes_keep_no_new_rule() -> None:
    fitter = Fitter(SensorModel(noise=NoiseModel(sigma=0.0005)),
                    FitOptions(**dict(worker_fit_options(4))))  # the daemon's workers' options
    before = fitter_cache_figures()
    warm, fitted = None, 0
    for tick in busy_frames(600):
        if tick.contact is None:
            warm = None
            continue
        res = fitter.fit(np.array(tick.strain), "auto", warm=warm)
        warm = (res.model, res.params) if res.converged and res.params and res.model else None
        fitted += 1
    after = fitter_cache_figures()
    figures("fits_keep_no_new_rule", fits=fitted, before=before, after=after)
    assert fitted > 400
    assert {k: after[k] for k in CACHE_KEYS} == {k: before[k] for k in CACHE_KEYS}


def test_a_real_workers_heap_stays_flat(tmp_path: Path, arun) -> None:
    path = tmp_path / "busy.tact"
    with Recorder(path, sensor_id=0) as rec:
        for k, tick in enumerate(busy_frames(1500)):
            rec.record(tick.frame(), host_time=1.0 + 0.01 * k)
    overrides = {"sensor[0].url": f"replay://{path}?speed=0", "fit.workers": 1,
                 "sensor[0].reuse_unchanged": False}

    async def ask(pool) -> dict:
        """The worker's answer to a memory request sent now."""
        asked = time.monotonic()
        assert pool.request_memory() == 1
        while True:
            await asyncio.sleep(0.01)
            w = pool.stats()["workers"][0]
            if w["memory_age_s"] is not None and time.monotonic() - w["memory_age_s"] > asked:
                return w["memory"]

    async def main() -> tuple[dict, dict, dict]:
        daemon = Daemon(load_settings(None, {}, overrides), lossless=True)
        await daemon.start()
        pool, pipe = daemon.pool, daemon.sensors["finger0"]
        while pipe.fitted < 150:  # the warm-up: first touches of code, the first contacts
            await asyncio.sleep(0.01)
        first = await ask(pool)
        assert await daemon.wait_finished(120)
        last = await ask(pool)
        stats = daemon.stats("finger0")
        await daemon.stop()
        return first, last, stats

    first, last, stats = arun(main())
    figures("real_worker_heap", fits=(first["fits"], last["fits"]),
            first={k: first[k] for k in (*CACHE_KEYS, "malloc_in_use_mb", "rss_anon_mb")},
            last={k: last[k] for k in (*CACHE_KEYS, "malloc_in_use_mb", "rss_anon_mb")})
    assert last["fits"] - first["fits"] >= 500, (first["fits"], last["fits"])
    assert stats["fit_errors"] == 0 and stats["fit_failed"] == 0
    assert {k: last[k] for k in CACHE_KEYS} == {k: first[k] for k in CACHE_KEYS}
    assert last["malloc_in_use_mb"] - first["malloc_in_use_mb"] < 1.0
