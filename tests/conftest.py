"""Shared fixtures: synthetic frames, a real pseudo-terminal that can be unplugged, a polling
wait, and a file descriptor leak check.

Helpers are handed out as fixtures (``frame_factory``, ``same_frame``, ``wait_until``,
``open_fd_count``) so test modules need not import this file.  Tests run coroutines with
``asyncio.run`` inside plain test functions (no asyncio plug-in).
"""

from __future__ import annotations

import asyncio
import os
import time
import tty
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from tactiled.frames import Frame


# --------------------------------------------------------------------------------------------
# State


@pytest.fixture(autouse=True)
def _own_state_dir(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every test's daemons keep what they learn (``[state] dir``'s default) in a directory
    of the test's own, never the user's: a flat field one test learned must not change
    another's fits."""
    monkeypatch.delenv("STATE_DIRECTORY", raising=False)
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path_factory.mktemp("xdg-state")))


# --------------------------------------------------------------------------------------------
# Frames


def make_frames(count: int, *, seed: int = 0, start_seq: int = 0, sensor_id: int = 0,
                shape: tuple[int, int] = (8, 8), period_us: int = 1000) -> list[Frame]:
    """``count`` frames with random uint16 counts, consecutive seq and a steady device clock."""
    rng = np.random.default_rng(seed)
    return [
        Frame(
            seq=start_seq + k,
            device_time_us=(start_seq + k) * period_us,
            raw=rng.integers(0, 1 << 16, size=shape, dtype=np.uint16),
            sensor_id=sensor_id,
        )
        for k in range(count)
    ]


def same_frame(a: Frame, b: Frame) -> bool:
    """Equal in everything the wire carries (seq, device time, sensor id, counts)."""
    return (a.seq == b.seq and a.device_time_us == b.device_time_us
            and a.sensor_id == b.sensor_id and a.raw.dtype == b.raw.dtype
            and np.array_equal(a.raw, b.raw))


@pytest.fixture
def frame_factory() -> Callable[..., list[Frame]]:
    """:func:`make_frames`: ``frame_factory(count, seed=0, start_seq=0, ...)``."""
    return make_frames


@pytest.fixture(name="same_frame")
def same_frame_fixture() -> Callable[[Frame, Frame], bool]:
    """:func:`same_frame`: equality of everything the wire carries."""
    return same_frame


# --------------------------------------------------------------------------------------------
# Waiting without long sleeps


async def wait_until(condition: Callable[[], bool], timeout: float,
                     poll: float = 0.002) -> float:
    """Poll ``condition`` every ``poll`` s; return the seconds it took, or fail after
    ``timeout`` s."""
    start = time.monotonic()
    while not condition():
        elapsed = time.monotonic() - start
        if elapsed > timeout:
            pytest.fail(f"condition not met within {timeout} s")
        await asyncio.sleep(poll)
    return time.monotonic() - start


@pytest.fixture(name="wait_until")
def wait_until_fixture() -> Callable[..., object]:
    """:func:`wait_until`: ``await wait_until(condition, timeout_s)`` -> seconds taken."""
    return wait_until


# --------------------------------------------------------------------------------------------
# File descriptors


def open_fd_count() -> int:
    """Number of open file descriptors of this process (Linux ``/proc``)."""
    return len(os.listdir("/proc/self/fd"))


@pytest.fixture(name="open_fd_count")
def open_fd_count_fixture() -> Callable[[], int]:
    """:func:`open_fd_count`."""
    return open_fd_count


@pytest.fixture
def fd_leak_check() -> Iterator[None]:
    """Fail the test if it ends with more open file descriptors than it started with."""
    before = open_fd_count()
    yield
    after = open_fd_count()
    assert after <= before, f"file descriptor leak: {before} open before, {after} after"


# --------------------------------------------------------------------------------------------
# A pseudo-terminal standing in for a USB serial device


