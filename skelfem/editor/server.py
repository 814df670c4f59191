"""The editor's web side: a Starlette app on uvicorn, bound to 127.0.0.1 only.

Routes (the JSON API is documented in docs/guide/editor.md):

    GET  /                 the page (static/index.html, editor.js, editor.css)
    GET  /api/design       the design as loaded: its TOML keys, file name, live parameter keys
    POST /api/solve        body: a design (the TOML's keys) -> result.json's keys + "mesh" + "editor"
    POST /api/ik           body: {"design", "marker", "target"} -> the same + "ik" and "new_design"
    POST /api/save         body: {"design", "name"?, "overwrite"?} -> {"saved", "file"}
    WS   /api/live         the page's solves and IK: {"id", "kind", ...} -> {"id", "ok", "answer" | "error"}
                           ("packed": true: the mesh's coordinates as packed float32, payload.json_default)

Guards: the Host header must be this server's own (``127.0.0.1:PORT`` or
``localhost:PORT``; DNS rebinding) and an Origin header, if any, this
server's page (403 otherwise); POST bodies must be JSON (415), at most
MAX_BODY bytes (413) and well-formed (400); a bad design answers 422 with
``{"error", "key"}``; a request replaced by a newer one of the same client
409 (see skelfem.editor.worker); an unexpected failure 500 and a request
beyond the solver's time or memory budget 503 (skelfem.editor.worker.Budget),
after either the solver starts again from the last design that solved.
Nothing a request sends can stop the server.
"""
from __future__ import annotations

import asyncio
import json
import logging
import socket
import threading
import time
from importlib import resources as importlib_resources
from pathlib import Path

from .payload import json_default

log = logging.getLogger("skelfem")

MAX_BODY = 1 << 20          # bytes of a POST body or a websocket message
HEADER_TIMEOUT = 10.0       # s a connection may take to send a request's headers (then it is closed)
KEEP_ALIVE = 5              # s an idle keep-alive connection is kept
MAX_CONNECTIONS = 256       # open HTTP connections; beyond, the oldest idle one is closed (never a 503)
BACKLOG = 128
STATIC = ("index.html", "editor.js", "editor3d.js", "editor.css")
# The page's own files only; no form may submit anywhere, no <base> may redirect its links, no frame may hold it
CSP = ("default-src 'self'; img-src 'self' data:; style-src 'self'; script-src 'self'; connect-src 'self'; "
       "object-src 'none'; form-action 'none'; base-uri 'none'; frame-ancestors 'none'")
TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8",
         ".css": "text/css; charset=utf-8"}


class EditorError(Exception):
    """The editor cannot start (e.g. the port is taken)."""


class ApiError(Exception):
    def __init__(self, status: int, message: str, key: str = ""):
        super().__init__(message)
        self.status, self.message, self.key = status, message, key


def dumps(value, packed: bool = False) -> str:
    """Strict, compact JSON (the payloads hold no NaN: result.json and the mesh use null); the mesh's arrays
    as lists, or packed (a page that asks: payload.json_default)."""
    return json.dumps(value, allow_nan=False, separators=(",", ":"), default=json_default(packed))


def _reject_constant(name):
    raise ValueError(f"{name} is not JSON")


def loads(data):
    """JSON text or bytes -> value; ApiError 400 for anything malformed (NaN and Infinity included)."""
    try:
        return json.loads(data, parse_constant=_reject_constant)
    except (ValueError, RecursionError) as exc:
        raise ApiError(400, f"malformed JSON: {str(exc)[:200]}") from None


def static_files() -> dict:
    """{name: bytes} of the page, read from the package."""
    root = importlib_resources.files("skelfem.editor") / "static"
    return {name: (root / name).read_bytes() for name in STATIC}


# -- guards ---------------------------------------------------------------------------------------------
class Guard:
    """ASGI middleware: this server's Host only, its own page's Origin only."""

    def __init__(self, app, port_of):
        self.app, self.port_of = app, port_of

    def allowed(self, scope) -> tuple[bool, str]:
        port = self.port_of()
        hosts = {f"127.0.0.1:{port}", f"localhost:{port}"}
        host = origin = None
        for k, v in scope.get("headers", ()):
            if k == b"host":
                if host is not None:
                    return False, "more than one Host header"
                host = v.decode("latin-1")
            elif k == b"origin":
                origin = v.decode("latin-1")
        if host not in hosts:
            return False, f"Host {host!r} is not this server ({' or '.join(sorted(hosts))})"
        if origin is not None and origin not in {f"http://{h}" for h in hosts}:
            return False, f"Origin {origin!r} is not this server's page"
        return True, ""

    async def __call__(self, scope, receive, send):
        if scope["type"] in ("http", "websocket"):
            ok, why = self.allowed(scope)
            if not ok:
                if scope["type"] == "websocket":
                    await receive()                                   # websocket.connect
                    await send({"type": "websocket.close", "code": 1008})
                    return
                body = dumps({"error": why, "key": ""}).encode()
                await send({"type": "http.response.start", "status": 403,
                            "headers": [(b"content-type", b"application/json"),
                                        (b"content-length", str(len(body)).encode())]})
                await send({"type": "http.response.body", "body": body})
                return
        await self.app(scope, receive, send)


