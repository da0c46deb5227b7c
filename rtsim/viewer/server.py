"""`rtsim view`'s web server: one page (rtsim/viewer/web) and one WebSocket per page, on 127.0.0.1 unless
told otherwise (``--bind``).

Why ``websockets`` (and no web framework): one small, dependency-free, well-kept package serves both the
WebSocket and the few static files the page needs (``process_request`` answers plain HTTP GETs); the
page's libraries (three.js, uPlot) come from ``web/node_modules``, installed by ``npm ci`` from the
committed lockfile (tools/setup), and are served from there: nothing loads from the internet.

Per page, over its WebSocket (JSON text messages); a replay (recordings instead of a live service) sends
``hello`` (``source`` replay, ``info.replays`` one scene per recording) and one ``recording`` message per
file (rtsim.viewer.recording), then only answers pings: the page plays them with its timeline.

- server -> page: ``hello`` (the scene: rtsim.viewer.scene.describe; ``source`` live), ``data`` (answer to a
  ``pull``: the samples new since the page's last pull, rtsim.viewer.relay.Relay.batch), ``drive_ack``
  (the service's reply to the page's command, with the page's own stamp and the query's round trip),
  ``pong`` (the server's clock, for the page's clock offset);
- page -> server: ``pull`` (once per drawn frame: the page sets its own rate), ``drive`` (the user's
  commands, rtsim.service.user_input channels), ``reset`` (the service's reset op: the scenario's start
  again), ``fault`` (the faults panel: ``{"op": "inject_fault" | "clear_fault", "args": {...}}``, the
  service's control op of that name, answered ``fault_ack`` with its reply; ``hello`` carries the fault
  catalogue as ``faults``), ``ping``.

Driving guard: a server given a session ``token`` (``rtsim view`` makes one, random, whenever it binds an
address off loopback: ``--web-allow-remote``) takes ``drive``, ``reset`` and ``fault`` only from a page whose
WebSocket URL carries it (``/ws?token=...``: the page passes on its own URL's query, and the URL printed
at start has it). Any other page may watch; its driving requests are answered ``ok: false`` with the
reason, counted in ``refused`` and logged (one line per page). Without a token (loopback) every page
this server served may drive, as the WebSocket's origin check allows.
"""
from __future__ import annotations

import asyncio
import http
import itertools
import json
import mimetypes
import secrets
import sys
import time
import urllib.parse
from pathlib import Path

from rtsim.errors import RtsimError
from rtsim.faults.cli import catalogue_json

from .relay import DriveSender, Relay, encode
from .scene import describe

WEB = Path(__file__).resolve().parent / "web"
NODE = WEB / "node_modules"
#: URL -> file for the libraries (the page's import map names these URLs)
LIBS = {
    "/lib/three.module.js": NODE / "three" / "build" / "three.module.js",
    "/lib/three.core.js": NODE / "three" / "build" / "three.core.js",
    "/lib/OrbitControls.js": NODE / "three" / "examples" / "jsm" / "controls" / "OrbitControls.js",
    "/lib/uPlot.esm.js": NODE / "uplot" / "dist" / "uPlot.esm.js",
    "/lib/uPlot.min.css": NODE / "uplot" / "dist" / "uPlot.min.css",
}
PAGE_FILES = ("index.html", "app.js", "scene.js", "plots.js", "input.js", "style.css")


def check_libraries() -> None:
    """RtsimError naming what is missing when the page's npm packages are not installed."""
    missing = [str(p.relative_to(WEB)) for p in LIBS.values() if not p.is_file()]
    if missing:
        raise RtsimError(f"the page's libraries are not installed ({', '.join(missing)} missing under "
                         f"{WEB}): run ./tools/setup, which runs `npm ci` there (needs node and npm)")


def _file_response(path: Path):
    from websockets.datastructures import Headers
    from websockets.http11 import Response

    body = path.read_bytes()
    ctype = mimetypes.guess_type(path.name)[0] or "application/octet-stream"
    if path.suffix == ".js":
        ctype = "text/javascript"
    headers = Headers([("Content-Type", f"{ctype}; charset=utf-8" if ctype.startswith("text") else ctype),
                       ("Content-Length", str(len(body))), ("Cache-Control", "no-cache"),
                       ("Connection", "close")])
    return Response(200, "OK", headers, body)