class PtyDevice:
    """A real pty whose slave is reachable at a *stable* path (a symlink), like a udev name.

    The test plays the device on the master side: :meth:`write` sends bytes, :meth:`unplug`
    closes the master (the slave reader sees EOF/EIO and the ``/dev/pts/N`` node vanishes) and
    removes the symlink; :meth:`replug` makes a new pty and points the symlink at it.
    """

    def __init__(self, link: Path) -> None:
        self.link = link
        self.master: int | None = None
        self.slave_name = ""
        self.plug()

    @property
    def path(self) -> str:
        """The stable device path to put in a ``serial://`` URL."""
        return str(self.link)

    @property
    def plugged(self) -> bool:
        return self.master is not None

    def plug(self) -> None:
        if self.master is not None:
            raise RuntimeError("pty device already plugged")
        master, slave = os.openpty()
        # Raw mode before anyone opens the slave, so no byte is echoed or translated even
        # before the driver configures the port; the slave fd itself is not kept.
        tty.setraw(slave)
        self.slave_name = os.ttyname(slave)
        os.close(slave)
        # The master must not block the test's event loop if the reader falls behind.
        os.set_blocking(master, False)
        self.master = master
        tmp = self.link.with_name(self.link.name + ".new")
        tmp.unlink(missing_ok=True)
        tmp.symlink_to(self.slave_name)
        tmp.replace(self.link)  # atomic re-point, as udev does

    replug = plug

    def unplug(self) -> None:
        if self.master is None:
            return
        os.close(self.master)
        self.master = None
        self.link.unlink(missing_ok=True)

    def write(self, data: bytes) -> None:
        """Write all of ``data`` to the master (raises BlockingIOError if the pty is full)."""
        if self.master is None:
            raise RuntimeError("pty device is unplugged")
        view = memoryview(data)
        while view:
            sent = os.write(self.master, view)
            view = view[sent:]

    async def send(self, data: bytes, chunk: int = 512) -> None:
        """Write ``data`` in ``chunk``-byte pieces, waiting whenever the pty buffer is full."""
        for start in range(0, len(data), chunk):
            piece = memoryview(data)[start : start + chunk]
            while piece:
                try:
                    sent = os.write(self.master, piece)  # type: ignore[arg-type]
                except BlockingIOError:
                    await asyncio.sleep(0.001)
                    continue
                piece = piece[sent:]
            await asyncio.sleep(0)

    def close(self) -> None:
        self.unplug()


@pytest.fixture
def pty_device(tmp_path: Path) -> Iterator[PtyDevice]:
    """A plugged :class:`PtyDevice` at ``tmp_path/'ttyTACT'``; closed after the test."""
    device = PtyDevice(tmp_path / "ttyTACT")
    try:
        yield device
    finally:
        device.close()


@pytest.fixture
def pty_devices(tmp_path: Path) -> Iterator[Callable[[str], PtyDevice]]:
    """Makes plugged :class:`PtyDevice` s, ``make(name)`` at ``tmp_path/name``; all closed
    after the test."""
    made: list[PtyDevice] = []

    def make(name: str) -> PtyDevice:
        made.append(PtyDevice(tmp_path / name))
        return made[-1]

    try:
        yield make
    finally:
        for device in made:
            device.close()


# --------------------------------------------------------------------------------------------
# One suite, every source that can be made to deliver given frames


class FeedableSource:
    """How to make one kind of frame source deliver given frames.

    ``url_for(frames)`` returns the source URL (preparing files as needed); after the source
    is opened, ``await feed(frames)`` makes the device send them (a no-op for replay, whose
    file already holds them).  ``ends`` says whether ``frames()`` ends by itself.
    """

    def __init__(self, kind: str, tmp_path: Path, device: PtyDevice | None = None) -> None:
        self.kind = kind
        self.tmp_path = tmp_path
        self.device = device
        self.ends = kind == "replay"

    def url_for(self, frames: list[Frame]) -> str:
        from urllib.parse import quote

        if self.kind == "replay":
            from tactiled.io.recording import Recorder

            path = self.tmp_path / "feed.tact"
            path.unlink(missing_ok=True)
            with Recorder(path) as recorder:
                for k, frame in enumerate(frames):
                    recorder.record(frame, host_time=1.0 + 0.001 * k)
            return f"replay://{quote(str(path))}?speed=0"
        assert self.device is not None
        return f"serial://{quote(self.device.path)}"

    async def feed(self, frames: list[Frame]) -> None:
        if self.device is not None:
            from tactiled.frames import encode_frame

            await self.device.send(b"".join(encode_frame(f) for f in frames))


