"""Run the daemon: acquisition, fitting, the REST/WebSocket API and the dashboard, one process.

With no configuration it plays the simulated finger's looping demo scene (one sensor,
finger0) and serves http://127.0.0.1:8765/ (the default port), which it prints on stdout once
the server answers.  Precedence: flags > TACTILED_* environment (TACTILED_TOKEN for the token)
> the --config file > defaults.  Listening on anything but loopback requires a token.

SIGTERM or Ctrl-C: graceful stop within 5 s (stream clients get close code 1001, devices are
released, recordings flushed); a second Ctrl-C exits at once.  Under systemd (Type=notify) it
reports READY=1 once serving, WATCHDOG=1 while frames flow, STOPPING=1 on the way out.

With --zenoh (or [zenoh] enabled) it also publishes the estimates, frames and health on Zenoh
(needs the zenoh extra: pip install 'tactiled[zenoh]'; docs/howto/zenoh.md).  With --ros2 (or [ros2]
enabled) it is also a ROS 2 node on that session, the way rmw_zenoh lays topics out (needs the
ros2 extra; docs/howto/ros2.md).

examples:
  tactiled run
  tactiled run --config /etc/tactiled/tactiled.toml
  TACTILED_TOKEN=s3cret tactiled run --host 0.0.0.0 --port 9000
  tactiled run --zenoh --zenoh-connect tcp/192.168.1.10:7447
  tactiled run --ros2 --zenoh-mode client --zenoh-connect tcp/localhost:7447
"""

from __future__ import annotations

import argparse
import asyncio
import os
import sys
from typing import Any

from tactiled.errors import ConfigError, TactiledError


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", metavar="FILE", default=None,
                   help="TOML configuration file (default: $TACTILED_CONFIG, else built-in "
                        "defaults: the simulated demo finger)")
    p.add_argument("--host", default=None,
                   help="address to listen on (default 127.0.0.1; others need a token)")
    p.add_argument("--port", type=int, default=None,
                   help="TCP port (default 8765; 0 picks a free one)")
    p.add_argument("--token", default=None,
                   help="bearer token clients must send (default $TACTILED_TOKEN; prefer the "
                        "environment: command lines are visible to other users)")
    p.add_argument("--max-subscribers", type=int, default=None, metavar="N",
                   help="WebSocket stream connections accepted at once (default: "
                        "[server] max_subscribers, 64)")
    p.add_argument("--allow-origin", action="append", default=[], metavar="ORIGIN",
                   help="browser origin (scheme://host:port) allowed to use the stream and "
                        "control endpoints besides the server's own; repeatable (replaces "
                        "[server] allow_origins)")
    p.add_argument("--max-fits-per-worker", type=int, default=None, metavar="N",
                   help="replace a fit worker after N fits, its successor started first (no "
                        "fit lost); 0 never (default: [fit] max_fits_per_worker, 0)")
    z = p.add_argument_group("Zenoh (docs/howto/zenoh.md; flags win over [zenoh] and TACTILED_ZENOH_*)")
    z.add_argument("--zenoh", action="store_true", default=None,
                   help="publish on Zenoh ([zenoh] enabled = true)")
    z.add_argument("--zenoh-mode", choices=("peer", "client"), default=None,
                   help="peer (default) or client (through a router)")
    z.add_argument("--zenoh-connect", action="append", default=None, metavar="ENDPOINT",
                   help="endpoint to connect to, e.g. tcp/192.168.1.10:7447; repeatable "
                        "(replaces [zenoh] connect)")
    z.add_argument("--zenoh-listen", action="append", default=None, metavar="ENDPOINT",
                   help="endpoint to listen on, e.g. tcp/0.0.0.0:7447; repeatable (replaces "
                        "[zenoh] listen)")
    z.add_argument("--zenoh-prefix", default=None, metavar="KEY",
                   help="the key every publication starts with (default tactiled/<hostname>)")
    r = p.add_argument_group("ROS 2 (docs/howto/ros2.md; flags win over [ros2] and TACTILED_ROS2_*)")
    r.add_argument("--ros2", action="store_true", default=None,
                   help="publish ROS 2 topics ([ros2] enabled = true): on the Zenoh session, as "
                        "rmw_zenoh does (turns on [zenoh] enabled too), unless "
                        "--ros2-middleware dds")
    r.add_argument("--ros2-middleware", choices=("dds", "zenoh", "both"), default=None,
                   help="DDS (Cyclone DDS, as ROS 2's default middlewares), rmw_zenoh's layout, "
                        "or both ([ros2] middleware)")
    r.add_argument("--ros2-domain-id", type=int, default=None, metavar="N",
                   help="ROS_DOMAIN_ID of the graph to join (default 0)")
    # -v is also accepted after the command name (the top-level parser handles the level).
    p.add_argument("-v", "--verbose", action="count", default=argparse.SUPPRESS,
                   help="more log output")