class ViewServer:
    """The server (see the module docstring) for one source of samples: a live service (``relay``) or one
    or two recordings (``recordings``: rtsim.viewer.recording.Recording) the page plays with a timeline."""

    def __init__(self, relay: Relay | None, bind: str = "127.0.0.1", port: int = 8470, config_timeout: float = 30.0,
                 recordings=(), token: str | None = None):
        check_libraries()
        self.token = token
        self.refused = 0                                # driving requests refused for want of the token
        self.relay = relay
        self.recordings = list(recordings)
        if (relay is None) == (not self.recordings):
            raise RtsimError("rtsim view: either a live service or recordings, not both")
        self.bind = bind
        self.port = port
        self.config_timeout = config_timeout
        self._info: dict | None = None
        self.pages = 0
        self.loop: asyncio.AbstractEventLoop | None = None
        self._conns: set = set()
        self.drive = DriveSender(relay.client, self._drive_done) if relay is not None else None
        self._drive_from: dict[int, object] = {}        # drive token -> the page that sent it
        self._tokens = itertools.count(1)
        self._server = None

    # -- scene ------------------------------------------------------------------------------------------
    def info(self) -> dict:
        if self._info is None:
            if self.relay is not None:
                self._info = describe(self.relay.config(timeout=self.config_timeout))
            else:
                infos = [describe(r.config) for r in self.recordings]
                self._info = {**infos[0], "replays": [{**i, "road": None, "file": r.path.name}
                                                      for i, r in zip(infos, self.recordings)]}
        return self._info

    # -- HTTP -------------------------------------------------------------------------------------------
    async def _http(self, connection, request):
        path = request.path.split("?", 1)[0]
        if path == "/ws":
            # only pages this server served may open the WebSocket (it drives the car): a browser sends the
            # page's origin, which must be this server's own host and port (no other site the engineer has
            # open can reach it); a client that is not a browser sends no origin
            origin = request.headers.get("Origin")
            if origin is not None and urllib.parse.urlsplit(origin).netloc != request.headers.get("Host"):
                return connection.respond(http.HTTPStatus.FORBIDDEN, f"origin {origin} refused\n")
            return None                               # the WebSocket handshake goes on
        if path == "/":
            path = "/index.html"
        if path in LIBS:
            return _file_response(LIBS[path])
        name = path.lstrip("/")
        if name in PAGE_FILES:
            return _file_response(WEB / name)
        if path == "/api/info":
            from websockets.datastructures import Headers
            from websockets.http11 import Response
            info = await asyncio.get_running_loop().run_in_executor(None, self.info)
            body = encode(info).encode()
            return Response(200, "OK", Headers([("Content-Type", "application/json"),
                                                ("Content-Length", str(len(body))), ("Connection", "close")]), body)
        return connection.respond(http.HTTPStatus.NOT_FOUND, f"not found: {path}\n")

    # -- WebSocket --------------------------------------------------------------------------------------
    def may_drive(self, ws) -> bool:
        """True when this page's WebSocket URL carries the session token (or the server needs none)."""
        if self.token is None:
            return True
        query = urllib.parse.urlsplit(getattr(getattr(ws, "request", None), "path", "") or "").query
        given = urllib.parse.parse_qs(query).get("token", [""])[0]
        return secrets.compare_digest(given.encode(), self.token.encode())

    async def _refuse(self, ws, kind: str, logged: list) -> None:
        """A driving request from a page without the token: counted, logged once per page, answered."""
        self.refused += 1
        if not logged:
            logged.append(True)
            peer = getattr(ws, "remote_address", None)
            print(f"rtsim view: refused a {kind} request from {peer[0] if peer else 'a page'}: no valid session "
                  f"token in its URL ({self.refused} refused so far)", file=sys.stderr, flush=True)
        reply = {"ok": False, "error": f"{kind} refused: this page's URL has no valid session token (open the "
                                       f"URL `rtsim view` printed)"}
        await ws.send(encode({"type": f"{kind}_ack", "seq": None, "reply": reply}))

    async def _fault(self, msg: dict) -> dict:
        """A faults-panel request relayed to the service's control op (which checks its arguments)."""
        op, args = msg.get("op"), msg.get("args")
        if op not in ("inject_fault", "clear_fault") or not isinstance(args, dict):
            return {"ok": False, "error": "fault: give op inject_fault or clear_fault and args (an object)"}
        if "op" in args or "timeout" in args:
            return {"ok": False, "error": f"{op}: unknown argument {'op' if 'op' in args else 'timeout'!r}"}
        try:
            return await asyncio.get_running_loop().run_in_executor(
                None, lambda: self.relay.client.control(op, timeout=10.0, **args))
        except RtsimError as exc:
            return {"ok": False, "error": f"{op}: {exc}"}

    async def _page(self, ws) -> None:
        self.pages += 1
        self._conns.add(ws)
        last: dict[str, int] = {}
        driver = self.may_drive(ws)
        logged: list = []
        try:
            info = await asyncio.get_running_loop().run_in_executor(None, self.info)
            source = "live" if self.relay is not None else "replay"
            await ws.send(encode({"type": "hello", "source": source, "info": info, "server_time": time.time(),
                                  "faults": catalogue_json() if self.relay is not None else [],
                                  "may_drive": driver}))
            for i, rec in enumerate(self.recordings):
                await ws.send(rec.payload(i))
            async for text in ws:
                try:
                    msg = json.loads(text)
                except ValueError:
                    continue
                kind = msg.get("type") if isinstance(msg, dict) else None
                if self.relay is None:
                    if kind == "ping":
                        await ws.send(encode({"type": "pong", "client_time": msg.get("client_time"),
                                              "server_time": time.time()}))
                    continue                        # a recording: the page plays it by itself
                if kind == "pull":
                    await ws.send(self.relay.batch(last))
                elif kind in ("drive", "reset", "fault") and not driver:
                    await self._refuse(ws, kind, logged)
                elif kind == "drive":
                    token = next(self._tokens)
                    self._drive_from[token] = ws
                    msg["_ws"] = token
                    self.drive.submit(msg)
                elif kind == "fault":               # the faults panel: the service's inject/clear ops
                    await ws.send(encode({"type": "fault_ack", "reply": await self._fault(msg)}))
                elif kind == "reset":               # the page's reset button (after a fall, say)
                    reply = await asyncio.get_running_loop().run_in_executor(
                        None, lambda: self.relay.client.control("reset", timeout=30.0))
                    await ws.send(encode({"type": "reset_ack", "reply": reply}))
                elif kind == "ping":
                    await ws.send(encode({"type": "pong", "client_time": msg.get("client_time"),
                                          "server_time": time.time()}))
        except Exception as exc:  # noqa: BLE001  (a page that goes away must not stop the server)
            if not type(exc).__name__.startswith("Connection"):
                try:
                    await ws.send(encode({"type": "error", "error": f"{type(exc).__name__}: {exc}"}))
                except Exception:  # noqa: BLE001
                    pass
        finally:
            self._conns.discard(ws)
            self.pages -= 1

    def _drive_done(self, req: dict, reply: dict, seconds: float) -> None:
        """(DriveSender's thread) the service's reply, back to the page that sent the command."""
        token = req.get("_ws")
        ws = self._drive_from.pop(token, None)
        for k in [k for k in self._drive_from if k < token]:   # replaced by later ones: never answered
            self._drive_from.pop(k, None)
        loop = self.loop
        if ws is None or loop is None or loop.is_closed():
            return
        ack = encode({"type": "drive_ack", "seq": req.get("seq"), "t_page": req.get("t_page"),
                      "query_s": seconds, "reply": reply})
        try:
            loop.call_soon_threadsafe(lambda: asyncio.ensure_future(self._send(ws, ack)))
        except RuntimeError:                             # the server stopped meanwhile
            pass

    @staticmethod
    async def _send(ws, text: str) -> None:
        try:
            await ws.send(text)
        except Exception:  # noqa: BLE001  (the page left)
            pass

    async def serve(self, stop: asyncio.Event, started=None) -> None:
        from websockets.asyncio.server import serve

        self.loop = asyncio.get_running_loop()
        async with serve(self._page, self.bind, self.port, process_request=self._http, max_size=2 ** 20,
                         compression=None) as server:
            self._server = server
            self.port = server.sockets[0].getsockname()[1]
            if started is not None:
                started(self)
            await stop.wait()

    def close(self) -> None:
        if self.drive is not None:
            self.drive.close()
        if self.relay is not None:
            self.relay.close()
