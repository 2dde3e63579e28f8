"""Fit worker faults under the real daemon: two fingers streaming over ptys (serial://) at
500 Hz into a pool of two real worker processes, while a worker is SIGKILLed, hangs
(``worker_hooks.hang``), or is given work that makes the fitter raise.

Bars: a lost worker is replaced (ready to fit) within 1 s and the restart is counted in health
(``worker_restarts``); no estimate ever holds NaN/inf (``json.dumps(allow_nan=False)`` on every
one); per sensor the published seqs are strictly increasing (no stale estimate under a newer
seq); every frame is accounted for.

A *frame* that makes the fitter raise does not exist on the wire: counts are uint16, the daemon
drops frames of the wrong shape before the fit (``bad_shape``), and the fitter turns NaN, inf,
saturated or empty frames into a FitResult (tests/stress/test_fitter_never_breaks.py).  So the
hostile frames below check that the worker survives the worst wire frames without an error, and
a fitter that raises is made the only way possible across the process boundary: a runtime
configuration (``noise_sigma = 1e-300``) whose fitter setup fails in the worker, so that every
fit request of that sensor raises inside the worker process.
"""

from __future__ import annotations

import asyncio
import os
import signal
import statistics
import sys
import time
from typing import Any

import numpy as np
import pytest
from rel_helpers import (
    Streamer,
    accounted,
    check_estimates,
    collect,
    figures,
    serial_url,
    wait_for,
    wait_open,
)
from worker_hooks import hang

from tactiled.frames import Frame, encode_frame
from tactiled.pipeline import Daemon
from tactiled.settings import load_settings

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="needs Linux ptys")

FINGERS = ("thumb", "index")
READY_S = 1.0


class Hand:
    """The daemon, two pty fingers streaming, and everything they published."""

    def __init__(self, more_ptys, scene: str = "press", skip: float = 0.0,
                 **overrides: Any) -> None:
        self.devices = [more_ptys(f"tty_{name}") for name in FINGERS]
        settings: dict[str, Any] = {"fit.workers": 2}
        for i, (name, dev) in enumerate(zip(FINGERS, self.devices)):
            settings[f"sensor[{i}].name"] = name
            settings[f"sensor[{i}].url"] = serial_url(dev.path)
            settings[f"sensor[{i}].wire_id"] = i + 1
            settings[f"sensor[{i}].reuse_unchanged"] = False  # every contact frame is fitted
        settings.update(overrides)
        self.daemon = Daemon(load_settings(None, {}, settings))
        self.estimates = collect(self.daemon)
        # The press scene (3 s, looped: press, hold, release, rest) releases often, so fits
        # are outstanding when contact ends (the stale-result path); the demo scene holds long.
        self.streamers = [Streamer(dev, rate_hz=500, scene=scene, seed=i + 1, sensor_id=i + 1)
                          for i, dev in enumerate(self.devices)]
        self.skip = round(skip * 500)

    async def __aenter__(self) -> Hand:
        await self.daemon.start()
        for name in FINGERS:
            await wait_open(self.daemon, name)
        for i, s in enumerate(self.streamers):
            s.sim.skip(self.skip + 300 * i)  # the fingers out of step
            s.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        for s in self.streamers:
            await s.stop()
        await self.daemon.stop()

    @property
    def pool(self):
        return self.daemon.pool

    def fits(self, name: str) -> int:
        return self.daemon.sensors[name].fitted

    async def fitting(self, timeout: float = 10.0, more: int = 5) -> None:
        """Wait until every finger has had ``more`` further fits answered."""
        target = {n: self.fits(n) + more for n in FINGERS}
        await wait_for(lambda: all(self.fits(n) >= target[n] for n in FINGERS), timeout,
                       "fits on every finger")

    def all_ready(self) -> bool:
        return all(w["state"] == "ready" for w in self.pool.stats()["workers"])

    async def all_serving(self) -> None:
        """Wait for more fits on every finger and at least one answered by every worker:
        a worker lost before its first fit is restarted with backoff, by design (crash-loop
        protection), so each fault waits for this before the next."""
        await self.fitting(more=5)
        await wait_for(lambda: all(w["fits"] > 0 for w in self.pool.stats()["workers"]), 10,
                       "both workers serving")

    async def settle(self) -> dict[str, dict]:
        for s in self.streamers:
            await s.stop()
        # Every frame written decoded first: the serial reader thread may still hold the last
        # bytes while the pipeline looks idle (seen once: a stats snapshot one fit short).
        pipes = [self.daemon.sensors[n] for n in FINGERS]
        try:
            await wait_for(lambda: all(p.frames >= s.sent for p, s in zip(pipes, self.streamers)),
                           30, "every frame written decoded")
        except AssertionError as err:  # what each finger's reading holds, to find out why
            raise AssertionError(f"{err}: " + "; ".join(
                f"{n}: sent {s.sent}, dropped {s.dropped}, frames {p.frames}, read_left "
                f"{p.read_left}, decoder {self.daemon.stats(n)['decoder']}"
                for n, p, s in zip(FINGERS, pipes, self.streamers))) from None
        await wait_for(lambda: all(p.settled for p in pipes), 10, "every fit done")
        return {n: self.daemon.stats(n) for n in FINGERS}


