"""The flat field a daemon learns from its own fits survives a restart: saved per sensor in the
state directory, loaded only by the same sensor through the same sensor model, a corrupt or
foreign file refused cleanly (tactiled/pipeline/learned.py)."""

from __future__ import annotations

import asyncio
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from tactiled.fit.flatfield import FlatField
from tactiled.pipeline import Daemon, learned
from tactiled.sensors import load_description
from tactiled.settings import default_state_dir, load_settings

#: A finger whose tactels depart from the model (5 % gains, 0.1 mm positions), pressed over
#: and over; every contact frame fitted (no tracker, no reuse) so the flat field learns fast.
URL = "sim://?scene=demo&seed=3&gain_error=0.05&position_error=0.1&finger_seed=6"
#: how long a daemon may take to save 60 fits, or its worker to start and answer: seconds on
#: the core; the Python reference (``TACTILED_CORE=python``) warms and fits ten times slower,
#: and a loaded machine slower again
LIMIT_S = 180.0


def _settings(state: Path, **extra: object):
    return load_settings(None, {}, {"sensor[0].url": URL, "sensor[0].track": False,
                                    "sensor[0].reuse_unchanged": False, "fit.workers": 1,
                                    "state.dir": str(state), **extra})


async def _run_until(daemon: Daemon, done, limit_s: float) -> None:
    t0 = time.monotonic()
    while not done():
        assert time.monotonic() - t0 < limit_s, "the daemon did not get there in time"
        await asyncio.sleep(0.05)


async def _worker_flat(daemon: Daemon) -> dict:
    """The flat field the (one) worker's fitter holds, from its health figures.  Asked again
    until the worker is ready (only a ready worker is asked; its warm-up takes seconds, more
    on the Python reference: ``TACTILED_CORE=python``)."""
    t0 = time.monotonic()
    while True:
        worker = daemon.pool.stats()["workers"][0]
        if worker["memory"] is not None:
            flats = worker["memory"]["flat_fields"]
            assert len(flats) == 1
            return next(iter(flats.values()))
        daemon.pool.request_memory()  # a worker asked already is not asked twice
        assert time.monotonic() - t0 < LIMIT_S, "the worker did not answer"
        await asyncio.sleep(0.02)


def _summary(state: dict) -> dict:
    flat = FlatField(8, 8)
    flat.restore(state)
    return flat.summary()


def test_a_restarted_daemon_starts_with_the_flat_field_it_learned(tmp_path: Path, arun) -> None:
    state_dir = tmp_path / "state"
    path = learned.state_path(state_dir, "finger0")

    async def first() -> None:
        daemon = Daemon(_settings(state_dir))
        await daemon.start()
        try:  # saved after each re-solve: the first after 20 fits, then every quarter more
            await _run_until(daemon, lambda: learned.saved_fits(path) >= 60, LIMIT_S)
        finally:
            await daemon.stop()

    arun(first())
    with np.load(path) as data:
        saved = {k: data[k] for k in data.files}
    saved.pop("meta")
    fits = int(saved["fits"])
    assert fits >= 60 and np.any(saved["ata"] != 0.0)

    async def second() -> tuple[dict, dict]:
        # a source that never delivers a frame: nothing new is learned before we look
        daemon = Daemon(_settings(state_dir, **{"sensor[0].url": "sim://?scene=empty&seed=3"}),
                        keep_learned=True)
        await daemon.start()
        try:
            return daemon.stats("finger0")["learned_state"], await _worker_flat(daemon)
        finally:
            await daemon.stop()

    # the sensor model is the same (the URL's finger is the simulator's, not the model's)
    stats, worker = arun(second())
    assert stats == {"loaded_fits": fits, "refused": 0, "refusal": ""}
    expected = _summary(saved)
    assert worker["fits"] == fits and worker["active"] == expected["active"]
    assert worker["gain_rms"] == pytest.approx(expected["gain_rms"], rel=1e-12, abs=1e-15)
    assert worker["shift_rms_um"] == pytest.approx(expected["shift_rms_um"], rel=1e-12, abs=1e-12)