async def read_json(request):
    """The request body as JSON: 415 unless application/json, 413 beyond MAX_BODY, 400 if malformed."""
    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if ctype != "application/json":
        raise ApiError(415, "the body must be JSON (Content-Type: application/json)")
    length = request.headers.get("content-length")
    if length is not None and (not length.isdigit() or int(length) > MAX_BODY):
        raise ApiError(413 if length.isdigit() else 400, f"the body must be at most {MAX_BODY} bytes")
    body = bytearray()
    async for chunk in request.stream():
        body += chunk
        if len(body) > MAX_BODY:
            raise ApiError(413, f"the body must be at most {MAX_BODY} bytes")
    return loads(bytes(body))


# -- the app ----------------------------------------------------------------------------------------------
def _live_endpoint(run, error_response):
    """The websocket endpoint: each JSON message a job answered by its id, as the worker finishes it
    (a newer message from the same page supersedes an older one); run(channel, job) hands a job to the
    worker, error_response(exc) is the HTTP answer an exception would get."""
    from starlette.websockets import WebSocketDisconnect

    from .worker import Superseded

    async def live(ws):
        await ws.accept()
        channel = ("ws", id(ws))
        lock = asyncio.Lock()
        tasks = set()

        async def reply(message, packed: bool = False):
            async with lock:
                try:
                    await ws.send_text(dumps(message, packed))
                except Exception:  # noqa: BLE001 - the page went away
                    pass

        async def answer(mid, job, packed: bool):
            try:
                result = await run(channel, job)
                await reply({"id": mid, "ok": True, "answer": result}, packed)
            except Superseded:
                await reply({"id": mid, "dropped": True})
            except Exception as exc:  # noqa: BLE001
                resp = error_response(exc)
                await reply({"id": mid, "ok": False, "status": resp.status_code, **json.loads(resp.body)})

        try:
            while True:
                message = await ws.receive()
                if message["type"] == "websocket.disconnect":
                    break
                text = message.get("text")
                if text is None:
                    await reply({"id": None, "ok": False, "status": 400, "key": "",
                                 "error": "binary frames are not accepted: send each message as JSON text"})
                    continue
                try:
                    msg = loads(text)
                    mid, job = _live_job(msg)
                except ApiError as exc:
                    await reply({"id": None, "ok": False, "status": exc.status, "error": exc.message, "key": ""})
                    continue
                task = asyncio.create_task(answer(mid, job, msg.get("packed") is True))
                tasks.add(task)
                task.add_done_callback(tasks.discard)
        except (WebSocketDisconnect, RuntimeError):
            pass

    return live


