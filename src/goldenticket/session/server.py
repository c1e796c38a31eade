"""The session's web app: the robot's JSON API and the operator's page, on Starlette + uvicorn.

    GET  /api/next    -> {"episode", "ticket_id", "noise", "gaussian_seed", "noise_shape"} or {"done": true}
    POST /api/score   {"episode": int, "success": bool, "note"?: str, "scene"?: str} -> {"ok": true};
                      409 {"error", "due"} for any episode but the due one
    POST /api/undo    {"episode": int} -> {"undone": episode}; 409 {"error", "last_scored"} unless
                      it names the last score entered
    GET  /api/status  -> {"scored", "total" (the most it may run), "due", "last_scored", "stopping",
                      "stage" (what is due, in words), "session", "policy", ...}, and "verdict" (with
                      "stopping": when and why it stopped) once the session is complete
    GET  /verdict.png -> the verdict plot, once done
    GET  /            -> the operator's page (never shows which arm runs)

Every error is JSON, {"error": message}: 400 a malformed request, 401 no token, 403 another
site, 404 no such path (or no verdict yet), 405 a method the path does not take, 413 a body over
64 KiB, 415 a POST that is not JSON, 503 the store cannot save (its file deleted, a full disk).

No other web site can use the API through a browser: the Host header must name this server (no
DNS rebinding), an Origin header must be this server's own, and a POST must be
`application/json`, which no HTML form can send. Bound to 127.0.0.1 by default; any other
interface needs a token, sent as `Authorization: Bearer <token>` or `?token=<token>`.
"""

from __future__ import annotations

import hmac
import json
import socket
import sqlite3
from importlib.resources import files
from pathlib import Path
from urllib.parse import urlsplit

from goldenticket.errors import OptionError, UserError
from goldenticket.session.folder import ScoreConflict, Session
from goldenticket.session.store import StoreLost

LOCAL_HOSTS = ("127.0.0.1", "localhost", "::1")
ANY_HOST = ("0.0.0.0", "::")
MAX_BODY = 64 * 1024
SECURITY_HEADERS = [
    (b"x-frame-options", b"DENY"), (b"x-content-type-options", b"nosniff"),
    (b"content-security-policy", b"default-src 'self' 'unsafe-inline'; frame-ancestors 'none'"),
    (b"referrer-policy", b"no-referrer"), (b"cache-control", b"no-store")]
_STATUS = {UserError: 400, ScoreConflict: 409, StoreLost: 503, sqlite3.Error: 503, OSError: 503}


