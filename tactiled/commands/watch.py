"""Subscribe to a running daemon and print what it streams, one JSON object per line.

Like gpspipe: every estimate (and, with --frames, every zeroed frame; with --slip, every slip
event of a 3-axis array) the daemon's stream sends, as it arrives, flushed line by line so it
can be piped (`tactiled watch | jq .r1_mm`).  Each line is the stream's message: "type"
("estimate", "frame" or "slip"), "v", "sensor", "seq", the keys of a `tactiled fit` line, and
"ellipse" (a slip event: "event", "contact_id", "state", docs/concepts/shear.md).  Control messages (version, subscribed) are not
printed; an error message from the server goes to stderr.

Exit status: 0 when the daemon closes the stream normally (or on Ctrl-C), 1 when the
connection fails or is closed with an error code, 2 for bad arguments or a refused token.

With --zenoh it reads Zenoh instead (docs/howto/zenoh.md; needs the zenoh extra): the estimates of
every daemon it can reach under the key expression --key (default tactiled/**), each line
tagged with its daemon's "prefix" first; --list prints one line per daemon alive (its
liveliness token) with its status and sensors, then exits.  The session is configured like a
daemon's [zenoh] (--config FILE, TACTILED_ZENOH_* variables: mode, multicast_scouting,
connect), --connect replacing connect; it never listens.

With --ros2 it prints what a ROS 2 subscriber of the daemons' ROS 2 topics receives
(docs/howto/ros2.md; needs the ros2 extra, and the zenoh extra for Zenoh): every wrench, contact
and markers message (with --frames the strain and 3-axis taxels images too, and /diagnostics),
decoded, one JSON object per line: "topic", "type", "sequence_number" and "source_timestamp_ns" (the rmw_zenoh
attachment; on DDS the writer's timestamp and no sequence number), "message" (the message's
fields).  --ros2-middleware reads DDS or Zenoh (default: Zenoh with --connect, else as [ros2]
middleware says, "auto" being Zenoh when [zenoh] is enabled, else DDS).  --domain-id picks the
ROS domain (default [ros2] domain_id, 0).

examples:
  tactiled watch
  tactiled watch ws://robot.local:8765/v1/stream --token "$TACTILED_TOKEN" --sensor thumb
  tactiled watch --frames --rate 10
  tactiled watch --zenoh
  tactiled watch --zenoh --connect tcp/192.168.1.10:7447 --key 'tactiled/hand1/**'
  tactiled watch --zenoh --list
  tactiled watch --ros2 --connect tcp/localhost:7447 --count 3
  tactiled watch --ros2 --ros2-middleware dds --domain-id 7
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import sys
from typing import Any, TextIO

from tactiled.errors import TactiledError
from tactiled.settings import DEFAULT_PORT

DEFAULT_URL = f"ws://127.0.0.1:{DEFAULT_PORT}/v1/stream"
ZENOH_KEY = "tactiled/**"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("url", nargs="?", default=None, metavar="URL",
                   help=f"the daemon's stream (default {DEFAULT_URL}; an http:// address or "
                        "host:port is completed)")
    p.add_argument("--token", default=None,
                   help="bearer token (default $TACTILED_TOKEN)")
    p.add_argument("--sensor", action="append", default=None, metavar="NAME",
                   help="only this sensor; repeatable (default: all)")
    p.add_argument("--frames", action="store_true", help="also print the zeroed strain frames")
    p.add_argument("--slip", action="store_true",
                   help="also print a 3-axis array's slip events (onset, end)")
    p.add_argument("--rate", type=float, default=None, metavar="HZ",
                   help="at most this many messages per second per sensor and stream "
                        "(default: every one)")
    p.add_argument("--count", type=int, default=None, metavar="N",
                   help="exit after N data messages")
    z = p.add_argument_group("Zenoh")
    z.add_argument("--zenoh", action="store_true",
                   help="read the daemons publishing on Zenoh instead of one WebSocket stream")
    z.add_argument("--connect", action="append", default=None, metavar="ENDPOINT",
                   help="Zenoh endpoint to connect to, e.g. tcp/192.168.1.10:7447; "
                        "repeatable (default: [zenoh] connect, and multicast scouting)")
    z.add_argument("--key", default=None, metavar="EXPR",
                   help=f"key expression to read (default {ZENOH_KEY})")
    z.add_argument("--list", action="store_true",
                   help="list the daemons alive and their sensors, then exit")
    z.add_argument("--ros2", action="store_true",
                   help="read the ROS 2 topics (rmw_zenoh's layout) and print them decoded")
    z.add_argument("--ros2-middleware", choices=("dds", "zenoh"), default=None,
                   help="where --ros2 reads: DDS or Zenoh (default: see above)")
    z.add_argument("--domain-id", type=int, default=None, metavar="N",
                   help="ROS domain of --ros2 (default [ros2] domain_id, 0)")
    z.add_argument("--config", default=None, metavar="FILE",
                   help="take the Zenoh session's settings from this file's [zenoh] "
                        "(default $TACTILED_CONFIG)")


def stream_url(url: str | None) -> str:
    """Complete ``url`` to a ``ws://.../v1/stream`` address."""
    if not url:
        return DEFAULT_URL
    if url.startswith(("http://", "https://")):
        url = "ws" + url[len("http"):]
    elif not url.startswith(("ws://", "wss://")):
        url = "ws://" + url
    scheme, rest = url.split("://", 1)
    if "/" not in rest:
        rest += "/v1/stream"
    elif rest.endswith("/") and rest.count("/") == 1:
        rest += "v1/stream"
    return f"{scheme}://{rest}"