def _check(hand: Hand, stats: dict[str, dict]) -> None:
    counts = check_estimates(hand.estimates)
    for name, streamer in zip(FINGERS, hand.streamers):
        st = stats[name]
        assert st["frames"] == accounted(st), st
        assert counts.get(name, 0) == st["published"]
        assert st["decoder"]["crc_errors"] == st["decoder"]["truncated"] == 0
        # The only frames missing are those the test held back on purpose.
        assert streamer.dropped == 0 and st["decoder"]["lost"] == streamer.unsent


def _reasons(workers: dict, reason: str, induced: int) -> int:
    """Check the restarts by reason: exactly ``induced`` of ``reason``, and otherwise only
    "hung" ones (a fit that really ran past fit.timeout: on this shared 2-core machine, a
    heavy fit slowed down by other jobs can); returns how many of those extra ones."""
    by = dict(workers["restarts_by_reason"])
    extra = by.pop("hung", 0) - (induced if reason == "hung" else 0)
    if reason != "hung":
        assert by.pop(reason, 0) == induced, workers["restarts_by_reason"]
    assert not by and extra >= 0, workers["restarts_by_reason"]
    assert workers["restarts"] == induced + extra
    return extra


async def _kills(more_ptys, kills: int) -> dict:
    async with Hand(more_ptys) as hand:
        pool = hand.pool
        await hand.fitting(more=20)
        ready, fit_again = [], []
        for k in range(kills):
            await wait_for(lambda: bool(pool.busy_pids()), 5, "a worker busy fitting")
            victim = pool.busy_pids()[0]
            died = pool.restarts_by_reason.get("died", 0)
            killed_at = time.monotonic()
            os.kill(victim, signal.SIGKILL)
            ready.append(await wait_for(
                lambda: pool.restarts_by_reason.get("died", 0) == died + 1 and hand.all_ready(),
                5, f"kill {k}: replacement ready"))
            assert victim not in pool.pids()
            last = pool.stats()["last_restart"]
            if last["pid"] == victim:  # (unless a slow fit was restarted since: see _reasons)
                assert last["reason"] == "died"
                assert last["ready_s"] is not None and last["ready_s"] < READY_S
            await hand.fitting(more=5)
            fit_again.append(time.monotonic() - killed_at)
            await hand.all_serving()
        stats = await hand.settle()
        workers = pool.stats()
    _check(hand, stats)
    return {"ready": ready, "fit_again": fit_again, "stats": stats, "workers": workers}


@pytest.mark.parametrize("kills", [3, pytest.param(30, marks=pytest.mark.slow)])
def test_sigkilled_worker(more_ptys, arun, kills: int) -> None:
    r = arun(_kills(more_ptys, kills))
    assert max(r["ready"]) < READY_S, r["ready"]
    extra = _reasons(r["workers"], "died", kills)
    for name in FINGERS:  # counted in every sensor's health
        assert r["stats"][name]["worker_restarts"] == r["workers"]["restarts"]
        assert r["stats"][name]["fit_errors"] == 0
    assert sum(r["stats"][n]["fit_failed"] for n in FINGERS) <= kills  # at most the fit held
    figures(f"sigkilled_worker[{kills}]", kills=kills,
            ready_ms_max=round(1e3 * max(r["ready"]), 1),
            ready_ms_median=round(1e3 * statistics.median(r["ready"]), 1),
            both_fingers_fitting_again_ms_max=round(1e3 * max(r["fit_again"]), 1),
            fit_failed=sum(r["stats"][n]["fit_failed"] for n in FINGERS), slow_fits_hung=extra)


