"""Who may use the API: bearer token, dashboard session cookie, Origin and Host checks.

Open mode (loopback, no token) needs no credentials but still refuses foreign Host and
Origin; token mode needs a bearer token or the dashboard's session cookie; CORS
(:class:`Cors`) only for allow-listed origins (docs/reference/api.md, "Security").  Works on
raw ASGI scopes, so REST routes and the raw WebSocket endpoint share it.
"""
# * Open mode (listening on loopback, no token configured): a request whose Host is not a
#   loopback name is refused (DNS rebinding), and a WebSocket or control request carrying a
#   foreign Origin is refused (cross-site WebSocket hijacking, CSRF).
# * Token mode (a token is configured; required off loopback): /v1 endpoints other than
#   /v1/health, /v1/version and the OpenAPI document need "Authorization: Bearer <token>" or the
#   session cookie.  The stream checks this at the handshake, so an unauthorised client is
#   answered 401/403 and never accepted.
# * The dashboard logs in by being loaded once as /?token=<token>: the server sets an HttpOnly,
#   SameSite=Strict session cookie and redirects to /, so the token leaves the address bar and
#   page scripts never see it.
# * CORS: a page of an origin on [server] allow_origins may call the REST API with fetch (a JSON
#   PATCH, a bearer token): its preflight is answered and its answers carry
#   Access-Control-Allow-Origin.  Other origins get no CORS header, so browsers keep their pages
#   from reading any answer.

from __future__ import annotations

import hmac
import json
import ipaddress
import secrets
import time
from collections import OrderedDict
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from http.cookies import CookieError, SimpleCookie
from typing import Any

SESSION_COOKIE = "tactiled_session"
#: A dashboard session lasts this long without a new login (s).
SESSION_TTL_S = 12 * 3600.0
MAX_SESSIONS = 1000
LOOPBACK_NAMES = frozenset({"localhost", "localhost.localdomain", "ip6-localhost"})


@dataclass(frozen=True)
class Denial:
    """Why a request is refused: HTTP ``status``, a precise ``message``, extra headers."""

    status: int
    message: str
    headers: tuple[tuple[str, str], ...] = ()


def is_loopback_host(host: str) -> bool:
    """True for a loopback address or name (``127.0.0.1``, ``::1``, ``localhost``)."""
    name = host.strip().strip("[]").lower()
    if name in LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(name).is_loopback
    except ValueError:
        return False


def header(scope: dict[str, Any], name: bytes) -> str | None:
    """The first value of header ``name`` (lower-case bytes) in an ASGI scope."""
    for key, value in scope.get("headers", ()):
        if key == name:
            return value.decode("latin-1")
    return None


def _host_name(host_header: str) -> str:
    """``127.0.0.1:8765`` -> ``127.0.0.1``; ``[::1]:8765`` -> ``::1``."""
    if host_header.startswith("["):
        return host_header[1:].split("]", 1)[0]
    return host_header.rsplit(":", 1)[0] if host_header.count(":") == 1 else host_header


class Sessions:
    """Dashboard sessions: random ids with an expiry (monotonic s), oldest evicted first."""

    def __init__(self, ttl: float = SESSION_TTL_S, limit: int = MAX_SESSIONS) -> None:
        self.ttl = ttl
        self.limit = limit
        self._expiry: OrderedDict[str, float] = OrderedDict()

    def create(self) -> str:
        sid = secrets.token_urlsafe(32)
        self._expiry[sid] = time.monotonic() + self.ttl
        while len(self._expiry) > self.limit:
            self._expiry.popitem(last=False)
        return sid

    def valid(self, sid: str | None) -> bool:
        if not sid:
            return False
        expiry = self._expiry.get(sid)
        if expiry is None:
            return False
        if time.monotonic() > expiry:
            del self._expiry[sid]
            return False
        return True