@pytest.fixture(params=["replay", "serial"])
def feedable_source(request: pytest.FixtureRequest, tmp_path: Path) -> FeedableSource:
    """Parametrised over the frame sources that can be fed known frames (the simulator has
    its own scenes, so it is not one of them)."""
    device = request.getfixturevalue("pty_device") if request.param == "serial" else None
    return FeedableSource(request.param, tmp_path, device)


#: Test directories whose tests only compute: no real-time process, port, device or server.
COMPUTE_ONLY = frozenset({"calibration", "docs", "fit", "frames", "house", "io", "native",
                          "physics", "stress"})
#: Modules of the other directories that only compute likewise: frames made and fed in this
#: process (the pipeline driven through its own entry points, its worker's work done here,
#: framers, scenes, message encoders) or commands run to their end on files (``tactiled fit``,
#: ``tactiled bench``'s tables, imports without the optional packages), no clock read as a
#: deadline.
COMPUTE_ONLY_MODULES = frozenset({
    "bench/test_bench_cli.py", "bench/test_runner_scoring.py", "bench/test_shear_bench.py",
    "cli/test_every_command_bad_files.py", "cli/test_fit_cli.py",
    "cli/test_newcomer_papercuts.py", "packaging/test_shipped_dependencies.py",
    "drivers/test_lines_core.py", "drivers/test_torn_units.py",
    "drivers/test_vendor_framers.py",
    "pipeline/test_association.py", "pipeline/test_contact_filter.py",
    "pipeline/test_contact_filter_general.py", "pipeline/test_estimate_records.py",
    "pipeline/test_frame_run.py", "pipeline/test_held_drift.py",
    "pipeline/test_hysteresis_learnt.py", "pipeline/test_kernels.py",
    "pipeline/test_multi_contact.py", "pipeline/test_pipeline_gate.py",
    "pipeline/test_sensor_stats.py", "pipeline/test_several_contacts.py",
    "pipeline/test_signal_refit.py", "pipeline/test_tracked_dispatch.py",
    "pipeline/test_tracked_estimate.py",
    "pipeline/test_tracker_sigmas.py", "pipeline/test_worker_packing.py",
    "reliability/test_decoder_fuzz.py", "reliability/test_golden_truth.py",
    "sensors/test_three_axis.py", "service/test_json_messages.py",
    "service/test_slip_pacing.py",
    "sim/test_hand_scene.py", "sim/test_moving_scene.py", "sim/test_scenes.py",
    "sim/test_simulator.py"})
_TESTS = Path(__file__).resolve().parent


def group_of(rel: str) -> str:
    """The xdist group of the test module at ``rel`` (its path under tests/): ``live``, or
    the module's own for a compute-only one."""
    parts = rel.split("/")
    if len(parts) > 1 and parts[0] in COMPUTE_ONLY or rel in COMPUTE_ONLY_MODULES:
        return rel
    return "live"


@pytest.hookimpl(tryfirst=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log: object) -> object | None:
    """``--dist loadgroup`` (pyproject's addopts) as :func:`_in_groups` means it: each work unit
    is a group of :func:`group_of`, read from the test id's path.  xdist's own loadgroup reads
    the group from a suffix its workers append to each test id, which pytest 9 no longer
    keeps (a node's id is no longer ``_nodeid``): every test was a unit of its own, the live
    ones spread over both workers at once."""
    if config.getoption("dist", "no") != "loadgroup":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class GroupScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return group_of_id(nodeid)

        def schedule(self) -> None:
            # Units in collection order (live first: _in_groups), not by size: the live group
            # goes to a worker that has run nothing yet, never to one a compute-only module
            # has niced.
            reorder = self.config.option.loadscopereorder
            self.config.option.loadscopereorder = False
            try:
                super().schedule()
            finally:
                self.config.option.loadscopereorder = reorder

    return GroupScheduling(config, log)


