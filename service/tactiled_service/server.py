"""The daemon and the web server in one process and one asyncio loop.

:class:`Service` builds the :class:`~tactiled.pipeline.Daemon` from the settings, starts it
(the fit workers are separate processes), and runs uvicorn programmatically on a listening
socket made here; it owns the signals, the graceful stop, sd_notify, and the optional Zenoh
and ROS 2 front ends.
"""
# * The socket is ours (listen_socket) so it carries TCP_USER_TIMEOUT, which accepted sockets
#   inherit: a peer that stops reading (zero window) or vanishes is dropped by the kernel after
#   tcp_user_timeout_s, even after we closed the socket, when close() alone could never finish.
#   A bounded SO_SNDBUF (inherited too) keeps such a peer from soaking up megabytes first.
#   Binding early turns a busy port into a clear error before any worker starts.
# * Signals are ours: uvicorn's handlers are disabled (it would re-raise the signal after
#   shutting down); Service.install_signal_handlers makes SIGTERM and SIGINT start the graceful
#   stop, and a second SIGINT kill the workers and exit at once.
# * Graceful stop (Service.stop, within shutdown_timeout_s): systemd is told STOPPING=1; every
#   stream subscriber gets close code 1001; then, concurrently, uvicorn stops accepting and
#   closes its connections, and the daemon stops reading, lets fits in flight finish, releases
#   the devices and flushes the recordings.
# * sd_notify: READY=1 once the socket is bound and served, WATCHDOG=1 only while the frame
#   counters advance (a stuck pipeline gets the daemon restarted), STATUS= a one-line summary.
# * Zenoh ([zenoh] enabled): tactiled_service.bus, imported only then (the zenoh extra),
#   checked in Service.bind, opened before the sensors start and closed first on the way out
#   (its liveliness token goes at once).
# * ROS 2 ([ros2] enabled): tactiled_service.ros2, on DDS (started here) and/or as a guest of
#   the Zenoh front end on its session (bus.fronts), as [ros2] middleware says; with
#   [record] format "mcap" or "both" an MCAP recorder on the hub, closed after the daemon stops.

from __future__ import annotations

import asyncio
import contextlib
import importlib
import ipaddress
import logging
import os
import signal
import socket
import sys
import time
from collections.abc import Callable, Iterator, Mapping
from types import ModuleType
from typing import Any

import uvicorn

from tactiled import heap
from tactiled.errors import ConfigError
from tactiled.pipeline import Daemon
from tactiled.settings import Settings, ZenohSettings
from tactiled.sources import FrameSource
from tactiled.systemd import Notifier, WatchdogGate, watchdog_interval, watchdog_loop
from tactiled_service.app import Context, build_context, create_app
from tactiled_service.auth import AuthPolicy
from tactiled_service.options import ServiceOptions
from tactiled_service.protocol import http_protocol_class, protocol_class

log = logging.getLogger(__name__)

HEALTH_SAMPLE_S = 1.0  # s between health samples (and STATUS= updates)


def listen_socket(host: str, port: int, tcp_user_timeout_s: float, backlog: int = 128,
                  send_buffer: int = 0) -> socket.socket:
    """A bound, listening, non-blocking TCP socket with ``TCP_USER_TIMEOUT`` (ms) set, and
    ``SO_SNDBUF`` when ``send_buffer`` (bytes) is not 0; accepted sockets inherit both.

    Raises :class:`ConfigError` naming ``server.host`` or ``server.port`` when the address
    cannot be resolved or bound.
    """
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM,
                                   flags=socket.AI_PASSIVE)
    except socket.gaierror as err:
        raise ConfigError(f"server.host: cannot resolve {host!r}: {err.strerror}") from None
    family, type_, proto, _, addr = infos[0]
    sock = socket.socket(family, type_, proto)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        # Inherited by every accepted socket (Linux copies the listener's options).
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_USER_TIMEOUT,
                        max(1, int(tcp_user_timeout_s * 1000)))
        if send_buffer:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, send_buffer)
        sock.bind(addr)
        sock.listen(backlog)
        sock.setblocking(False)
    except OSError as err:
        sock.close()
        raise ConfigError(f"server.port: cannot listen on {format_host(host)}:{port}: "
                          f"{err.strerror or err}") from None
    return sock