async def _hangs(more_ptys, hangs: int, timeout: float) -> dict:
    async with Hand(more_ptys, **{"fit.timeout": timeout}) as hand:
        pool = hand.pool
        await hand.fitting(more=20)
        noticed, ready = [], []
        for k in range(hangs):
            slot = k % pool.size
            t0 = time.monotonic()
            victim = hang(pool, slot, 30.0)
            assert victim is not None
            noticed.append(await wait_for(lambda: victim not in pool.pids(), 5,
                                          f"hang {k} noticed"))
            last = pool.stats()["last_restart"]
            assert last["reason"] == "hung" and last["pid"] == victim
            await wait_for(hand.all_ready, 5, f"hang {k}: replacement ready")
            ready.append(pool.stats()["last_restart"]["ready_s"])
            assert time.monotonic() - t0 < timeout + READY_S + 0.2
            await hand.all_serving()
        stats = await hand.settle()
        workers = pool.stats()
    _check(hand, stats)
    return {"noticed": noticed, "ready": ready, "stats": stats, "workers": workers}


@pytest.mark.parametrize("hangs", [2, pytest.param(10, marks=pytest.mark.slow)])
def test_hung_worker(more_ptys, arun, hookable_workers, hangs: int) -> None:
    timeout = 0.5
    r = arun(_hangs(more_ptys, hangs, timeout))
    # Noticed at the deadline (fit.timeout from when the worker could start on the request,
    # checked every 50 ms), replaced within a second of that.
    assert all(timeout <= t < timeout + 0.25 for t in r["noticed"]), r["noticed"]
    assert max(r["ready"]) < READY_S, r["ready"]
    extra = _reasons(r["workers"], "hung", hangs)
    for name in FINGERS:
        assert r["stats"][name]["worker_restarts"] == r["workers"]["restarts"]
    figures(f"hung_worker[{hangs}]", hangs=hangs, fit_timeout_s=timeout,
            noticed_ms_max=round(1e3 * max(r["noticed"]), 1),
            ready_after_kill_ms_max=round(1e3 * max(r["ready"]), 1),
            fit_failed=sum(r["stats"][n]["fit_failed"] for n in FINGERS), slow_fits_hung=extra)


def _frame(raw: Any, sensor_id: int, seq: int) -> Frame:
    return Frame(seq=seq, device_time_us=seq * 2000, raw=np.asarray(raw, dtype=np.uint16),
                 sensor_id=sensor_id)


async def _send_quietly(hand: Hand, finger: int, raws: list[Any], quiet: float) -> list[int]:
    """Pause finger ``finger``'s stream, send frames of counts ``raws`` (as the next seqs),
    stay quiet for ``quiet`` s (so the last of them is fitted: latest frame wins), resume."""
    s = hand.streamers[finger]
    s.paused = True
    await asyncio.sleep(0.004)
    seqs = []
    for raw in raws:
        seq = s.sim.next_index
        s.sim.skip(1)
        await hand.devices[finger].send(encode_frame(_frame(raw, finger + 1, seq)))
        seqs.append(seq)
        await asyncio.sleep(0.002)
    await asyncio.sleep(quiet)
    s.paused = False
    return seqs


async def _saturated_frames(more_ptys) -> dict:
    # Tracking off on the thumb: with it, the saturated frame (its fit runs into the budget,
    # 0.5 s) would go out after 5 ms with the tracked contact predicted to its time
    # (MAX_WAIT_S), and this test is about the fit's own answer.
    async with Hand(more_ptys, **{"sensor[0].track": False}) as hand:
        pool = hand.pool
        await hand.fitting(more=20)
        # Every tactel at full scale: a "contact" the size of the finger, whose fit used to run
        # for ~9 s (150 ms per evaluation of the model; 27 s before the rule-ladder fix).
        before = pool.restarts
        t0 = time.monotonic()
        (seq,) = await _send_quietly(hand, 0, [np.full((8, 8), 65535)], quiet=0.05)
        await wait_for(lambda: any(e.seq == seq and e.sensor == "thumb" for e in hand.estimates),
                       5, "an estimate of the saturated frame")
        answered = time.monotonic() - t0  # t0: just before the frame was written
        (saturated,) = [e for e in hand.estimates if e.seq == seq and e.sensor == "thumb"]
        await hand.fitting(more=10)
        resumed = time.monotonic() - t0
        # Then a burst of the worst a device can send, back to back (latest frame wins).
        rng = np.random.default_rng(7)
        burst = [np.zeros((8, 8)) + 10001, np.indices((8, 8)).sum(0) % 2 * 65535]
        burst += [rng.integers(0, 65536, (8, 8)) for _ in range(30)]
        await _send_quietly(hand, 0, burst, quiet=0.0)
        await wait_for(hand.all_ready, 5, "workers ready after the burst")
        await hand.fitting(more=10, timeout=15)
        stats = await hand.settle()
        workers = pool.stats()
    _check(hand, stats)
    return {"answered": answered, "saturated": saturated, "resumed": resumed,
            "stats": stats, "workers": workers, "restarts": workers["restarts"] - before}


