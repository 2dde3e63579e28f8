"""The ROS 2 front end: every sensor's topics over DDS and/or rmw_zenoh (docs/howto/ros2.md).

With ``[ros2] enabled`` the daemon is a ROS 2 node (default ``/tactiled/tactiled``) with no ROS
installation and no bridge, on DDS (:mod:`.dds`, Cyclone DDS) and/or Zenoh (:mod:`.rmw`), as
``[ros2] middleware`` says.  Read-only: per sensor wrench, contact, contacts, markers and
strain (and a 3-axis array's taxels) topics, and ``/diagnostics``.  Each message is built once, on a sender thread of its own,
and the same bytes go to every middleware (an estimate's, to the MCAP recorder too).
"""
# Middlewares: DDS lays topics out as ROS 2's DDS middlewares do (rt/<topic>,
# pkg::msg::dds_::Type_); Zenoh uses the daemon's session with the key expressions, liveliness
# tokens and attachments of [ros2] distro's rmw_zenoh (so ros2 node list and ros2 topic list
# show the node there too).
# Topics per sensor (messages: .messages):
# * <namespace>/<sensor>/wrench (geometry_msgs/msg/WrenchStamped), .../contact
#   (tactiled_msgs/msg/Contact, the strongest contact), .../contacts
#   (tactiled_msgs/msg/ContactArray, every contact), .../markers
#   (visualization_msgs/msg/MarkerArray, every contact drawn): one each per estimate;
# * .../strain (sensor_msgs/msg/Image, 32FC1): zeroed frames, at most [zenoh] frame_rate_hz
#   per second per sensor (0: none); a 3-axis array's .../taxels (sensor_msgs/msg/Image, 32FC3:
#   its zeroed readings x, y, z, as the MCAP recording's) goes with the same frames;
# * /diagnostics (diagnostic_msgs/msg/DiagnosticArray): the health, once a second.
# header.stamp is the frame's time (tactiled.clock).  Nothing is subscribed to.  On Zenoh the
# node is a guest of tactiled_service.bus.Bus (bus.fronts): declared once the session is open,
# undeclared (tokens first) when it closes; on DDS the service starts it (Ros2Node.start_dds).
# Nothing is converted for a topic no subscriber matches on any middleware; the sender thread
# keeps serialisation off the event loop.
from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from typing import Any

from tactiled.pipeline import Daemon, Estimate, ZeroedFrame
from tactiled.settings import Settings
from tactiled_service.ros2 import messages
from tactiled_service.sender import QUEUE_SIZE, Sender

log = logging.getLogger(__name__)

DIAGNOSTICS_PERIOD_S = 1.0
KINDS = ("wrench", "contact", "contacts", "markers", "strain", "taxels", "diagnostics")
#: The kinds published for (paced) zeroed frames: ``taxels`` on 3-axis arrays only.
FRAME_KINDS = ("strain", "taxels")


class ZenohSink:
    """One topic's rmw_zenoh publisher: its Zenoh publisher, GID and sequence numbers."""

    def __init__(self, token: str) -> None:
        from tactiled_service.ros2 import rmw

        self.token = token
        self.gid = rmw.gid(token)
        self.matched = False  # kept by Zenoh's matching listener
        self.sequence = 0  # the last sequence number sent (rmw_zenoh's first is 1)
        self.publisher: Any = None

    def write(self, payload: bytes, timestamp_ns: int) -> None:
        from tactiled_service.ros2.rmw import attachment

        self.sequence += 1
        self.publisher.put(payload, attachment=attachment(self.sequence, timestamp_ns,
                                                          self.gid))


class Topic:
    """One ROS publisher on every middleware: :meth:`put` runs on the sender thread: it takes
    the CDR bytes of an item (``encode``: an estimate's are built once per estimate, shared
    with the MCAP recorder: ``messages.estimate_cdr``), then hands the same bytes to each sink
    (a :class:`ZenohSink`, a :class:`~tactiled_service.ros2.dds.DdsSink`)."""

    def __init__(self, name: str, typename: str, encode: Callable[[Any], bytes]) -> None:
        self.name = name
        self.typename = typename
        self.encode = encode
        self.sinks: list[Any] = []

    @property
    def matched(self) -> bool:
        """Whether any middleware has a subscriber (nothing is built for none)."""
        return any(sink.matched for sink in self.sinks)

    def put(self, item: Any) -> None:
        payload = self.encode(item)
        now = time.time_ns()
        for sink in self.sinks:
            if sink.matched:
                sink.write(payload, now)