def subscribe_message(args: argparse.Namespace) -> dict[str, Any]:
    streams = ["estimates"] + (["frames"] if args.frames else []) + (["slip"] if args.slip else [])
    msg: dict[str, Any] = {"type": "subscribe", "streams": streams}
    if args.sensor:
        msg["sensors"] = list(args.sensor)
    if args.rate is not None:
        msg["max_rate"] = args.rate
    return msg


async def watch(args: argparse.Namespace, out: TextIO) -> int:
    from websockets.asyncio.client import connect
    from websockets.exceptions import ConnectionClosed, InvalidStatus, InvalidURI

    url = stream_url(args.url)
    token = args.token if args.token is not None else os.environ.get("TACTILED_TOKEN")
    headers = {"Authorization": f"Bearer {token}"} if token else None
    count = 0
    try:
        async with connect(url, additional_headers=headers, compression=None,
                           max_size=2**22, open_timeout=10) as ws:
            async for text in ws:
                msg = json.loads(text)
                kind = msg.get("type")
                if kind == "version":
                    await ws.send(json.dumps(subscribe_message(args)))
                elif kind == "error":
                    print(f"tactiled watch: server: {msg.get('message')}", file=sys.stderr)
                    if msg.get("request") == "subscribe":
                        return 2
                elif kind in ("estimate", "frame", "slip"):
                    out.write(text + "\n")
                    out.flush()
                    count += 1
                    if args.count is not None and count >= args.count:
                        return 0
            code, reason = ws.close_code, ws.close_reason
    except InvalidStatus as err:
        status = err.response.status_code
        try:
            detail = json.loads(err.response.body or b"{}").get("detail", "")
        except ValueError:
            detail = ""
        print(f"tactiled watch: {url}: refused ({status}){': ' + detail if detail else ''}",
              file=sys.stderr)
        return 2 if status in (401, 403) else 1
    except InvalidURI as err:
        print(f"tactiled watch: error: {err}", file=sys.stderr)
        return 2
    except ConnectionClosed as err:
        code = err.rcvd.code if err.rcvd is not None else 1006
        reason = err.rcvd.reason if err.rcvd is not None else "no close frame"
        print(f"tactiled watch: closed by the daemon ({code} {reason})", file=sys.stderr)
        return 0 if code in (1000, 1001) else 1
    except (OSError, TimeoutError) as err:
        print(f"tactiled watch: cannot connect to {url}: {err}", file=sys.stderr)
        return 1
    print(f"tactiled watch: the daemon closed the stream ({code} {reason})", file=sys.stderr)
    return 0


