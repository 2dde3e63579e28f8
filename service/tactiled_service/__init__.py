"""tactiled's service: the REST API, the WebSocket stream and the dashboard (docs/reference/api.md).

:mod:`~tactiled_service.server` runs the daemon and uvicorn in one loop;
:mod:`~tactiled_service.app` holds the routes, :mod:`~tactiled_service.stream` the WebSocket
fan-out, :mod:`~tactiled_service.auth` the access checks, :mod:`~tactiled_service.health` the
status rules, :mod:`~tactiled_service.json_messages` the wire messages; ``bus`` and ``ros2`` are
the Zenoh and ROS 2 front ends.  Nothing here knows Hertz but the display ellipse.
"""
# Also: schemas (pydantic), protocol (uvicorn's WebSocket protocol with a forced close), options
# (limits), dashboard and static/.  python -m tactiled_bench.websocket_fanout benchmarks the
# fan-out.