class Ros2Node:
    """The ROS 2 node of one daemon (see the module docstring); ``health`` has ``report()``
    (the service's :class:`~tactiled_service.health.HealthMonitor`)."""

    name = "ros2"  # its section in the health document's ``zenoh``

    def __init__(self, settings: Settings, daemon: Daemon, health: Any,
                 queue_size: int = QUEUE_SIZE) -> None:
        self.settings = settings.ros2
        self.daemon = daemon
        self.health = health
        self.sender = Sender(queue_size, kinds=KINDS, name="tactiled-ros2-send")
        self.frame_ids = {s.name: messages.frame_name(self.settings.frame_id, s.name)
                          for s in settings.sensors}
        self.hardware_ids = {s.name: s.url for s in settings.sensors}
        rate = settings.zenoh.frame_rate_hz
        self._frame_period = 1.0 / rate if rate > 0 else None
        self._frame_due: dict[str, float] = {}
        #: Monotonic -> wall-clock seconds, for items no clock stamped.
        self.clock_offset = time.time() - time.monotonic()
        self.node: Any = None  # rmw.NodeInfo once declared on Zenoh
        self.topics: dict[tuple[str, str], Topic] = {}  # (sensor, kind) -> topic
        plan = [(name, kind) for name in daemon.sensors
                for kind in (*messages.ESTIMATE_KINDS, *FRAME_KINDS)
                if kind not in FRAME_KINDS or (self._frame_period is not None and (
                    kind != "taxels" or getattr(daemon.sensors[name], "shear", None) is not None))]
        plan.append(("", "diagnostics"))
        for sensor, kind in plan:
            self.topics[(sensor, kind)] = Topic(
                messages.topic(self.settings.namespace, sensor, kind), messages.TYPES[kind],
                self._builder(sensor, kind))
        self.participant: Any = None  # the DDS domain participant (start_dds)
        self._remove_listener: Callable[[], None] | None = None
        self._task: asyncio.Task[None] | None = None

    # -- lifecycle ------------------------------------------------------------------------------

    def declare(self, session: Any) -> list[Any]:
        """Declare the publishers and tokens on ``session`` (on the event loop) and start
        publishing; returns what the bus undeclares at stop, tokens last (undeclared first)."""
        import zenoh

        from tactiled_service.ros2 import rmw

        s = self.settings
        self.node = rmw.NodeInfo(s.domain_id, str(session.zid()), 0, s.namespace, s.node_name)
        declared: list[Any] = []
        tokens = [session.liveliness().declare_token(self.node.token())]
        for entity_id, topic in enumerate(self.topics.values(), start=1):
            type_hash = rmw.distro_hash(messages.type_hash(topic.typename), s.distro)
            sink = ZenohSink(self.node.publisher_token(entity_id, topic.name, topic.typename,
                                                       type_hash))
            sink.publisher = session.declare_publisher(
                rmw.topic_key(s.domain_id, topic.name, topic.typename, type_hash),
                congestion_control=zenoh.CongestionControl.DROP)
            declared.append(sink.publisher)
            declared.append(sink.publisher.declare_matching_listener(
                zenoh.handlers.Callback(self._matcher(sink))))
            tokens.append(session.liveliness().declare_token(sink.token))
            topic.sinks.append(sink)
        self._start("zenoh")
        return declared + tokens

    def start_dds(self) -> None:
        """Create the DDS writers of every topic (:mod:`.dds`) and start publishing."""
        from tactiled_service.ros2 import dds

        self.participant = dds.participant(self.settings.domain_id)
        publisher = dds.Publisher(self.participant)
        for (_sensor, kind), topic in self.topics.items():
            topic.sinks.append(dds.DdsSink(self.participant, publisher, topic.name,
                                           topic.typename, kind, self.settings.distro))
        self._start("DDS")

    def _start(self, middleware: str) -> None:
        s = self.settings
        log.info("ros2: node %s/%s on domain %d over %s, %d topics", s.namespace.rstrip("/"),
                 s.node_name, s.domain_id, middleware, len(self.topics))
        if self._remove_listener is not None:  # already publishing on another middleware
            return
        self.sender.start()
        self._remove_listener = self.daemon.hub.add_listener(self._on_item)
        self._task = asyncio.get_running_loop().create_task(self._diagnostics_loop(),
                                                            name="tactiled-ros2-diagnostics")

    def stop(self) -> None:
        """Stop publishing (the bus undeclares and closes the Zenoh session afterwards; the
        DDS participant is deleted here).  Idempotent."""
        if self._remove_listener is not None:
            self._remove_listener()
            self._remove_listener = None
        if self._task is not None:
            self._task.cancel()
            self._task = None
        self.sender.stop()
        for topic in self.topics.values():
            topic.sinks = [sink for sink in topic.sinks if not hasattr(sink, "writer")]
        participant, self.participant = self.participant, None
        if participant is not None:
            del participant  # Cyclone DDS deletes the entity and its writers with the last ref

    # -- publishing -----------------------------------------------------------------------------

    @staticmethod
    def _matcher(sink: ZenohSink) -> Callable[[Any], None]:
        def on_status(status: Any) -> None:  # a Zenoh thread: one assignment, atomic
            sink.matched = bool(status.matching)

        return on_status

    def _builder(self, sensor: str, kind: str) -> Callable[[Any], bytes]:
        """The function that makes the CDR bytes of ``kind``'s message of a hub item (on the
        sender thread)."""
        typename = messages.TYPES[kind]
        serialize = messages.serialize
        if kind == "diagnostics":
            return lambda item: serialize(
                messages.diagnostics(item[0], item[1], self.hardware_ids), typename)
        frame_id = self.frame_ids[sensor]
        offset = self.clock_offset
        stamp = messages.item_stamp
        if kind == "strain":
            return lambda frame: serialize(
                messages.strain_image(frame.strain, stamp(frame, offset), frame_id), typename)
        if kind == "taxels":
            return lambda frame: serialize(
                messages.taxel_image(frame.taxels, stamp(frame, offset), frame_id), typename)
        return lambda est: messages.estimate_cdr(kind, est, stamp(est, offset), frame_id)

    def _on_item(self, item: Estimate | ZeroedFrame) -> None:
        """The hub's listener (the event loop's thread): queue the item, never wait."""
        if item.kind == "estimate":
            for kind in messages.ESTIMATE_KINDS:
                topic = self.topics.get((item.sensor, kind))
                if topic is not None and topic.matched:
                    self.sender.offer(topic, kind, item)
            return
        if self._frame_period is None:
            return
        wanted = [(topic, kind) for kind in FRAME_KINDS
                  if (topic := self.topics.get((item.sensor, kind))) is not None and topic.matched
                  and (kind != "taxels" or getattr(item, "taxels", None) is not None)]
        if not wanted:
            return
        now = time.monotonic()
        due = self._frame_due.get(item.sensor, 0.0)
        if now < due:
            return
        period = self._frame_period  # average rate frame_rate_hz; no burst after a pause
        self._frame_due[item.sensor] = due + period if now - due < period else now + period
        for topic, kind in wanted:  # strain and taxels of the same frames
            self.sender.offer(topic, kind, item)

    async def _diagnostics_loop(self) -> None:
        topic = self.topics[("", "diagnostics")]
        while True:
            await asyncio.sleep(DIAGNOSTICS_PERIOD_S)
            if not topic.matched:
                continue
            try:
                self.sender.offer(topic, "diagnostics", (self.health.report(), time.time()))
            except Exception:  # a health glitch must not stop the diagnostics
                log.exception("ros2: diagnostics failed")

    def stats(self) -> dict[str, Any]:
        """The health document's ``zenoh.ros2``: messages put by kind, dropped (the sender
        fell ``queue_size`` behind), put errors, the last error."""
        s = self.sender
        return {"published": dict(s.sent), "dropped": s.dropped, "put_errors": s.errors,
                "last_error": s.last_error}
