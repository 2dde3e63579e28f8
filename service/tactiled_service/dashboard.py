"""The dashboard: static files (``static/``, no build step, nothing fetched from a CDN) and
the login by ``/?token=...`` that turns a token into a same-origin session cookie."""

from __future__ import annotations

import html
from pathlib import Path

from fastapi import FastAPI, Request
from fastapi.responses import FileResponse, HTMLResponse, RedirectResponse, Response
from fastapi.staticfiles import StaticFiles

from tactiled_service.auth import SESSION_COOKIE, SESSION_TTL_S, AuthPolicy

STATIC = Path(__file__).resolve().parent / "static"
NO_STORE = {"Cache-Control": "no-store"}


def _page(status: int, title: str, text: str) -> HTMLResponse:
    body = (f"<!doctype html><meta charset=utf-8><title>tactiled: {html.escape(title)}</title>"
            "<link rel=icon href='data:,'>"
            f"<body style='font-family:sans-serif;margin:3em'><h1>{html.escape(title)}</h1>"
            f"<p>{html.escape(text)}</p>")
    return HTMLResponse(body, status_code=status, headers=NO_STORE)


def mount(app: FastAPI, auth: AuthPolicy) -> None:
    """Add ``GET /`` and ``/static/*`` to ``app``."""

    @app.get("/", include_in_schema=False)
    async def index(request: Request) -> Response:
        if auth.open:
            return FileResponse(STATIC / "index.html", headers=NO_STORE)
        token = request.query_params.get("token")
        if token is not None:
            if not auth.token_matches(token):
                return _page(403, "invalid token", "The token in the address is wrong.")
            # Trade the token for a session cookie and drop it from the address bar (and
            # from the browser's history).
            response = RedirectResponse("/", status_code=303, headers=NO_STORE)
            response.set_cookie(SESSION_COOKIE, auth.sessions.create(),
                                max_age=int(SESSION_TTL_S), path="/", httponly=True,
                                samesite="strict",
                                secure=request.url.scheme == "https")
            return response
        if auth.sessions.valid(auth.session_id(request.scope)):
            return FileResponse(STATIC / "index.html", headers=NO_STORE)
        return _page(401, "login needed",
                     "This daemon requires a token. Open this page once as "
                     "/?token=<your token>; the browser then keeps a session cookie.")

    app.mount("/static", StaticFiles(directory=STATIC), name="static")
