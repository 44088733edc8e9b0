"""The web application of ``refine serve``: the page, its websocket, the access token and writing.

Built on Starlette (routing, websockets, responses) served by uvicorn. Every request passes
:class:`Guard` first: without ``--host`` only the names of the loopback interface are accepted as
``Host`` (a page elsewhere cannot rebind a name to it); with ``--host`` every request must carry
the printed access token (``?token=``, the ``X-Refine-Token`` header, or the cookie the page
gets), compared in constant time. A request with an ``Origin`` of another site is refused.

The browser names no file but calibration measurements, which must lie inside the problem folder
(:func:`refine.serve.calibration.inside_folder`): the problem file is the one the app was started
on, the outputs go to the folder given on the command line, and ``/files/NAME`` serves only a file
written there.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import json
import logging
import threading
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from http.cookies import SimpleCookie
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlsplit

import anyio
from plotly.offline import get_plotlyjs
from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import FileResponse, HTMLResponse, JSONResponse, PlainTextResponse, Response
from starlette.routing import Route, WebSocketRoute
from starlette.websockets import WebSocket, WebSocketDisconnect

from refine.errors import InputError, RefineError
from refine.report.html import ERRORS_JS
from refine.serve.session import Answer, LatestSolver, Session
from refine.serve.state import SceneDiff, values_of, verdict_message

log = logging.getLogger(__name__)

LOOPBACK_NAMES = ("127.0.0.1", "localhost", "[::1]", "::1")
"""The ``Host`` names accepted without ``--host``."""
TOKEN_COOKIE = "refine_token"
"""The cookie that carries the access token after the first page load."""
MAX_MESSAGE_BYTES = 64_000
"""The largest message the page may send [bytes]."""


@dataclass
class Hub:
    """The open websockets, and the last messages a newly opened one is sent first."""

    loop: asyncio.AbstractEventLoop | None = None
    queues: set[asyncio.Queue] = field(default_factory=set)
    last: dict[str, str] = field(default_factory=dict)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def publish(self, kind: str, text: str, keep: str | None = None) -> None:
        """Send ``text`` to every open websocket (from any thread).

        ``keep`` (``text`` when None) is kept as the last ``kind``, sent first to a websocket opened later.
        """
        with self.lock:
            self.last[kind] = text if keep is None else keep
            loop, queues = self.loop, list(self.queues)
        if loop is None or loop.is_closed():
            return
        for q in queues:
            loop.call_soon_threadsafe(q.put_nowait, text)


class SceneBuilder:
    """Builds and publishes the scene of the newest answer on its own thread; older ones waiting are skipped.

    The verdict is published on the solver's thread as soon as the solve ends; the scene (paths,
    robot poses, motions, about 13 ms of CPU on the glass cell, the cell and the robot's shapes
    reused) follows from here, so a change made meanwhile is solved at once and a scene overtaken by a newer answer is never built. The thread
    is a :class:`refine.serve.session.LatestSolver` whose job is an :class:`Answer`.
    """

    def __init__(self, hub: Hub) -> None:
        self.hub, self.scenes = hub, SceneDiff()
        self._worker = LatestSolver(
            lambda answer: self.scenes.messages(answer), self._built, name="refine-serve-scene"
        )

    @property
    def built(self) -> int:
        """How many scenes were built."""
        return self._worker.solved

    @property
    def skipped(self) -> int:
        """How many answers were overtaken before their scene was built."""
        return self._worker.dropped

    def submit(self, answer: Answer) -> None:
        """Build the scene of ``answer`` next (an answer still waiting is skipped)."""
        self._worker.submit(answer)

    def stop(self, timeout_s: float = 5.0) -> None:
        """End the thread after the scene under way [s to wait for it]."""
        self._worker.stop(timeout_s)

    def _built(self, answer: Answer, messages: tuple[str, str] | None, error: BaseException | None) -> None:
        if error is not None:  # the verdict is out already; the page keeps the scene it has
            log.error("serve: the scene of revision %d failed", answer.revision, exc_info=error)
            return
        changed, whole = messages
        self.hub.publish("scene", changed, keep=whole)


class Guard:
    """ASGI middleware: the host check, the origin check and the access token (module docstring)."""

    def __init__(self, app: Any, token: str | None) -> None:
        self.app, self.token = app, token

    def _refuse(self, scope: dict[str, Any]) -> str | None:
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers", [])}
        host = headers.get("host", "")
        name = host.rsplit(":", 1)[0] if not host.startswith("[") else host.split("]")[0] + "]"
        if self.token is None and name not in LOOPBACK_NAMES:
            return f"host {host!r} refused: the app answers on the loopback interface only (start it with --host)"
        origin = headers.get("origin")
        if origin is not None and urlsplit(origin).netloc != host:
            return f"origin {origin!r} refused: only the app's own page may call it"
        if self.token is None:
            return None
        given = parse_qs(scope.get("query_string", b"").decode("latin-1")).get("token", [""])[0]
        given = given or headers.get("x-refine-token", "")
        if not given and "cookie" in headers:
            cookie = SimpleCookie()
            cookie.load(headers["cookie"])
            given = cookie[TOKEN_COOKIE].value if TOKEN_COOKIE in cookie else ""
        if not hmac.compare_digest(given.encode(), self.token.encode()):
            return "access token missing or wrong: open the address the server printed"
        return None

    async def __call__(self, scope: dict[str, Any], receive: Callable, send: Callable) -> None:
        """Refuse the request (403, or close the websocket with 1008) or pass it on."""
        if scope["type"] in ("http", "websocket"):
            why = self._refuse(scope)
            if why is not None:
                if scope["type"] == "websocket":
                    await send({"type": "websocket.close", "code": 1008, "reason": why[:120]})
                    return
                await PlainTextResponse(why, status_code=403)(scope, receive, send)
                return
        await self.app(scope, receive, send)


def create_app(session: Session, out_dir: Path, *, token: str | None = None) -> Starlette:
    """The application serving ``session``; outputs are written into ``out_dir``.

    Args:
        session: the problem being edited (not yet started: the app starts its first solve).
        out_dir: where "write" puts the outputs (``refine run``'s ``--out``).
        token: the access token every request must carry, or None for the loopback interface only.
    """
    hub = Hub()
    out_dir = Path(out_dir).resolve()
    plotly_js = get_plotlyjs()

    scenes = SceneBuilder(hub)

    def answered(answer: Answer) -> None:  # on the solver's thread
        hub.publish("verdict", json.dumps(verdict_message(session, answer), allow_nan=False))
        if answer.error is None and answer.result is not None:
            scenes.submit(answer)  # built on its own thread: the next solve need not wait for it

    session.on_answer(answered)

    async def page(request: Request) -> Response:
        from refine.serve.page import page_html

        response = HTMLResponse(page_html(session.problem.name, ERRORS_JS))
        if token is not None:
            response.set_cookie(TOKEN_COOKIE, token, httponly=True, samesite="strict")
        return response

    async def script(request: Request) -> Response:
        from refine.serve.page import page_script

        return Response(page_script(), media_type="text/javascript")

    async def module(request: Request) -> Response:
        from refine.serve.page import module_script

        try:
            text = module_script(request.path_params.get("name") or request.url.path.rsplit("/", 1)[-1])
        except KeyError:
            return PlainTextResponse("no such script", status_code=404)
        return Response(text, media_type="text/javascript")

    async def no_icon(request: Request) -> Response:
        return Response(status_code=204)

    async def plotly(request: Request) -> Response:
        return Response(plotly_js, media_type="text/javascript")

    async def change(request: Request) -> Response:
        try:
            body = await _body(request)
            revision = await anyio.to_thread.run_sync(session.change, body.get("changes", {}))
        except InputError as e:
            return JSONResponse({"error": str(e)}, status_code=400)
        _pending(hub, session, revision)
        return JSONResponse({"revision": revision})

    async def reset(request: Request) -> Response:
        revision = await anyio.to_thread.run_sync(session.reset)
        _pending(hub, session, revision)
        return JSONResponse({"revision": revision})

    async def calibrate(request: Request) -> Response:
        from refine.serve.calibration import fit

        try:
            body = await _body(request)
            return JSONResponse(await anyio.to_thread.run_sync(fit, session.problem, body))
        except InputError as e:
            return JSONResponse({"error": str(e)}, status_code=400)

    async def diff(request: Request) -> Response:
        return JSONResponse({"diff": await anyio.to_thread.run_sync(session.diff)})

    async def write(request: Request) -> Response:
        try:
            result = await anyio.to_thread.run_sync(session.write, out_dir)
        except RefineError as e:
            return JSONResponse({"error": str(e)}, status_code=400)
        files = sorted(Path(p).name for p in result.outputs.values())
        _pending(hub, session, session.revision)
        return JSONResponse({"status": result.status, "files": files, "out": str(out_dir)})

    async def written(request: Request) -> Response:
        name = request.path_params["name"]
        target = (out_dir / name).resolve()
        if target.parent != out_dir or not target.is_file():
            return JSONResponse(
                {"error": f"{name!r}: not a file the app wrote into {out_dir}"}, status_code=404
            )
        return FileResponse(target)

    async def socket(websocket: WebSocket) -> None:
        await websocket.accept()
        queue: asyncio.Queue = asyncio.Queue()
        with hub.lock:
            hub.loop = asyncio.get_running_loop()
            hub.queues.add(queue)
            first = [hub.last[k] for k in ("verdict", "scene") if k in hub.last]
        for text in first:
            await websocket.send_text(text)

        async def forward() -> None:
            while True:
                await websocket.send_text(await queue.get())

        sender = asyncio.create_task(forward())
        try:
            while True:
                text = await websocket.receive_text()
                reply = await _on_message(session, hub, text)
                if reply is not None:
                    await websocket.send_text(json.dumps(reply))
        except WebSocketDisconnect:
            pass
        finally:
            sender.cancel()
            with hub.lock:
                hub.queues.discard(queue)

    @contextlib.asynccontextmanager
    async def lifespan(app: Starlette) -> AsyncIterator[None]:
        hub.loop = asyncio.get_running_loop()
        session.start()
        try:
            yield
        finally:
            session.close()
            scenes.stop()

    routes = [
        Route("/", page),
        Route("/page.js", script),
        Route("/scene3d.js", module),
        Route("/three/{name:path}", module),
        Route("/plotly.js", plotly),
        Route("/favicon.ico", no_icon),
        Route("/api/change", change, methods=["POST"]),
        Route("/api/reset", reset, methods=["POST"]),
        Route("/api/diff", diff),
        Route("/api/calibrate", calibrate, methods=["POST"]),
        Route("/api/write", write, methods=["POST"]),
        Route("/files/{name:path}", written),
        WebSocketRoute("/ws", socket),
    ]
    app = Starlette(routes=routes, lifespan=lifespan)
    app.add_middleware(Guard, token=token)
    return app


async def _body(request: Request) -> dict[str, Any]:
    raw = await request.body()
    if len(raw) > MAX_MESSAGE_BYTES:
        raise InputError(f"a change of {len(raw)} bytes is too large (limit {MAX_MESSAGE_BYTES} bytes)")
    try:
        body = json.loads(raw or b"{}")
    except ValueError as e:
        raise InputError(f"a change must be JSON: {e}") from e
    if not isinstance(body, dict):
        raise InputError("a change must be a JSON object")
    return body


def _pending(hub: Hub, session: Session, revision: int) -> None:
    hub.publish(
        "pending", json.dumps({"type": "pending", "revision": revision, "values": values_of(session)})
    )


async def _on_message(session: Session, hub: Hub, text: str) -> dict[str, Any] | None:
    """Handle one websocket message; the reply for that socket alone (an error), or None."""
    try:
        if len(text) > MAX_MESSAGE_BYTES:
            raise InputError(f"a message of {len(text)} bytes is too large (limit {MAX_MESSAGE_BYTES} bytes)")
        try:
            msg = json.loads(text)
        except ValueError as e:
            raise InputError(f"a message must be JSON: {e}") from e
        if not isinstance(msg, dict) or msg.get("type") != "change":
            raise InputError('a message must be {"type": "change", "changes": {...}}')
        revision = await anyio.to_thread.run_sync(session.change, msg.get("changes", {}))
    except InputError as e:
        return {"type": "error", "message": str(e)}
    _pending(hub, session, revision)
    return None
