"""tactiled's service: the REST API, the WebSocket stream and the dashboard (docs/reference/api.md).

Modules: :mod:`~tactiled_service.server` (daemon + uvicorn in one loop, signals, sd_notify),
:mod:`~tactiled_service.app` (FastAPI routes), :mod:`~tactiled_service.stream` (the WebSocket
fan-out), :mod:`~tactiled_service.auth` (token, session cookie, Origin and Host checks),
:mod:`~tactiled_service.health` (status rules), :mod:`~tactiled_service.schemas` (pydantic),
:mod:`~tactiled_service.json_messages` (the JSON wire messages),
:mod:`~tactiled_service.protocol` (uvicorn's WebSocket protocol with a forced close),
:mod:`~tactiled_service.options` (limits), :mod:`~tactiled_service.dashboard` and ``static/``;
``python -m tactiled_bench.websocket_fanout`` benchmarks the fan-out.  Nothing here knows Hertz
but the display ellipse in ``json_messages``.
"""