def _fingerprint(name: str | None = None, noise_sigma: float = 0.0005) -> str:
    """The sensor-model fingerprint a pipeline of description ``name`` computes."""
    d = load_description(name)
    return learned.fingerprint(d.sensor_model(noise_sigma), None, d.fingerprint())


def _saved_state(tmp_path: Path, owner: learned.Owner) -> Path:
    flat = FlatField(8, 8)
    flat.fits, flat.gain = 50, np.full((8, 8), 1.02)
    path = learned.state_path(tmp_path, owner.name)
    learned.save(path, owner, flat.state())
    return path


async def _learned_stats(settings) -> dict:
    daemon = Daemon(settings, keep_learned=True)
    await daemon.start()
    try:
        return daemon.stats("finger0")["learned_state"], await _worker_flat(daemon)
    finally:
        await daemon.stop()


@pytest.mark.parametrize("change", ["name", "wire_id", "model", "description"])
def test_a_flat_field_of_another_sensor_or_model_is_refused(tmp_path: Path, arun, change) -> None:
    overrides = {"sensor[0].url": "sim://?scene=empty", "fit.workers": 1, "state.dir": str(tmp_path)}
    if change == "description":  # the file was learned on the paper's finger; this is a pad
        overrides.update({"sensor[0].description": "flat16",
                          "sensor[0].url": "sim://?scene=empty&sensor=flat16"})
    settings = load_settings(None, {}, overrides)
    owner = learned.Owner("finger0", None, _fingerprint())
    other = {"name": replace(owner, name="finger1"), "wire_id": replace(owner, wire_id=7),
             "model": replace(owner, fingerprint=_fingerprint(noise_sigma=0.001)),
             "description": owner}
    path = _saved_state(tmp_path, other[change])
    if change == "name":  # another sensor's file sits under its own name: make it this one's
        path.rename(learned.state_path(tmp_path, "finger0"))
    stats, worker = arun(_learned_stats(settings))
    assert stats["loaded_fits"] is None and stats["refused"] == 1
    assert "learned by another" in stats["refusal"] and "not applied" in stats["refusal"]
    assert worker["fits"] == 0 and worker["gain_rms"] == 0.0


def test_the_right_file_is_applied_and_a_corrupt_one_refused(tmp_path: Path, arun) -> None:
    settings = load_settings(None, {}, {"sensor[0].url": "sim://?scene=empty", "fit.workers": 1,
                                        "state.dir": str(tmp_path)})
    path = _saved_state(tmp_path, learned.Owner("finger0", None, _fingerprint()))
    stats, worker = arun(_learned_stats(settings))
    assert stats["loaded_fits"] == 50 and stats["refused"] == 0
    assert worker["fits"] == 50 and worker["gain_rms"] == pytest.approx(0.02)
    path.write_bytes(path.read_bytes()[:200])  # truncated: a crash mid-copy, a full disk
    stats, worker = arun(_learned_stats(settings))
    assert stats["loaded_fits"] is None and stats["refused"] == 1
    assert "not a learned-state file" in stats["refusal"]
    assert worker["fits"] == 0


def test_the_state_directory_defaults(tmp_path: Path) -> None:
    assert default_state_dir({"STATE_DIRECTORY": "/var/lib/tactiled"}) == Path("/var/lib/tactiled")
    assert default_state_dir({"XDG_STATE_HOME": "/x"}) == Path("/x/tactiled")
    assert default_state_dir({"HOME": "/home/u"}) == Path("/home/u/.local/state/tactiled")
    cfg = tmp_path / "t.toml"
    cfg.write_text('[state]\ndir = "here"\n')
    assert load_settings(cfg).state.directory() == tmp_path / "here"