def test_frame_far_outside_the_model_costs_a_budgeted_fit_not_a_worker(more_ptys,
                                                                       arun) -> None:
    """A frame whose fit would run for seconds (every count at 65535) is stopped by the
    fit's budget (its iterations and work; the time budget, half of ``fit.timeout`` = 1 s,
    behind them): it gets an estimate saying "fit budget exhausted" (not converged, counted
    in ``fits_budget_spent``) well before the deadline, no worker is killed, and both fingers
    go on being fitted; so does a burst of random and saturated frames after it.
    (Before the budget the worker was SIGKILLed as hung at the deadline and replaced: the
    hung-worker path itself is tested by ``test_hung_worker``.)"""
    r = arun(_saturated_frames(more_ptys))
    fit = r["saturated"].fit
    assert r["saturated"].gate == "fit" and fit["contact"] is True
    assert fit["converged"] is False and fit["reasons"]["fit"].startswith("fit budget exhausted"), fit
    assert r["answered"] < 1.0, r["answered"]  # inside fit.timeout: the worker was not killed
    assert r["restarts"] == 0 and r["workers"]["restarts_by_reason"] == {}, r["workers"]
    thumb = r["stats"]["thumb"]
    assert thumb["fit_failed"] == 0 and thumb["fit_errors"] == 0
    assert thumb["fits_budget_spent"] >= 1
    figures("frame_far_outside_the_model", answered_s=round(r["answered"], 3),
            fit_ms=round(fit["fit_ms"], 1), iterations=fit["iterations"],
            fitting_again_s=round(r["resumed"], 3), restarts=r["restarts"])


async def _failing_setup(more_ptys) -> dict:
    async with Hand(more_ptys) as hand:
        await hand.fitting(more=20)
        index = hand.daemon.sensors["index"]
        errors_before = index.fit_errors
        # Settings refuse 1e-300 (it divides by zero in the fitter: bug 2); going past the
        # check on purpose is the simplest way to make every fit of one sensor raise.
        index.configure({"noise_sigma": 1e-300})
        await wait_for(lambda: index.fit_errors >= errors_before + 20, 10, "failing fits")
        thumb_fits = hand.fits("thumb")
        await wait_for(lambda: hand.fits("thumb") >= thumb_fits + 20, 10, "thumb still fitted")
        during = {n: hand.daemon.stats(n) for n in FINGERS}
        hand.daemon.update_config({"sensors": {"index": {"noise_sigma": 0.0005}}})
        errors_after = index.fit_errors
        fitted_after = index.fitted
        await wait_for(lambda: index.fitted >= fitted_after + 20, 10, "index fitted again")
        recovered_errors = index.fit_errors - errors_after
        first_good = min((e.seq for e in hand.estimates if e.sensor == "index"
                          and e.gate == "fit" and e.published_time > 0
                          and e.seq > during["index"]["frames"]), default=None)
        stats = await hand.settle()
        workers = hand.pool.stats()
    _check(hand, stats)
    return {"during": during, "stats": stats, "workers": workers,
            "recovered_errors": recovered_errors, "first_good": first_good}