def create_app(editor):
    """The Starlette app of an Editor (its worker, design file and port)."""
    from starlette.applications import Starlette
    from starlette.middleware import Middleware
    from starlette.responses import Response
    from starlette.routing import Route, WebSocketRoute

    from .engine import EditError
    from .savefile import SaveError
    from .worker import Closed, OverBudget, Superseded

    files = static_files()
    headers = {"Cache-Control": "no-store", "X-Content-Type-Options": "nosniff", "X-Frame-Options": "DENY",
               "Referrer-Policy": "no-referrer",
               "Content-Security-Policy": CSP}

    def json_response(value, status: int = 200):
        return Response(dumps(value), status, media_type="application/json", headers=headers)

    def error_response(exc):
        if isinstance(exc, ApiError):
            return json_response({"error": exc.message, "key": exc.key}, exc.status)
        if isinstance(exc, (EditError,)):
            return json_response(exc.to_dict(), exc.status)
        if isinstance(exc, SaveError):
            return json_response({"error": exc.message, "key": ""}, exc.status)
        if isinstance(exc, Superseded):
            return json_response({"error": "superseded by a newer request from the same client", "key": ""}, 409)
        if isinstance(exc, (Closed, OverBudget)):
            return json_response({"error": str(exc), "key": ""}, 503)
        return json_response({"error": f"internal error: {type(exc).__name__}: {exc}"[:500], "key": ""}, 500)

    async def run(channel, job):
        return await asyncio.wrap_future(editor.worker.submit(channel, job))

    def endpoint(fn):
        async def wrapped(request):
            try:
                return await fn(request)
            except Exception as exc:  # noqa: BLE001 - every failure is an answer, never a crash
                return error_response(exc)
        return wrapped

    async def page(request):
        return Response(files["index.html"], media_type=TYPES[".html"], headers=headers)

    async def static(request):
        name = request.path_params["name"]
        if name not in files:
            return json_response({"error": "not found", "key": ""}, 404)
        return Response(files[name], media_type=TYPES[Path(name).suffix], headers=headers)

    @endpoint
    async def design(request):
        return json_response(await run(("api", "design"), lambda e: editor.describe()))

    @endpoint
    async def solve(request):
        body = await read_json(request)
        answer = await run(("api", "solve"), lambda e: e.solve(body))
        if request.query_params.get("mesh") == "0":
            answer = dict(answer, mesh=None)
        return json_response(answer)

    @endpoint
    async def ik(request):
        body = await read_json(request)
        if not isinstance(body, dict):
            raise ApiError(400, 'the body must be {"design": {...}, "marker": NAME, "target": [x, y]}')
        answer = await run(("api", "ik"), lambda e: e.ik(body.get("design"), body.get("marker"), body.get("target"),
                                                 final=True))
        return json_response(answer)

    @endpoint
    async def save(request):
        body = await read_json(request)
        if not isinstance(body, dict) or not isinstance(body.get("design"), dict):
            raise ApiError(400, 'the body must be {"design": {...}, "name": "NEW.toml" (optional)}')
        return json_response(await run(("api", "save"), lambda e: editor.save(body["design"], body.get("name"),
                                                                     bool(body.get("overwrite", False)))))

    live = _live_endpoint(run, error_response)

    async def favicon(request):
        return Response(b"", 204, headers=headers)

    routes = [Route("/", page), Route("/favicon.ico", favicon), Route("/static/{name}", static),
              Route("/api/design", design),
              Route("/api/solve", solve, methods=["POST"]), Route("/api/ik", ik, methods=["POST"]),
              Route("/api/save", save, methods=["POST"]), WebSocketRoute("/api/live", live)]
    return Starlette(routes=routes, middleware=[Middleware(Guard, port_of=lambda: editor.port)])


def _live_job(msg):
    """(id, job) of one websocket message; ApiError 400 for a malformed one."""
    if not isinstance(msg, dict) or not isinstance(msg.get("id"), int) or isinstance(msg.get("id"), bool):
        raise ApiError(400, 'a message is {"id": N, "kind": "solve" | "ik", "design": {...}, ...}')
    mid, kind = msg["id"], msg.get("kind")
    if kind == "solve":
        have = msg.get("have")           # the mesh the page holds: its cells and regions are not sent again
        return mid, lambda e: e.solve(msg.get("design"), draft=bool(msg.get("draft", False)),
                                      framed=bool(msg.get("frame", False)),
                                      have=have if isinstance(have, str) else None,
                                      fields=bool(msg.get("fields", True)))
    if kind == "ik":
        return mid, lambda e: e.ik(msg.get("design"), msg.get("marker"), msg.get("target"),
                                   final=bool(msg.get("final", True)))
    raise ApiError(400, f"unknown kind {str(kind)[:40]!r} (solve or ik)")


# -- the editor: engine, worker, app, server ------------------------------------------------------------
def bind(host: str, port: int) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        raise EditorError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from None
    sock.listen(BACKLOG)
    sock.set_inheritable(True)
    return sock


