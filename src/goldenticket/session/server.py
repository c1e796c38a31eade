"""The session's web app: the robot's JSON API and the operator's page, on Starlette + uvicorn.

    GET  /api/next    -> {"episode", "ticket_id", "noise", "gaussian_seed"} or {"done": true}
    POST /api/score   {"episode": int, "success": bool, "note"?: str, "scene"?: str} -> 200;
                      409 if scored already; 400 with a message if malformed
    POST /api/undo    -> {"undone": episode or null}
    GET  /api/status  -> {"scored", "total", "due", ...} and "verdict" once every episode is scored
    GET  /verdict.png -> the verdict plot, once done
    GET  /            -> the operator's page (never shows which arm runs)

Bound to 127.0.0.1 by default; any other interface needs a token, sent as
`Authorization: Bearer <token>` or `?token=<token>`.
"""

from __future__ import annotations

import json
import socket
import tempfile
from importlib.resources import files
from pathlib import Path

from goldenticket.errors import UserError
from goldenticket.session.protocol import ScoreConflict, Session

LOCAL_HOSTS = ("127.0.0.1", "localhost", "::1")


def make_app(folder: str | Path, token: str | None = None):
    """The ASGI app for one session folder."""
    from starlette.applications import Starlette
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
        try:
            body = _json(await request.body())
            episode, success = _score_fields(body)
            session.score(episode, success, body.get("note") or "", body.get("scene"))
        except ScoreConflict as e:
            return JSONResponse({"error": str(e)}, status_code=409)
        except ValueError as e:  # malformed JSON or fields
            return JSONResponse({"error": str(e)}, status_code=400)
        return JSONResponse({"ok": True, "status": _public(session.status(), session)})

    async def undo(request):
        return JSONResponse({"undone": session.undo()})

    async def status(request):
        return JSONResponse(_public(session.status(), session))

    async def verdict_png(request):
        done = session.status()
        if "verdict" not in done:
            return JSONResponse({"error": "the session is not finished"}, status_code=404)
        return Response(_verdict_png(done["verdict"]), media_type="image/png")

    routes = [Route("/", index), Route("/api/next", next_episode), Route("/api/status", status),
              Route("/api/score", score, methods=["POST"]), Route("/api/undo", undo, methods=["POST"]),
              Route("/verdict.png", verdict_png)]
    middleware = [Middleware(_TokenGate, token=token)] if token else []
    return Starlette(routes=routes, middleware=middleware)


def serve(folder: str | Path, host: str = "127.0.0.1", port: int = 8765, token: str | None = None) -> None:
    """Run the app until interrupted; refuses a non-local interface without a token."""
    import uvicorn

    if host not in LOCAL_HOSTS and not token:
        raise UserError(f"binding to {host} exposes the session to the network: pass --token")
    if not 0 < port < 65536:
        raise UserError(f"--port must be in 1..65535, got {port}")
    app = make_app(folder, token)
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


def _json(raw: bytes):
    try:
        return json.loads(raw)
    except ValueError as e:
        raise ValueError(f"the body is not JSON ({e})") from None


def _score_fields(body) -> tuple[int, bool]:
    if not isinstance(body, dict):
        raise ValueError("the body must be a JSON object")
    episode, success = body.get("episode"), body.get("success")
    if not isinstance(episode, int) or isinstance(episode, bool):
        raise ValueError("'episode' must be an integer")
    if not isinstance(success, bool):
        raise ValueError("'success' must be true or false")
    for key in ("note", "scene"):
        if body.get(key) is not None and not isinstance(body[key], str):
            raise ValueError(f"'{key}' must be a string")
    return episode, success


def _public(status: dict, session: Session) -> dict:
    """Status plus the episode due next, by number only: the operator must not learn the arm."""
    due = session.next()
    return {**status, "due": None if due is None else due.episode}


def _verdict_png(verdict: dict) -> bytes:
    from goldenticket.plots import arms_png

    with tempfile.TemporaryDirectory() as tmp:
        return arms_png(verdict["arms"], Path(tmp) / "verdict.png", "Session verdict",
                        what="confirm-phase success", unit="episodes per arm").read_bytes()


class _TokenGate:
    """Refuses every request without the session token (header or query)."""

    def __init__(self, app, token: str):
        self.app, self.token = app, token

    async def __call__(self, scope, receive, send):
        from starlette.requests import Request
        from starlette.responses import JSONResponse

        if scope["type"] == "http":
            request = Request(scope)
            sent = request.headers.get("authorization", "").removeprefix("Bearer ").strip()
            if self.token not in (sent, request.query_params.get("token")):
                await JSONResponse({"error": "missing or wrong token"}, status_code=401)(scope, receive, send)
                return
        await self.app(scope, receive, send)