def watch_zenoh(args: argparse.Namespace, out: TextIO) -> int:
    """``--zenoh``: the bus's estimates (or ``--list``) through Zenoh."""
    from tactiled.settings import load_settings

    overrides: dict[str, Any] = {}
    if args.connect:
        overrides["zenoh.connect"] = list(args.connect)
    if args.domain_id is not None:
        overrides["ros2.domain_id"] = args.domain_id
    loaded = load_settings(args.config, os.environ, overrides)  # ConfigError: exit 2
    settings = loaded.zenoh
    middleware = args.ros2_middleware or (
        "zenoh" if args.connect else loaded.ros2.middlewares(loaded.zenoh.enabled)[-1])
    if args.ros2 and middleware == "dds":
        try:
            from tactiled_service.ros2 import dds_reader
        except ImportError as err:
            print(f"tactiled watch: error: --ros2 on DDS needs the ros2 extra: pip install "
                  f"'tactiled[ros2]' ({err})", file=sys.stderr)
            return 2
        return dds_reader.watch(loaded.ros2.domain_id, out, sensors=args.sensor,
                                frames=args.frames, count=args.count)
    if args.ros2:
        try:
            from tactiled_service.ros2 import reader
        except ImportError as err:
            print(f"tactiled watch: error: --ros2 needs the zenoh and ros2 extras: pip install "
                  f"'tactiled[zenoh,ros2]' ({err})", file=sys.stderr)
            return 2
        try:
            return reader.watch(settings, loaded.ros2.domain_id, out, sensors=args.sensor,
                                frames=args.frames, count=args.count)
        except Exception as err:  # zenoh.ZError: no router for a client, a refused endpoint
            print(f"tactiled watch: zenoh: {err}", file=sys.stderr)
            return 1
    try:
        # Only --zenoh pays for Zenoh (the zenoh extra).
        from tactiled_service import bus
    except ImportError as err:
        print(f"tactiled watch: error: --zenoh needs the zenoh extra: pip install "
              f"'tactiled[zenoh]' ({err})", file=sys.stderr)
        return 2
    key = args.key or ZENOH_KEY
    try:
        bus.check_key(key)
    except ValueError as err:
        print(f"tactiled watch: error: --key {key!r} is not a key expression: {err}",
              file=sys.stderr)
        return 2
    try:
        if args.list:
            for entry in bus.list_daemons(settings, key):
                out.write(json.dumps(entry) + "\n")
            out.flush()
            return 0
        kinds = ("estimate",) + (("frame",) if args.frames else ()) + (("slip",) if args.slip else ())
        return bus.watch(settings, key, out, kinds=kinds, sensors=args.sensor, count=args.count)
    except TactiledError:
        raise
    except Exception as err:  # zenoh.ZError: no router for a client, a refused endpoint
        print(f"tactiled watch: zenoh: {bus.describe_error(err)}", file=sys.stderr)
        return 1


def run(args: argparse.Namespace) -> int:
    if (args.domain_id is not None or args.ros2_middleware) and not args.ros2:
        print("tactiled watch: error: --domain-id and --ros2-middleware go with --ros2",
              file=sys.stderr)
        return 2
    if args.zenoh or args.ros2 or args.list or args.connect or args.key:
        if not (args.zenoh or args.ros2) or (args.ros2 and (args.list or args.key)):
            print("tactiled watch: error: --list, --connect and --key go with --zenoh "
                  "(--connect also with --ros2)", file=sys.stderr)
            return 2
        if args.url or args.token or args.rate is not None:
            print("tactiled watch: error: --zenoh reads Zenoh, not a WebSocket stream: no URL, "
                  "--token or --rate", file=sys.stderr)
            return 2
        if args.count is not None and args.count < 1:
            print("tactiled watch: error: --count must be >= 1", file=sys.stderr)
            return 2
        try:
            return watch_zenoh(args, sys.stdout)
        except KeyboardInterrupt:
            return 0
    if args.config:
        print("tactiled watch: error: --config goes with --zenoh", file=sys.stderr)
        return 2
    if args.rate is not None and not args.rate > 0:
        print("tactiled watch: error: --rate must be > 0", file=sys.stderr)
        return 2
    if args.count is not None and args.count < 1:
        print("tactiled watch: error: --count must be >= 1", file=sys.stderr)
        return 2
    try:
        return asyncio.run(watch(args, sys.stdout))
    except KeyboardInterrupt:
        return 0