def group_of_id(nodeid: str) -> str:
    """:func:`group_of` a test id (its path relative to the repository's root)."""
    return group_of(nodeid.split("::", 1)[0].removeprefix("tests/"))


def _in_groups(items: list[pytest.Item]) -> None:
    """For pytest-xdist's ``--dist loadgroup`` (``pytest -n 2``; CI runs the suite serially): every test
    that runs real processes, servers, devices or clocks is in the group ``live``, run in
    collection order on one worker, so no two of them compete for the machine and their
    deadlines mean what they meant in a serial run; a compute-only module's (a module of
    ``COMPUTE_ONLY`` or ``COMPUTE_ONLY_MODULES``) tests are a group
    of their own (its module fixtures set up once), run on the other worker meanwhile, niced
    (``COMPUTE_NICE``: :func:`pytest_runtest_setup`) so the ``live`` tests keep the machine
    first.  The ``live`` group comes first: it is the longest."""
    live, compute = [], []
    for item in items:
        group = group_of(Path(str(item.path)).resolve().relative_to(_TESTS).as_posix())
        item.add_marker(pytest.mark.xdist_group(group))
        (live if group == "live" else compute).append(item)
    items[:] = live + compute


#: The niceness a pytest-xdist worker takes on for a compute-only test: the group ``live`` keeps
#: the machine first (its processes' deadlines), the compute-only modules use what it leaves.
COMPUTE_NICE = 10


def pytest_runtest_setup(item: pytest.Item) -> None:
    group = item.get_closest_marker("xdist_group")
    if (os.environ.get("PYTEST_XDIST_WORKER") and group is not None and group.args
            and group.args[0] != "live" and os.getpriority(os.PRIO_PROCESS, 0) < COMPUTE_NICE):
        os.setpriority(os.PRIO_PROCESS, 0, COMPUTE_NICE)


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Tests marked ``slow`` (long soaks, full benchmarks, fresh environments) run only when
    asked for (``-m slow``, as the marker's description in pyproject.toml says); the short
    version of each is always on.  Under pytest-xdist, the tests are put in groups
    (:func:`_in_groups`) where they are collected: in each worker (whose options xdist has
    reset: ``numprocesses`` is None there, ``PYTEST_XDIST_WORKER`` names it), before xdist
    reads the groups into the test ids it schedules by."""
    if os.environ.get("PYTEST_XDIST_WORKER"):
        _in_groups(items)
    if "slow" in (config.getoption("markexpr") or ""):
        return
    skip = pytest.mark.skip(reason="slow: opt in with -m slow")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)


# -- random lookup-table knots (the calibration tests and the calibration file's) -------------


@pytest.fixture(scope="session")
def random_knots():
    """:func:`random_table_knots`."""
    return random_table_knots


def random_table_knots(rng: np.random.Generator, n: int, knots: int = 6):
    """Random valid knots for ``n`` tactels: counts strictly increasing in 2000..60000, strain
    non-decreasing with some flat runs."""
    counts, strain = [], []
    for _ in range(n):
        k = int(rng.integers(2, knots + 1))
        c = np.sort(rng.choice(np.arange(2000, 60000), k, replace=False)).astype(float)
        c += rng.uniform(0, 0.9, k)  # fractional knots, as the builder writes
        s = np.cumsum(rng.choice([0.0, 1.0], k, p=[0.2, 0.8]) * rng.uniform(0, 0.05, k))
        counts.append(c)
        strain.append(s - 0.01)
    return counts, strain