def test_fitter_that_raises_costs_frames_not_workers(more_ptys, arun) -> None:
    """Every fit request of one finger raises inside the worker (its fitter could not be set
    up): each costs that frame (``fit_errors``), the worker stays, the other finger is served,
    nothing is published for the failed fits, and fitting resumes once the setting is fixed."""
    r = arun(_failing_setup(more_ptys))
    during = r["during"]["index"]
    assert during["fit_errors"] >= 20 and "fit of seq" in during["last_error"]
    assert "building it failed: ZeroDivisionError" in during["last_error"]
    assert r["during"]["thumb"]["fit_errors"] == 0
    assert _reasons(r["workers"], "hung", 0) == r["workers"]["restarts"]  # none died
    assert r["recovered_errors"] <= 1  # at most the fit in flight when the setting changed
    figures("fitter_that_raises", fit_errors=r["stats"]["index"]["fit_errors"],
            worker_restarts=r["workers"]["restarts"],
            thumb_fitted=r["stats"]["thumb"]["fitted"])


async def _glitch_in_contact(more_ptys, frames: int = 1) -> dict:
    async with Hand(more_ptys, scene="demo", skip=1.0) as hand:  # a contact held for 9 s
        pool = hand.pool
        await hand.fitting(more=20)
        assert hand.daemon.stats("thumb")["in_contact"]
        # Frames of zero counts (an ADC glitch) after a short gap, in a held contact.
        await _send_quietly(hand, 0, [np.zeros((8, 8))] * frames, quiet=0.0)
        thumb = hand.fits("thumb")
        await asyncio.sleep(3.0)
        fits = hand.fits("thumb") - thumb
        restarts = dict(pool.restarts_by_reason)
        await hand.settle()
    return {"fits": fits, "restarts": restarts}


#: A frame captured from the soak (3 simulated fingers, demo scene) whose fit in a fresh worker
#: ran past fit.timeout: a barely touching contact (peak 0.0026 strain), warm-started from the
#: previous fit.  In a process of its own the fit takes ~1.1 s, 93 % of it computing quadrature
#: rules for contact sizes the solver visits (disk_rule cache misses); the same fit again: 26 ms.
SLOW_FRAME = [
    0.0010123450905624768, 0.0011920877025738985, 0.0009186844613917437, 0.001143231649189728,
    0.0006850810295519229, 0.0010013822688274953, 0.00029709246901812007, 0.0010034795042898358,
    0.0010597235462345457, 0.0010649189704480706, 0.0024033841754051463, 0.0017129647283126428,
    0.000838369876072396, 0.0005276930409913998, 0.0008821734985700075, 0.0011750714966635139,
    -9.223069590087339e-05, 0.0010522878932316797, 0.0009130600571972724, 0.0014738798856053256,
    0.0005559103908484035, -0.0002434223069589957, 0.0006451382268827208, 0.0009440419447092879,
    0.0005611534795042693, 0.0015116301239275305, 0.0002244995233555894, 0.0018772163965682092,
    0.001864775977121116, 0.001537130600571954, 0.00034718779790276084, 0.001138941849380382,
    -1.768350810297073e-05, -0.0005333174451858958, 0.0006923260247854736, 0.0017572926596758404,
    0.0009509056244042256, 0.0008011916110581026, 0.0014979027645376358, 0.0016003813155385785,
    0.0007933269780743035, 0.0009000953288845927, 0.001983698760724548, 0.0008001906577692557,
    0.0013856530028598588, -0.000650667302192558, 0.0014167778836987513, 0.0011978074356530219,
    0.0016691134413727106, 0.0020581506196377932, 0.0012836987607245133, 0.0014813155386081847,
    0.0007249285033364687, 0.0005048141086749136, 0.0004291706387035133, 0.0012815538608198379,
    0.0014750714966634795, 0.00046668255481409414, 0.0010672545281220562, 0.0003418493803622563,
    0.0007625357483317025, 0.0025519065776930237, 0.0010956148713060305, 0.0011351763584366316]
SLOW_WARM = ("cylinder", (-36.43943259920775, 0.7210672582836019, -2.057600592344896,
                          11.942615097510206, 13.878437314624763))

_FRESH_WORKER_FIT = """
import json, sys, time
import numpy as np
import tactiled.pipeline.preload  # what the forkserver template holds: kernels, start table
from tactiled.sensors.model import NoiseModel, SensorModel
from tactiled.fit.fitter import FitOptions, Fitter
from tactiled.pipeline.sensor import worker_fit_options
strain, warm = json.loads(sys.argv[1])
fitter = Fitter(SensorModel(noise=NoiseModel(sigma=0.0005)), FitOptions(**dict(worker_fit_options(4))))
t = time.perf_counter()
result = fitter.fit(np.array(strain).reshape(8, 8), "auto", warm=(warm[0], tuple(warm[1])))
first = time.perf_counter() - t
t = time.perf_counter()
fitter.fit(np.array(strain).reshape(8, 8), "auto", warm=(warm[0], tuple(warm[1])))
print(json.dumps({"first_s": first, "again_s": time.perf_counter() - t,
                  "iterations": result.iterations, "model": result.model}))
"""