class _Refused(UserError):
    """A request refused with its own HTTP status."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status


def make_app(folder: str | Path, token: str | None = None, host: str = "127.0.0.1"):
    """The ASGI app for one session folder, served on `host` (what the Host header must name)."""
    from starlette.applications import Starlette
    from starlette.exceptions import HTTPException
    from starlette.middleware import Middleware
    from starlette.responses import HTMLResponse, JSONResponse, Response
    from starlette.routing import Route

    session = Session(folder)
    page = files("goldenticket.session").joinpath("page.html").read_text()

    async def index(request):
        return HTMLResponse(page)

    async def next_episode(request):
        episode = session.next()
        return JSONResponse({"done": True} if episode is None else episode.to_json())

    async def score(request):
        body = await _json_body(request)
        session.score(*_score_fields(body), body.get("note") or "", body.get("scene"))
        return JSONResponse({"ok": True})

    async def undo(request):
        episode = _episode(await _json_body(request))
        session.undo(episode)
        return JSONResponse({"undone": episode})

    async def status(request):
        status = session.status()
        if "verdict" in status:
            status["verdict"] = status["verdict"].to_dict()
        return JSONResponse({**status, "session": session.name, "policy": session.plan.policy})

    async def verdict_png(request):
        if "verdict" not in session.status():
            raise _Refused(404, "the session is not finished")
        return Response((session.path.parent / "verdict.png").read_bytes(), media_type="image/png")

    routes = [Route("/", index), Route("/api/next", next_episode), Route("/api/status", status),
              Route("/api/score", score, methods=["POST"]), Route("/api/undo", undo, methods=["POST"]),
              Route("/verdict.png", verdict_png)]
    hosts = None if host in ANY_HOST else {host.lower(), *LOCAL_HOSTS}
    handlers = {kind: _answer(code) for kind, code in _STATUS.items()} | {HTTPException: _http_error}
    app = Starlette(routes=routes, middleware=[Middleware(_Guard, hosts=hosts, token=token)],
                    exception_handlers=handlers)
    app.state.session = session
    return app


def serve(folder: str | Path, host: str = "127.0.0.1", port: int = 8765, token: str | None = None) -> None:
    """Run the app until interrupted; refuses a non-local interface without a token."""
    import uvicorn

    if host not in LOCAL_HOSTS and not token:
        raise UserError(f"binding to {host} exposes the session to the network: pass --token")
    if not 0 < port < 65536:
        raise OptionError(f"port must be in 1..65535, got {port}", "port")
    app = make_app(folder, token, host)
    _check_free(host, port)
    print(f"Session {folder}: operator page at http://{host}:{port}/"
          + (f"?token={token}" if token else ""), flush=True)
    uvicorn.run(app, host=host, port=port, log_level="warning")


def _check_free(host: str, port: int) -> None:
    """UserError if nothing can listen on host:port (another server there, an unknown host)."""
    try:
        family = socket.getaddrinfo(host, port)[0][0]
        with socket.socket(family) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as uvicorn does
            probe.bind((host, port))
    except OSError as e:
        raise UserError(f"cannot listen on {host}:{port}: {e.strerror or e}") from None


def _answer(code: int):
    """An exception handler: the error as JSON with its status (and a conflict's details)."""
    from starlette.responses import JSONResponse

    async def handler(request, exc):
        message = str(exc) if isinstance(exc, UserError) else f"the session store failed ({exc})"
        return JSONResponse({"error": message, **getattr(exc, "details", {})},
                            status_code=getattr(exc, "status", code))

    return handler


async def _http_error(request, exc):
    """Starlette's own refusals (no such path, a method the path does not take) as JSON errors."""
    from starlette.responses import JSONResponse

    where = f"{request.method} {request.url.path}"
    if exc.status_code == 404:
        message = f"{where}: no such path (there are /, /verdict.png and /api/next, score, undo, status)"
    elif exc.status_code == 405:
        message = f"{where}: the path takes {exc.headers['Allow']} only"
    else:
        message = f"{where}: {exc.detail}"
    return JSONResponse({"error": message}, status_code=exc.status_code, headers=exc.headers)


async def _json_body(request):
    body = b""
    async for chunk in request.stream():
        body += chunk
        if len(body) > MAX_BODY:
            raise _Refused(413, f"the body is over {MAX_BODY // 1024} KiB")
    try:
        return json.loads(body)
    except (ValueError, RecursionError) as e:
        raise UserError(f"the body is not JSON that can be read ({e})") from None


def _episode(body) -> int:
    if not isinstance(body, dict):
        raise UserError("the body must be a JSON object")
    episode = body.get("episode")
    if not isinstance(episode, int) or isinstance(episode, bool):
        raise UserError("'episode' must be an integer")
    return episode


def _score_fields(body) -> tuple[int, bool]:
    episode, success = _episode(body), body.get("success")
    if not isinstance(success, bool):
        raise UserError("'success' must be true or false")
    for key in ("note", "scene"):
        if body.get(key) is not None and not isinstance(body[key], str):
            raise UserError(f"'{key}' must be a string")
    return episode, success


class _Guard:
    """Refuses requests from other sites (Host, Origin), without the token, or POSTs that are not
    JSON, before they reach the app; adds the security headers to every answer."""

    def __init__(self, app, hosts: set[str] | None, token: str | None):
        self.app, self.hosts, self.token = app, hosts, token

    async def __call__(self, scope, receive, send):
        from starlette.requests import Request
        from starlette.responses import JSONResponse

        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return

        async def secured(message):
            if message["type"] == "http.response.start":
                message["headers"] = [*message.get("headers", []), *SECURITY_HEADERS]
            await send(message)

        refusal = self._refusal(Request(scope))
        app = self.app if refusal is None else JSONResponse({"error": refusal[1]}, status_code=refusal[0])
        await app(scope, receive, secured)

    def _refusal(self, request) -> tuple[int, str] | None:
        host = request.headers.get("host", "")
        if self.hosts is not None and _hostname(host) not in self.hosts:
            return 403, f"the Host header {host!r} does not name this server"
        origin = request.headers.get("origin")
        if origin is not None and origin != f"{request.url.scheme}://{host}":
            return 403, f"requests from {origin} are refused: use this server's own page"
        if self.token and not _has_token(request, self.token):
            return 401, "missing or wrong token"
        media_type = request.headers.get("content-type", "").split(";")[0].strip().lower()
        if request.method == "POST" and media_type != "application/json":
            return 415, "send the body as JSON, with Content-Type: application/json"
        return None


def _hostname(host: str) -> str | None:
    """`[::1]:8765` -> `::1`; None if it is no host name."""
    try:
        return urlsplit(f"//{host}").hostname
    except ValueError:
        return None


def _has_token(request, token: str) -> bool:
    sent = (request.headers.get("authorization", "").removeprefix("Bearer ").strip()
            or request.query_params.get("token", ""))
    return hmac.compare_digest(sent.encode(), token.encode())