def load_bus(settings: ZenohSettings) -> ModuleType:
    """:mod:`tactiled_service.bus`, imported now (only ``[zenoh] enabled`` pays for Zenoh), with
    ``settings`` checked by Zenoh's own parser.  :class:`ConfigError` saying what to install
    when the extra is missing, or naming the key Zenoh refuses."""
    try:
        from tactiled_service import bus
    except ImportError as err:
        raise ConfigError(f"zenoh.enabled: publishing on Zenoh needs the zenoh extra: pip "
                          f"install 'tactiled[zenoh]' ({err})") from None
    bus.session_config(settings)
    return bus


def load_ros2(settings: Settings) -> tuple[ModuleType | None, ModuleType | None]:
    """The ROS 2 node module (``[ros2] enabled``) and the MCAP recorder's (``[record] format``
    "mcap" or "both"), imported now, or None each; :class:`ConfigError` naming the key when
    the ``ros2`` extra is missing."""
    want_node = settings.ros2.enabled
    want_mcap = settings.record.path is not None and settings.record.format != "tact"
    key = "ros2.enabled" if want_node else "record.format"
    try:
        node = importlib.import_module("tactiled_service.ros2.node") if want_node else None
        mcap = (importlib.import_module("tactiled_service.ros2.mcap_file") if want_mcap
                else None)
    except ImportError as err:
        raise ConfigError(f"{key}: ROS 2 messages need the ros2 extra: pip install "
                          f"'tactiled[ros2]' ({err})") from None
    if node is not None and "dds" in settings.ros2.middlewares(settings.zenoh.enabled):
        try:
            importlib.import_module("tactiled_service.ros2.dds")
        except ImportError as err:
            raise ConfigError(f"ros2.middleware: DDS needs Cyclone DDS (the cyclonedds package "
                              f"of the ros2 extra): pip install 'tactiled[ros2]' ({err})") from None
    if node is not None or mcap is not None:
        from tactiled_service.ros2.messages import check_segments
        try:
            check_segments([s.name for s in settings.sensors])
        except ValueError as err:
            raise ConfigError(f"{key}: {err}") from None
    return node, mcap


def format_host(host: str) -> str:
    """``::1`` -> ``[::1]`` (for URLs); names and IPv4 addresses unchanged."""
    return f"[{host}]" if ":" in host and not host.startswith("[") else host


def is_loopback_socket(sock: socket.socket) -> bool:
    """True when ``sock`` is bound to a loopback address."""
    addr = sock.getsockname()[0]
    try:
        return ipaddress.ip_address(addr.split("%", 1)[0]).is_loopback
    except ValueError:
        return False


class _Server(uvicorn.Server):
    """uvicorn without its signal handling (the service owns the signals)."""

    @contextlib.contextmanager
    def capture_signals(self) -> Iterator[None]:
        yield