def test_a_fit_in_a_fresh_worker_stays_well_inside_the_deadline() -> None:
    """Was a bug: a fresh worker's first fit spent 1.1 s building quadrature rules for the
    contact sizes it visited (44 workers killed as hung in a 10-minute soak).  Node counts are
    now rounded up to a ladder of cached sizes (physics/strain.py)."""
    import json
    import subprocess

    done = subprocess.run([sys.executable, "-c", _FRESH_WORKER_FIT,
                           json.dumps([SLOW_FRAME, SLOW_WARM])],
                          capture_output=True, text=True, timeout=120, check=True)
    r = json.loads(done.stdout.strip().splitlines()[-1])
    figures("fit_in_a_fresh_worker", **{k: round(v, 3) if isinstance(v, float) else v
                                        for k, v in r.items()})
    assert r["first_s"] < 0.25, r  # a quarter of fit.timeout (1 s); the fit itself is ~30 ms


@pytest.mark.parametrize("gap_frames", [0, 5])
def test_one_glitch_frame_barely_moves_the_baseline(gap_frames: int) -> None:
    """The zeroer's side of the glitch above, without processes: a held contact, a short gap,
    one frame of zero counts (strain -0.5 on every tactel), the contact again."""
    from tactiled.calibration.detection import ContactDetector
    from tactiled.calibration.lut import LookupTable
    from tactiled.calibration.stage import CalibrationStage
    from tactiled.calibration.zeroing import Zeroer
    from tactiled.sensors.model import SensorModel
    from tactiled.sim import FingerSimulator

    sigma = 0.0005
    zeroer = Zeroer((8, 8), detector=ContactDetector(sigma, sensor=SensorModel(),
                                                     false_rate=1e-4, average=2))
    stage = CalibrationStage(LookupTable.linear(8, 8, sensor_id=0), zeroer)
    sim = FingerSimulator(scene="demo", seed=1, rate_hz=500)
    for f in sim.frames(1250):  # 2.5 s: pressed and rolling
        stage.process(f)
    assert zeroer.in_contact
    before = zeroer.baseline.copy()
    sim.skip(gap_frames)
    seq = sim.next_index
    sim.skip(1)
    stage.process(_frame(np.zeros((8, 8)), 0, seq))
    for f in sim.frames(20):
        stage.process(f)
    shift = float(np.abs(zeroer.baseline - before).max())
    figures(f"glitch_baseline_shift[gap {gap_frames}]", shift_strain=round(shift, 5),
            shift_sigmas=round(shift / sigma, 1))
    assert shift < 5 * sigma, f"baseline moved {shift:.4f} strain = {shift / sigma:.0f} sigma"


def test_glitch_in_a_held_contact_does_not_stop_fitting(more_ptys, arun) -> None:
    r = arun(_glitch_in_contact(more_ptys, frames=3))
    figures("glitch_in_held_contact", zero_frames=3, fits_in_3s=r["fits"],
            restarts=r["restarts"])
    assert r["fits"] >= 20 and not r["restarts"].get("hung"), r


async def _bad_sigma_at_start(more_ptys) -> None:
    async with Hand(more_ptys, **{"sensor[1].noise_sigma": 1e-300}):
        raise AssertionError("a daemon started with noise_sigma = 1e-300")


def test_a_noise_sigma_that_would_break_the_fitter_is_refused_at_start(more_ptys,
                                                                       arun) -> None:
    """Bug 2, fixed twice: the setting is range-checked (refused at start, naming the key and
    the range), and a worker whose fitter cannot be built still serves the other sensors
    (tests/pipeline/test_pipeline_workers.py::test_a_fitter_that_cannot_be_built_costs_its_
    fits_not_the_worker, which bypasses the settings)."""
    from tactiled.errors import ConfigError

    with pytest.raises(ConfigError) as caught:
        arun(_bad_sigma_at_start(more_ptys))
    figures("fitter_cannot_be_built_at_start", refused=str(caught.value))
    assert "sensor[1].noise_sigma" in str(caught.value) and "1e-08..0.1" in str(caught.value)