class Editor:
    """A design file, the engine solving it on a worker thread, and the server on 127.0.0.1:port.

    The first solve happens here, in the caller's thread; then ``run()`` serves
    until Ctrl-C (main thread), or ``start()`` / ``stop()`` serve from a thread
    (tests, the latency study). DesignError for a bad design, EditorError if the
    port cannot be had.
    """

    HOST = "127.0.0.1"

    def __init__(self, path, port: int = 0, max_dofs=None, budget=None):
        from ..design.parse import load_design
        from .engine import Engine
        from .worker import Worker

        self.path = Path(path).absolute()
        self.folder = self.path.parent.resolve()
        design = load_design(self.path)
        self.sock = bind(self.HOST, port)
        self.port = self.sock.getsockname()[1]
        try:
            self.engine = Engine(design.raw, self.path.name, max_dofs=max_dofs)
        except BaseException:
            self.sock.close()
            raise
        self.worker = Worker(self.engine, on_error=self._recover, budget=budget)
        self.app = create_app(self)
        self.server = None
        self._thread = None

    @property
    def url(self) -> str:
        return f"http://{self.HOST}:{self.port}/"

    def _recover(self, exc) -> None:
        from ..design.spec import DesignError
        from .engine import EditError
        from .savefile import SaveError
        from .worker import Cancel
        if isinstance(exc, (EditError, DesignError, SaveError)):
            return
        if not isinstance(exc, Cancel):                  # a job over budget: the watchdog has said so
            log.warning("editor: %s: %s; starting the solver again from the last design that solved",
                        type(exc).__name__, exc)
        self.engine.recover()

    # -- requests the worker runs ---------------------------------------------------------------------------
    def describe(self) -> dict:
        self.engine.ensure()
        d = self.engine.design
        return {"design": d.raw, "saved": self._on_disk(d.raw), "file": self.path.name, "folder": str(self.folder),
                "dim": d.dim, "readonly": False, "parameters": sorted(self.engine.session.model.parameters()),
                "first": self.engine.first if self.engine.first.get("converged") else None}

    def _on_disk(self, fallback: dict) -> dict:
        """The design file's keys as they are on disk (the page's baseline for unsaved changes); the
        current design if the file cannot be read as TOML any more."""
        import tomllib

        from ..design.parse import MAX_FILE
        from ..io.files import read_bounded
        try:
            return tomllib.loads(read_bounded(self.path, MAX_FILE, "design file"))
        except (OSError, ValueError):
            return fallback

    def save(self, design: dict, name: str | None, overwrite: bool) -> dict:
        from ..io.files import write_text
        from .savefile import SaveError, render, target
        d = self.engine.parse(design, budget=False)      # saving needs no solve
        if d.dim != self.engine.design.dim:              # one design per server: its file keeps its dimension
            raise SaveError(f"{self.path.name}: dim: the editor holds a {self.engine.design.dim}D design and "
                            f"cannot write a {d.dim}D one over it; edit the TOML file instead", 422)
        path = target(self.folder, self.path, name)
        if name is not None and path.exists() and path != self.path and not overwrite:
            raise SaveError(f"{path.name} exists; save with overwrite to replace it", 409)
        from ..design.parse import MAX_FILE
        from ..io.files import read_bounded
        try:
            base = read_bounded(self.path, MAX_FILE, "design file")     # the file on disk may have grown
        except (OSError, ValueError):
            base = ""
        try:
            text = render(base, d.raw, default_name=self.path.stem)
        except SaveError:
            raise
        except Exception:  # noqa: BLE001 - the file on disk is no longer TOML: write the design plainly
            text = render("", d.raw, default_name=self.path.stem)
        try:
            write_text(path, text)
        except OSError as exc:
            raise SaveError(f"cannot write {path.name}: {exc.strerror or exc}", 500) from None
        self.path = path
        return {"saved": str(path), "file": path.name, "bytes": len(text.encode())}

    # -- serving ------------------------------------------------------------------------------------------------
    def _server(self):
        import uvicorn

        from .connections import one_line_logs, protocol_class
        one_line_logs()
        config = uvicorn.Config(self.app, log_config=None, log_level="warning", access_log=False, lifespan="off",
                                http=protocol_class(HEADER_TIMEOUT, MAX_CONNECTIONS),
                                ws="websockets", ws_max_size=MAX_BODY, ws_per_message_deflate=False,
                                limit_concurrency=None, timeout_keep_alive=KEEP_ALIVE, backlog=BACKLOG)
        worker = self.worker

        class Server(uvicorn.Server):
            async def shutdown(self, sockets=None):
                worker.abandon()          # requests waiting for a solve answer 503 now: nothing waits for it
                await super().shutdown(sockets)

        self.server = Server(config)
        return self.server

    def run(self, open_browser: bool = False) -> None:
        """Serve until Ctrl-C / SIGTERM (uvicorn's handlers in the main thread), then stop the solver."""
        server = self._server()
        if open_browser:
            threading.Thread(target=self._open_browser, daemon=True).start()
        try:
            server.run(sockets=[self.sock])
        finally:
            self.close()

    def _open_browser(self) -> None:
        import webbrowser
        for _ in range(100):
            if self.server is not None and self.server.started:
                break
            time.sleep(0.05)
        webbrowser.open(self.url)

    def start(self, timeout: float = 30.0) -> "Editor":
        """Serve from a background thread; returns once the server accepts connections."""
        server = self._server()
        self._thread = threading.Thread(target=server.run, kwargs={"sockets": [self.sock]}, daemon=True)
        self._thread.start()
        t_end = time.monotonic() + timeout
        while not server.started:
            if time.monotonic() > t_end or not self._thread.is_alive():
                raise EditorError("the editor's server did not start")
            time.sleep(0.02)
        return self

    def stop(self) -> None:
        if self.server is not None:
            self.server.should_exit = True
        if self._thread is not None:
            self._thread.join(10)
        self.close()

    @property
    def busy(self) -> bool:
        """The solver thread is still in a job (after close(): one that nobody waits for)."""
        return self.worker.busy

    def close(self, timeout: float = 1.0) -> None:
        """Stop the solver without waiting for a running solve (it is abandoned, then dropped at exit)."""
        self.worker.abandon()
        if self.worker.close(timeout):
            self.engine.close()
        else:
            log.warning("editor: stopped during a solve; it is abandoned")
        self.sock.close()