class AuthPolicy:
    """The checks above for one server: ``token`` (None: open), ``loopback`` (bound to a
    loopback address), extra ``allowed_origins`` (``scheme://host[:port]``)."""

    def __init__(self, token: str | None, loopback: bool,
                 allowed_origins: Iterable[str] = ()) -> None:
        if token is None and not loopback:
            raise ValueError("a token is required when not listening on loopback")
        self.token = token
        self.loopback = loopback
        self.allowed_origins = frozenset(o.rstrip("/").lower() for o in allowed_origins)
        self.sessions = Sessions()

    def listed_origin(self, origin: str) -> bool:
        """True when ``origin`` is on the configured allow-list (not merely same-origin)."""
        return origin.rstrip("/").lower() in self.allowed_origins

    @property
    def open(self) -> bool:
        """No credentials needed (loopback, no token)."""
        return self.token is None

    # -- individual checks ----------------------------------------------------------------------

    def check_host(self, scope: dict[str, Any]) -> Denial | None:
        """In open mode, refuse a Host header that is not a loopback name: a page of another
        site that rebinds its DNS name to 127.0.0.1 would otherwise reach the open API."""
        if not self.open:
            return None
        host = header(scope, b"host")
        if host is None:  # HTTP/1.0 clients; not a browser
            return None
        if is_loopback_host(_host_name(host)):
            return None
        return Denial(403, f"Host {host!r} not allowed: this server is open to loopback "
                           "clients only (configure a token to serve other hosts)")

    def check_origin(self, scope: dict[str, Any]) -> Denial | None:
        """A browser request from another origin than the server's own (or the allow-list)
        is refused; clients that send no Origin (not browsers) pass."""
        origin = header(scope, b"origin")
        if origin is None:
            return None
        if self.listed_origin(origin):
            return None
        origin_l = origin.rstrip("/").lower()
        host = header(scope, b"host")
        if host is not None:
            scheme = scope.get("scheme", "http")
            scheme = {"ws": "http", "wss": "https"}.get(scheme, scheme)
            if origin_l == f"{scheme}://{host}".lower():
                return None
        return Denial(403, f"Origin {origin!r} not allowed (allowed: the server's own origin"
                           + (", " + ", ".join(sorted(self.allowed_origins))
                              if self.allowed_origins else "") + ")")

    def session_id(self, scope: dict[str, Any]) -> str | None:
        raw = header(scope, b"cookie")
        if not raw:
            return None
        try:
            cookie = SimpleCookie(raw)
        except CookieError:
            return None
        morsel = cookie.get(SESSION_COOKIE)
        return morsel.value if morsel is not None else None

    def check_credentials(self, scope: dict[str, Any]) -> Denial | None:
        """Token mode: a valid bearer token or dashboard session; open mode: nothing."""
        if self.open:
            return None
        auth = header(scope, b"authorization")
        if auth is not None:
            scheme, _, value = auth.partition(" ")
            if scheme.lower() != "bearer" or not value.strip():
                return Denial(401, "Authorization header must be 'Bearer <token>'",
                              (("WWW-Authenticate", 'Bearer realm="tactiled"'),))
            if self.token_matches(value.strip()):
                return None
            return Denial(403, "invalid token",
                          (("WWW-Authenticate", 'Bearer realm="tactiled", '
                                                'error="invalid_token"'),))
        if self.sessions.valid(self.session_id(scope)):
            return None
        return Denial(401, "authentication required: send 'Authorization: Bearer <token>' "
                           "(or open the dashboard as /?token=<token>)",
                      (("WWW-Authenticate", 'Bearer realm="tactiled"'),))

    def token_matches(self, candidate: str) -> bool:
        """Constant-time comparison with the configured token."""
        if self.token is None:
            return False
        return hmac.compare_digest(candidate.encode(), self.token.encode())

    # -- combined -------------------------------------------------------------------------------

    def check_stream(self, scope: dict[str, Any]) -> Denial | None:
        """The WebSocket handshake: Origin first (a browser page of another site), then
        credentials."""
        return self.check_origin(scope) or self.check_credentials(scope)

    def check_control(self, scope: dict[str, Any]) -> Denial | None:
        """State-changing REST calls: the same as the stream (Origin stops CSRF even in open
        mode)."""
        return self.check_origin(scope) or self.check_credentials(scope)

    def check_read(self, scope: dict[str, Any]) -> Denial | None:
        """Data reads: credentials only (a cross-origin page cannot read the answer)."""
        return self.check_credentials(scope)


class HostGuard:
    """ASGI middleware applying :meth:`AuthPolicy.check_host` to HTTP requests (the stream
    applies it at its own handshake)."""

    def __init__(self, app: Any, auth: AuthPolicy) -> None:
        self.app = app
        self.auth = auth

    async def __call__(self, scope: dict[str, Any], receive: Any, send: Any) -> None:
        if scope["type"] == "http":
            denial = self.auth.check_host(scope)
            if denial is not None:
                body = json.dumps({"detail": denial.message}).encode()
                await send({"type": "http.response.start", "status": denial.status,
                            "headers": [(b"content-type", b"application/json"),
                                        (b"content-length", str(len(body)).encode())]})
                await send({"type": "http.response.body", "body": body})
                return
        await self.app(scope, receive, send)


#: What a preflight allows a listed origin's page to send besides the simple headers, and how
#: long (s) the browser may keep the answer.
CORS_ALLOW_HEADERS = b"Authorization, Content-Type"
CORS_MAX_AGE_S = 600


class Cors:
    """ASGI middleware: CORS for the origins of :attr:`AuthPolicy.allowed_origins` on the REST
    API (``/v1/...`` and ``/metrics``).

    A preflight (``OPTIONS`` with ``Access-Control-Request-Method``) from a listed origin to a
    path that exists is answered 204 with the path's methods (``methods(scope)``), the
    headers a page may send (``Authorization``, ``Content-Type``) and a max age; its other
    requests are served as usual (credentials and Origin checked as for anyone) and answered
    with ``Access-Control-Allow-Origin``.  A request from any other origin passes through
    untouched: a preflight gets the path's 405, no CORS header, and the browser stops there.
    """

    def __init__(self, app: Any, auth: AuthPolicy,
                 methods: Callable[[dict[str, Any]], set[str]]) -> None:
        self.app = app
        self.auth = auth
        self.methods = methods

    async def __call__(self, scope: dict[str, Any], receive: Any, send: Any) -> None:
        if scope["type"] != "http" or not (scope["path"].startswith("/v1/")
                                           or scope["path"] == "/metrics"):
            await self.app(scope, receive, send)
            return
        origin = header(scope, b"origin")
        if origin is None or not self.auth.listed_origin(origin):
            await self.app(scope, receive, send)
            return
        allow = [(b"access-control-allow-origin", origin.encode("latin-1")),
                 (b"vary", b"Origin")]
        if (scope["method"] == "OPTIONS"
                and header(scope, b"access-control-request-method") is not None):
            methods = self.methods(scope)
            if methods:
                await send({"type": "http.response.start", "status": 204, "headers": allow + [
                    (b"access-control-allow-methods", ", ".join(sorted(methods)).encode()),
                    (b"access-control-allow-headers", CORS_ALLOW_HEADERS),
                    (b"access-control-max-age", str(CORS_MAX_AGE_S).encode())]})
                await send({"type": "http.response.body", "body": b""})
                return

        async def send_allowed(message: dict[str, Any]) -> None:
            if message["type"] == "http.response.start":
                message = {**message, "headers": [*message.get("headers", ()), *allow]}
            await send(message)

        await self.app(scope, receive, send_allowed)