class Service:
    """The daemon plus its REST/WebSocket server (see the module docstring).

    ``sources`` (tests) replaces the frame sources of the named sensors; ``notifier`` defaults
    to ``Notifier.from_env()`` (a no-op without ``NOTIFY_SOCKET``).  The systemd variables are
    read and removed from the environment here, before any worker process can inherit them.
    """

    def __init__(self, settings: Settings, options: ServiceOptions | None = None, *,
                 sources: Mapping[str, FrameSource] | None = None,
                 notifier: Notifier | None = None) -> None:
        self.settings = settings
        self.options = options or ServiceOptions()
        self.sources = sources
        self.notifier = (notifier if notifier is not None
                         else Notifier.from_env(unset_environment=True))
        self.watchdog_interval = watchdog_interval(unset_environment=True)
        self.sock: socket.socket | None = None
        self.loopback = False  # bound to a loopback address (set by bind)
        self.daemon: Daemon | None = None
        self.ctx: Context | None = None
        self.bus: Any = None  # tactiled_service.bus.Bus when [zenoh] enabled
        self._bus_module: ModuleType | None = None
        self._ros2_modules: tuple[ModuleType | None, ModuleType | None] | None = None
        self.mcap_recorder: Any = None  # tactiled_service.ros2.mcap_file.McapRecorder
        self.ros2_node: Any = None  # tactiled_service.ros2.node.Ros2Node when [ros2] enabled
        self.server: _Server | None = None
        self.host = settings.server.host
        self.port = settings.server.port
        self._serve_task: asyncio.Task[None] | None = None
        self._tasks: list[asyncio.Task[None]] = []
        self._stop_requested = asyncio.Event()
        self._stopped = asyncio.Event()
        self._stopping = False
        self._status = ""
        self._last_status: dict[str, str] = {}

    # -- addresses ------------------------------------------------------------------------------

    @property
    def url(self) -> str:
        """The dashboard's address, ``http://HOST:PORT/`` (the actual port when 0 was asked)."""
        return f"http://{format_host(self.host)}:{self.port}/"

    @property
    def ws_url(self) -> str:
        return f"ws://{format_host(self.host)}:{self.port}/v1/stream"

    # -- starting -------------------------------------------------------------------------------

    def bind(self) -> None:
        """Bind the listening socket and check the security rule (no I/O beyond that).

        Raises :class:`ConfigError`: the address cannot be bound, or it is not loopback and
        no token is configured; or ``[zenoh] enabled`` without the zenoh extra, or with an
        endpoint Zenoh refuses.
        """
        if self.sock is not None:
            return
        if self.settings.zenoh.enabled and self._bus_module is None:
            self._bus_module = load_bus(self.settings.zenoh)
        if self._ros2_modules is None:
            self._ros2_modules = load_ros2(self.settings)
        server = self.settings.server
        sock = listen_socket(server.host, server.port, self.options.tcp_user_timeout_s,
                             send_buffer=self.options.socket_send_buffer)
        loopback = is_loopback_socket(sock)
        if not loopback and not server.token:
            sock.close()
            raise ConfigError(
                f"server.token: required when listening on {server.host!r}, which is not a "
                "loopback address (set TACTILED_TOKEN, --token, or [server] token; or listen "
                "on 127.0.0.1)")
        self.sock = sock
        self.loopback = loopback
        self.port = sock.getsockname()[1]

    async def start(self) -> None:
        """Bind, start the daemon (workers warm) and the server; READY=1 when serving."""
        self.bind()
        assert self.sock is not None
        try:
            self.daemon = Daemon(self.settings, sources=self.sources)
            auth = AuthPolicy(self.settings.server.token, self.loopback,
                              self.options.allowed_origins)
            self.ctx = build_context(self.daemon, self.options, auth)
            node_module = self._ros2_modules[0] if self._ros2_modules else None
            middlewares = self.settings.ros2.middlewares(self.settings.zenoh.enabled)
            if node_module is not None:
                self.ros2_node = node_module.Ros2Node(self.settings, self.daemon,
                                                      self.ctx.health)
                if "dds" in middlewares:
                    self.ros2_node.start_dds()
            if self._bus_module is not None:
                # Before the sensors start: the first estimates already go out, and a session
                # that cannot open at all stops the start before any device is opened.
                self.bus = self._bus_module.Bus(self.settings.zenoh, self.daemon,
                                                self.ctx.encoder, self.ctx.health)
                self.ctx.health.bus = self.bus
                if self.ros2_node is not None and "zenoh" in middlewares:
                    self.bus.fronts.append(self.ros2_node)
                await self.bus.start()
            mcap_module = self._ros2_modules[1] if self._ros2_modules else None
            if mcap_module is not None:
                self.mcap_recorder = mcap_module.McapRecorder(self.settings, self.daemon,
                                                              self.ctx.health)
                self.mcap_recorder.start()
            # Fits carry their contact ellipse, so this process never needs the Hertz code
            # (it imports scipy); messages.display_ellipse loads it lazily only for a
            # fit line without one.
            await self.daemon.start()
            self.ctx.manager.start()
            self.server = _Server(self._uvicorn_config(create_app(self.ctx), self.ctx))
            self._serve_task = asyncio.create_task(self.server.serve(sockets=[self.sock]),
                                                   name="tactiled-uvicorn")
            while not self.server.started:
                if self._serve_task.done():
                    exc = self._serve_task.exception()
                    raise RuntimeError(f"the web server did not start: {exc!r}")
                await asyncio.sleep(0.01)
        except BaseException:
            await self._abort_start()
            raise
        self._tasks.append(asyncio.create_task(self._sample_loop(), name="tactiled-health"))
        if self.watchdog_interval is not None:
            gate = WatchdogGate(self._progress)
            self._tasks.append(asyncio.create_task(
                watchdog_loop(self.notifier, gate, self.watchdog_interval),
                name="tactiled-watchdog"))
        self.notifier.ready()
        self._update_status()
        log.info("serving %s (%s)", self.url, "open: loopback, no token" if auth.open
                 else "token required")

    async def _abort_start(self) -> None:
        if self.bus is not None:
            with contextlib.suppress(Exception):
                await self.bus.stop()
        if self.ros2_node is not None:
            with contextlib.suppress(Exception):
                self.ros2_node.stop()
        if self._serve_task is not None and self.server is not None:
            self.server.should_exit = True
            with contextlib.suppress(BaseException):
                await asyncio.wait_for(self._serve_task, 2.0)
        if self.daemon is not None:
            with contextlib.suppress(Exception):
                await self.daemon.stop(1.0)
        if self.mcap_recorder is not None:
            with contextlib.suppress(Exception):
                await asyncio.to_thread(self.mcap_recorder.stop)
        if self.sock is not None:
            self.sock.close()
        self._stopped.set()

    def _uvicorn_config(self, app: Any, ctx: Context) -> uvicorn.Config:
        o = self.options
        return uvicorn.Config(
            app,
            lifespan="off",
            http=http_protocol_class(o.read_timeout_s, ctx.http),
            ws=protocol_class(o.close_timeout_s),
            ws_max_size=o.max_message_bytes,
            ws_per_message_deflate=False,  # CPU per subscriber and message; and CRIME-like leaks
            ws_ping_interval=20.0,
            ws_ping_timeout=20.0,
            timeout_graceful_shutdown=max(0.5, min(1.5, o.shutdown_timeout_s / 3)),
            timeout_keep_alive=5,
            log_config=None,
            access_log=False,
            server_header=False,
            proxy_headers=False,
        )

    # -- running --------------------------------------------------------------------------------

    def request_stop(self) -> None:
        """Start the graceful stop (what SIGTERM does)."""
        self._stop_requested.set()

    async def wait(self) -> None:
        """Until a stop is requested, or the server task ends on its own."""
        assert self._serve_task is not None
        stop = asyncio.create_task(self._stop_requested.wait())
        try:
            await asyncio.wait({stop, self._serve_task}, return_when=asyncio.FIRST_COMPLETED)
        finally:
            stop.cancel()
            await asyncio.gather(stop, return_exceptions=True)

    def install_signal_handlers(self) -> None:
        """SIGTERM / SIGINT: graceful stop; a second SIGINT: kill the workers, exit now."""
        loop = asyncio.get_running_loop()

        def on_signal(sig: signal.Signals) -> None:
            if self._stop_requested.is_set() and sig == signal.SIGINT:
                self.force_exit(130, "second interrupt: exiting now")
            # an asked-for stop is no fault: INFO (the journal shows systemd's own line); a
            # person at the terminal who pressed Ctrl-C is told so whatever the log level
            log.info("%s: shutting down (interrupt again to force)", sig.name)
            if sig == signal.SIGINT and not log.isEnabledFor(logging.INFO):
                print("tactiled: interrupted: shutting down (Ctrl-C again to force)",
                      file=sys.stderr, flush=True)
            self.request_stop()

        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.add_signal_handler(sig, on_signal, sig)

    def force_exit(self, code: int, why: str) -> None:
        """Kill the fit workers and leave the process at once (no cleanup)."""
        log.error("%s", why)
        if self.daemon is not None:
            for pid in self.daemon.pool.pids():
                if pid:
                    with contextlib.suppress(OSError):
                        os.kill(pid, signal.SIGKILL)
        with contextlib.suppress(Exception):
            import sys

            sys.stdout.flush()
            sys.stderr.flush()
        os._exit(code)

    # -- background -----------------------------------------------------------------------------

    async def _sample_loop(self) -> None:
        assert self.ctx is not None
        while True:
            try:
                self.ctx.health.sample()
                report = self.ctx.health.report()
                self._update_status(report)
                self._log_transitions(report)
            except Exception:  # a health glitch must not stop the sampler
                log.exception("health sample failed")
            await asyncio.sleep(HEALTH_SAMPLE_S)

    def _log_transitions(self, report: dict[str, Any]) -> None:
        """One log line whenever a sensor's status changes (the journal tells the story)."""
        for name, sensor in report["sensors"].items():
            before = self._last_status.get(name)
            quiet_start = before is None and sensor["status"] in ("OK", "WARN")
            if sensor["status"] != before and not quiet_start:
                level = logging.INFO if sensor["status"] == "OK" else logging.WARNING
                log.log(level, "sensor %s: %s -> %s%s", name, before, sensor["status"],
                        f" ({sensor['reason']})" if sensor["reason"] else "")
            self._last_status[name] = sensor["status"]

    def _update_status(self, report: dict[str, Any] | None = None) -> None:
        """STATUS= for systemd, sent when the summary changes."""
        if self.ctx is None or self.daemon is None:
            return
        report = report if report is not None else self.ctx.health.report()
        rate = sum(s["frame_rate_hz"] for s in report["sensors"].values())
        text = (f"{report['status']}: {len(report['sensors'])} sensor(s), {rate:.0f} frames/s, "
                f"{report['subscribers']['count']} subscriber(s), {self.url}")
        if text != self._status:
            self._status = text
            self.notifier.status(text)

    def _progress(self) -> int:
        """Frames read by all sensors so far: the watchdog's evidence of progress."""
        assert self.daemon is not None
        return sum(p.frames for p in self.daemon.sensors.values())

    def settle_heap(self, period_s: float = heap.COLLECT_PERIOD_S) -> None:
        """Freeze the start-up heap, collect every ``period_s`` s, and pin malloc's thresholds
        (:mod:`tactiled.heap`).

        For the process that *is* this service (``serve``, the soak), once started; not done
        by :meth:`start` because a process running many services one after another (the
        tests) would freeze each one's objects for good."""
        self._tasks.append(heap.serving(period_s))

    # -- stopping -------------------------------------------------------------------------------

    async def stop(self) -> None:
        """Graceful stop (idempotent; see the module docstring)."""
        if self._stopping:
            await self._stopped.wait()
            return
        self._stopping = True
        self._stop_requested.set()
        t0 = time.monotonic()
        self.notifier.stopping()
        try:
            for task in self._tasks:
                task.cancel()
            await asyncio.gather(*self._tasks, return_exceptions=True)
            # The Zenoh front end first (alongside the rest): its liveliness token goes at
            # once, so Zenoh peers see the daemon leave before its sensors stop.
            bus_stop = (asyncio.ensure_future(self.bus.stop()) if self.bus is not None
                        else None)
            if self.ros2_node is not None:  # on DDS: its writers go at once too (idempotent)
                self.ros2_node.stop()
            if self.ctx is not None:
                await self.ctx.manager.shutdown(timeout=min(1.0, self.options.close_timeout_s))
            if self.server is not None:
                self.server.should_exit = True
            parts = []
            if self._serve_task is not None:
                parts.append(self._serve_task)
            if bus_stop is not None:
                parts.append(bus_stop)
            if self.daemon is not None:
                stop_timeout = min(self.settings.fit.stop_timeout, 2.0)
                parts.append(asyncio.ensure_future(self.daemon.stop(stop_timeout)))
            results = await asyncio.gather(*parts, return_exceptions=True)
            if self.mcap_recorder is not None:  # after the daemon: it writes what came last
                results.extend(await asyncio.gather(asyncio.to_thread(self.mcap_recorder.stop),
                                                    return_exceptions=True))
            for result in results:
                if isinstance(result, BaseException) and not isinstance(
                        result, asyncio.CancelledError):
                    log.error("during shutdown: %r", result)
        finally:
            if self.sock is not None:
                self.sock.close()
            self._stopped.set()
            log.info("stopped in %.2f s", time.monotonic() - t0)