#: key -> the flag (or variable) that sets it, as an error names it
FLAGS: dict[str, str] = {
    "server.token": "--token or $TACTILED_TOKEN", "server.host": "--host", "server.port": "--port",
    "fit.max_fits_per_worker": "--max-fits-per-worker", "zenoh.enabled": "--zenoh or --ros2",
    "zenoh.mode": "--zenoh-mode", "zenoh.connect": "--zenoh-connect",
    "zenoh.listen": "--zenoh-listen", "zenoh.prefix": "--zenoh-prefix",
    "ros2.enabled": "--ros2", "ros2.domain_id": "--ros2-domain-id",
}


def _overrides(args: argparse.Namespace) -> dict[str, Any]:
    out: dict[str, Any] = {}
    token = args.token if args.token is not None else os.environ.get("TACTILED_TOKEN")
    if token is not None:
        out["server.token"] = token
    if args.host is not None:
        out["server.host"] = args.host
    if args.port is not None:
        out["server.port"] = args.port
    if args.max_fits_per_worker is not None:
        out["fit.max_fits_per_worker"] = args.max_fits_per_worker
    for flag, key in (("zenoh", "enabled"), ("zenoh_mode", "mode"),
                      ("zenoh_connect", "connect"), ("zenoh_listen", "listen"),
                      ("zenoh_prefix", "prefix")):
        value = getattr(args, flag, None)
        if value is not None:
            out[f"zenoh.{key}"] = value
    middleware = getattr(args, "ros2_middleware", None)
    if middleware is not None:
        out["ros2.middleware"] = middleware
    if getattr(args, "ros2", None):
        out["ros2.enabled"] = True
        if middleware != "dds":
            out["zenoh.enabled"] = True
    if getattr(args, "ros2_domain_id", None) is not None:
        out["ros2.domain_id"] = args.ros2_domain_id
    return out


def run(args: argparse.Namespace) -> int:
    from tactiled.settings import load_settings

    settings = load_settings(args.config, os.environ, _overrides(args), FLAGS)  # ConfigError: exit 2
    try:
        # The service pulls in FastAPI and uvicorn: only this command pays for them.
        from tactiled_service.options import ServiceOptions
        from tactiled_service.server import serve
    except ImportError as err:
        print(f"tactiled run: error: the service is not installed: {err}", file=sys.stderr)
        return 2
    # The flags override the [server] keys of the configuration (the usual precedence).
    kwargs: dict[str, Any] = {"max_subscribers": settings.server.max_subscribers,
                              "allowed_origins": settings.server.allow_origins,
                              "read_timeout_s": settings.server.read_timeout}
    if args.max_subscribers is not None:
        kwargs["max_subscribers"] = args.max_subscribers
    if args.allow_origin:
        kwargs["allowed_origins"] = tuple(args.allow_origin)
    try:
        options = ServiceOptions(**kwargs)
    except ValueError as err:
        raise ConfigError(f"--max-subscribers: {err}") from None

    def ready(service: Any) -> None:
        # The one line on stdout: scripts and tests read the address from it.
        print(service.url, flush=True)
        if settings.server.token:
            print(f"tactiled: open {service.url}?token=<token> once to log in the dashboard",
                  file=sys.stderr, flush=True)

    try:
        return asyncio.run(serve(settings, options, on_ready=ready))
    except TactiledError:
        raise  # one line and exit code 2, at the CLI's edge
    except (OSError, RuntimeError) as err:
        print(f"tactiled run: error: {err}", file=sys.stderr)
        return 1