async def serve(settings: Settings, options: ServiceOptions | None = None, *,
                on_ready: Callable[[Service], None] | None = None,
                install_signals: bool = True) -> int:
    """Run a :class:`Service` until SIGTERM/SIGINT; return the exit code (0: clean stop).

    Raises :class:`ConfigError` for a configuration that cannot run (exit code 2 at the CLI).
    """
    service = Service(settings, options)
    service.bind()  # a clear error before anything starts
    if install_signals:
        service.install_signal_handlers()
    # A stop asked for during start-up (workers warming, up to fit.startup_timeout) aborts it.
    starting = asyncio.create_task(service.start())
    stop = asyncio.create_task(service._stop_requested.wait())
    await asyncio.wait({starting, stop}, return_when=asyncio.FIRST_COMPLETED)
    stop.cancel()
    if not starting.done():
        log.warning("stopped during start-up")
        starting.cancel()
        await asyncio.gather(starting, stop, return_exceptions=True)
        return 0
    await asyncio.gather(stop, return_exceptions=True)
    starting.result()  # re-raises a start-up failure
    service.settle_heap()
    if on_ready is not None:
        on_ready(service)
    await service.wait()
    try:
        await asyncio.wait_for(service.stop(), service.options.shutdown_timeout_s)
    except TimeoutError:
        service.force_exit(1, f"shutdown took longer than {service.options.shutdown_timeout_s:g}"
                              " s: exiting anyway")
    return 0
