"""The viewer's web server: one page, the recorded episodes under a path, and live envs.

Routes: ``/`` the page and ``/static/viz.js``, ``/static/viz.css`` its files (shipped in the
package; nothing is fetched from the network, no other file is served); ``/api/episodes`` the list
of recorded episodes and whether a live env is connected; ``/api/episodes/{i}`` one episode as
JSON; ``/ws/source`` where live envs (``smarts.viz.live``) send episodes and frames; ``/ws/live``
where pages receive them. The server tells sources whether any page is watching, so unwatched
envs build no frames.

The viewer has no authentication, so it trusts only this machine: it binds 127.0.0.1 unless told
otherwise (any other address needs ``allow_remote``), and every request and websocket must name it
in its ``Host`` header (``localhost``, ``127.0.0.1`` or ``[::1]`` with the bound port), with an
``Origin``, when a browser sends one, of that same address. Anything else is answered 403 (a
websocket is closed with code 1008), so a web page elsewhere can neither read the episodes nor push
one, DNS rebinding included. ``allow_remote`` also accepts an IP address or this machine's own
name as the host. Every response carries a Content-Security-Policy that allows only the page's own
script, style and server. Live messages are checked field by field (``smarts.viz.schema``) and
re-serialised, within the byte limits below; frames nobody watches are dropped.
"""

from __future__ import annotations

import asyncio
import errno
import ipaddress
import json
import logging
import re
import socket
import sys
from collections import deque
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from starlette.applications import Starlette
from starlette.responses import FileResponse, JSONResponse, PlainTextResponse, Response
from starlette.routing import Route, WebSocketRoute
from starlette.types import ASGIApp, Message, Receive, Scope, Send
from starlette.websockets import WebSocket, WebSocketDisconnect

from smarts.viz.live import DEFAULT_HOST, DEFAULT_PORT
from smarts.viz.schema import EpisodeMessage, MessageError, parse_message
from smarts.viz.sources import EpisodeEntry, episode_json, find_episodes

log = logging.getLogger("smarts.viz")

STATIC_DIR = Path(__file__).parent / "static"
STATIC_FILES = {"viz.js": "text/javascript; charset=utf-8", "viz.css": "text/css; charset=utf-8"}
"""The only files under ``/static``; any other name is 404 (no path reaches the file system)."""
MAX_EPISODE_BYTES = 16 * 2**20
"""Largest websocket message the server reads (an episode: metadata and the map description)."""
MAX_FRAME_BYTES = 2 * 2**20
"""Largest live frame (about 30,000 vehicles); a longer one closes the source (code 1009)."""
LIVE_HISTORY = 3000
"""Most frames of the current live episode kept for pages that connect later (seek back)."""
LIVE_HISTORY_BYTES = 64 * 2**20
"""Most bytes those frames may hold together; the oldest go first. Only the current episode is
kept, and frames that arrive while no page watches are not kept at all."""
SEND_TIMEOUT = 10.0
"""Seconds a page may take to take one message before it is disconnected (a stalled page must
not stall the relay)."""
CONTENT_SECURITY_POLICY = (
    "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data:; "
    "connect-src 'self' ws://{host} wss://{host}; object-src 'none'; base-uri 'none'; form-action 'none'; "
    "frame-ancestors 'none'"
)
"""No inline script or style, nothing from elsewhere; ``{host}``: the request's checked Host."""


def is_loopback(host: str) -> bool:
    """Whether ``host`` names this machine only (127.0.0.0/8, ::1 or ``localhost``)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_bind(host: str, allow_remote: bool) -> str | None:
    """Refuse a non-loopback ``host`` without ``allow_remote`` (``ValueError`` saying so); with it,
    return the warning to print."""
    if is_loopback(host):
        return None
    if not allow_remote:
        raise ValueError(
            f"--host {host}: refusing to serve beyond this machine; the viewer has no authentication and "
            f"shows everything under its path. Use --host 127.0.0.1 (the default), or add --allow-remote "
            f"to serve on {host} anyway"
        )
    return f"warning: serving on {host}: anyone who can reach this address can view these episodes (no authentication)"


# ---------------------------------------------------------------------------------- Host and Origin
_NAME = re.compile(r"[a-z0-9](?:[a-z0-9.-]{0,251}[a-z0-9])?")


def split_host(value: str, default_port: int) -> tuple[str, int] | None:
    """``(name, port)`` of a ``Host`` value (``name``, ``name:port``, ``[v6]`` or ``[v6]:port``),
    lower-cased; None when it is not one."""
    value = value.strip().lower()
    if value.startswith("["):
        name, sep, rest = value[1:].partition("]")
        if not sep:
            return None
        try:
            name = str(ipaddress.IPv6Address(name))
        except ValueError:
            return None
    else:
        name, colon, port = value.partition(":")
        rest = colon + port
        if not _NAME.fullmatch(name):
            return None
    if not rest:
        return name, default_port
    port = rest[1:]
    if rest[0] != ":" or not (port.isascii() and port.isdigit() and len(port) <= 5) or int(port) > 65535:
        return None
    return name, int(port)


class AccessPolicy:
    """Which ``Host`` and ``Origin`` a request may carry (see the module docstring)."""

    def __init__(self, allow_remote: bool = False, names: Iterable[str] = ()):
        self.allow_remote = allow_remote
        self.names = {n.lower().strip("[]") for n in names if n}
        if allow_remote:
            self.names |= {socket.gethostname().lower(), socket.getfqdn().lower()}

    def allows_name(self, name: str) -> bool:
        """Whether a Host may name this server ``name`` (loopback always; more with allow_remote)."""
        if is_loopback(name):
            return True
        if not self.allow_remote:
            return False
        if name in self.names:
            return True
        try:  # an address cannot be rebound to another machine the way a DNS name can
            ipaddress.ip_address(name)
            return True
        except ValueError:
            return False

    def refusal(self, headers: dict[str, str], port: int | None, secure: bool = False) -> str | None:
        """Why a request with these headers (lower-case names) to the server's ``port`` is refused;
        None when it is allowed."""
        raw_host = headers.get("host")
        if raw_host is None:
            return "no Host header"
        host = split_host(raw_host, 443 if secure else 80)
        if host is None or not self.allows_name(host[0]):
            return f"Host {raw_host[:100]!r} is not this machine"
        if port is not None and host[1] != port:
            return f"Host {raw_host[:100]!r} names port {host[1]}, this server listens on {port}"
        origin = headers.get("origin")
        if origin is not None:
            scheme, sep, rest = origin.partition("://")
            scheme = scheme.lower()
            if scheme not in ("http", "https") or not sep or "/" in rest:
                return f"Origin {origin[:100]!r} is not a page of this server"
            if split_host(rest, 443 if scheme == "https" else 80) != host:
                return f"Origin {origin[:100]!r} is not a page of this server ({raw_host[:100]})"
        return None


class GuardMiddleware:
    """Refuses requests and websockets from elsewhere (``AccessPolicy``) before any route runs, and
    adds the security headers to every response."""

    def __init__(self, app: ASGIApp, policy: AccessPolicy):
        self.app = app
        self.policy = policy

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers: dict[str, str] = {}
        for k, v in scope.get("headers", []):
            name = k.decode("latin-1").lower()
            if name in headers and name in ("host", "origin"):
                headers[name] = "(more than one)"  # never allowed
            else:
                headers[name] = v.decode("latin-1")
        server = scope.get("server")
        port = server[1] if server and len(server) > 1 else None
        secure = scope.get("scheme") in ("https", "wss")
        why = self.policy.refusal(headers, port, secure)
        if why is not None:
            log.warning("smarts viz: refused %s %s: %s", scope["type"], scope.get("path", "")[:200], why)
            if scope["type"] == "http":
                await PlainTextResponse(f"forbidden: {why}\n", status_code=403)(scope, receive, send)
            else:
                await _close_websocket(receive, send, 1008, why)
            return
        if scope["type"] == "websocket":
            await self.app(scope, receive, send)
            return
        csp = CONTENT_SECURITY_POLICY.format(host=headers["host"].strip().lower()).encode("latin-1")

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                message["headers"] = [
                    *message.get("headers", []),
                    (b"content-security-policy", csp),
                    (b"x-content-type-options", b"nosniff"),
                    (b"referrer-policy", b"no-referrer"),
                    (b"cross-origin-resource-policy", b"same-origin"),
                ]
            await send(message)

        await self.app(scope, receive, send_with_headers)


async def _close_websocket(receive: Receive, send: Send, code: int, reason: str) -> None:
    """Complete the handshake only to close with ``code`` and ``reason`` (nothing else is sent)."""
    message = await receive()
    if message["type"] != "websocket.connect":
        return
    await send({"type": "websocket.accept"})
    await send({"type": "websocket.close", "code": code, "reason": _short(reason)})


def _short(reason: str) -> str:
    """A close reason within the protocol's 123 bytes."""
    data = reason.encode()
    return reason if len(data) <= 123 else data[:120].decode(errors="ignore") + "..."


# ---------------------------------------------------------------------------------- live episodes
class MessageTooLarge(MessageError):
    """A source's message over its byte limit (the websocket closes with code 1009)."""


class LiveHub:
    """Relays the live env's episode and frames to every connected page; keeps the current
    episode and its newest frames (``LIVE_HISTORY``, ``LIVE_HISTORY_BYTES``) for pages that
    connect later."""

    def __init__(self, history: int = LIVE_HISTORY, history_bytes: int = LIVE_HISTORY_BYTES):
        self.episode: str | None = None
        self.lanes: int | None = None
        self.signals: int | None = None
        self.frames: deque[str] = deque()
        self.frame_bytes = 0
        self.history = history
        self.history_bytes = history_bytes
        self.pages: set[WebSocket] = set()
        self.sources: set[WebSocket] = set()

    def accept(self, text: str) -> str | None:
        """Check one source message (``MessageError`` naming the field) and keep it; returns the
        text to relay to the pages, or None when there is nothing to relay."""
        size = len(text.encode())
        if size > MAX_EPISODE_BYTES:
            raise MessageTooLarge(f"a message of {size} bytes; the limit is {MAX_EPISODE_BYTES}")
        message = parse_message(text, self.lanes, self.signals)
        if isinstance(message, EpisodeMessage):
            self.episode = message.model_dump_json()
            self.lanes, self.signals = len(message.scene.lanes), len(message.scene.signals)
            self.frames.clear()
            self.frame_bytes = 0
            return self.episode
        if size > MAX_FRAME_BYTES:
            raise MessageTooLarge(f"frame: {size} bytes; the limit is {MAX_FRAME_BYTES}")
        if not self.pages:  # nobody watches (the source was told so): nothing is kept
            return None
        out = message.model_dump_json()
        self.frames.append(out)
        self.frame_bytes += len(out)
        while self.frames and (len(self.frames) > self.history or self.frame_bytes > self.history_bytes):
            self.frame_bytes -= len(self.frames.popleft())
        return out

    async def _send(self, ws: WebSocket, text: str) -> bool:
        try:
            await asyncio.wait_for(ws.send_text(text), SEND_TIMEOUT)
            return True
        except Exception:  # gone, or too slow to keep up: it reconnects and gets the history
            return False

    async def _send_all(self, sockets: set[WebSocket], text: str) -> None:
        for ws in list(sockets):
            if not await self._send(ws, text):
                sockets.discard(ws)

    async def _tell_sources(self) -> None:
        await self._send_all(self.sources, json.dumps({"type": "watching", "value": bool(self.pages)}))

    async def source(self, ws: WebSocket) -> None:
        await ws.accept()
        self.sources.add(ws)
        await self._send(ws, json.dumps({"type": "watching", "value": bool(self.pages)}))
        try:
            while True:
                message = await ws.receive()
                if message["type"] == "websocket.disconnect":
                    return
                text = message.get("text")
                if text is None:
                    await _refuse(ws, 1003, "binary messages are not accepted; send JSON text")
                    return
                try:
                    out = self.accept(text)
                except MessageError as err:
                    await _refuse(ws, 1009 if isinstance(err, MessageTooLarge) else 1008, str(err))
                    return
                if out is not None:
                    await self._send_all(self.pages, out)
        except WebSocketDisconnect:
            pass
        finally:
            self.sources.discard(ws)

    async def page(self, ws: WebSocket) -> None:
        await ws.accept()
        if self.episode is not None:
            for text in [self.episode, *self.frames]:
                if not await self._send(ws, text):
                    return
        self.pages.add(ws)
        await self._tell_sources()
        try:
            while True:  # pages only listen; whatever they send is ignored, this notices when they leave
                if (await ws.receive())["type"] == "websocket.disconnect":
                    return
        except WebSocketDisconnect:
            pass
        finally:
            self.pages.discard(ws)
            await self._tell_sources()


async def _refuse(ws: WebSocket, code: int, reason: str) -> None:
    """Close a source's websocket saying why (one log line, no traceback)."""
    log.warning("smarts viz: refused a /ws/source message: %s", reason)
    try:
        await ws.send_text(json.dumps({"type": "error", "error": reason}))
        await ws.close(code=code, reason=_short(reason))
    except Exception:
        pass


def _print_warning(path: Path, problem: str) -> None:
    print(f"warning: skipping {path}: {problem}", file=sys.stderr, flush=True)


def create_app(
    path: str | Path | None = None,
    *,
    allow_remote: bool = False,
    host: str | None = None,
    warn: Callable[[Path, str], None] = _print_warning,
) -> Starlette:
    """The viewer app for the episodes under ``path`` (None: live envs only). A file under a folder
    that cannot be opened is skipped with one ``warn(file, problem)``. ``allow_remote`` widens the
    Host check (``AccessPolicy``); ``host``: the name it was bound to, also accepted then."""
    episodes: list[EpisodeEntry] = find_episodes(path, on_skip=warn) if path is not None else []
    hub = LiveHub()

    async def index(request) -> Response:
        return FileResponse(STATIC_DIR / "index.html", headers={"Cache-Control": "no-store"})

    async def static(request) -> Response:
        name = request.path_params["name"]
        if name not in STATIC_FILES:
            return PlainTextResponse("not found\n", status_code=404)
        return FileResponse(STATIC_DIR / name, media_type=STATIC_FILES[name], headers={"Cache-Control": "no-cache"})

    async def list_episodes(request) -> Response:
        return JSONResponse(
            {
                "episodes": [{"id": i, "name": e.name, "kind": e.kind} for i, e in enumerate(episodes)],
                "live": hub.episode is not None,
                "path": None if path is None else str(path),
            }
        )

    async def get_episode(request) -> Response:
        raw = request.path_params["index"]
        if not re.fullmatch(r"[0-9]{1,9}", raw) or int(raw) >= len(episodes):
            return JSONResponse({"error": f"no episode {raw[:40]}; there are {len(episodes)}"}, status_code=404)
        try:
            body = await asyncio.to_thread(episode_json, episodes[int(raw)])
        except (ValueError, OSError) as err:  # LogError and friends: say which file and what is wrong
            return JSONResponse({"error": str(err)}, status_code=422)
        return Response(body, media_type="application/json")

    routes = [
        Route("/", index),
        Route("/static/{name}", static),
        Route("/api/episodes", list_episodes),
        Route("/api/episodes/{index}", get_episode),
        WebSocketRoute("/ws/source", hub.source),
        WebSocketRoute("/ws/live", hub.page),
    ]
    app = Starlette(routes=routes)
    app.add_middleware(GuardMiddleware, policy=AccessPolicy(allow_remote, [host] if host else []))
    app.state.hub = hub
    app.state.episodes = episodes
    return app


def bind(host: str, port: int) -> socket.socket:
    """A listening socket on ``host:port`` (0: any free port), bound here rather than by uvicorn so
    that a port in use is one plain ``ValueError`` before anything is printed or served."""
    try:
        family, kind, proto, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
    except socket.gaierror as err:
        raise ValueError(f"--host {host}: not an address of this machine ({err.strerror})") from None
    sock = socket.socket(family, kind, proto)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as uvicorn does: no wait after a restart
        sock.bind(address)
        sock.listen(128)
    except OSError as err:
        sock.close()
        if err.errno == errno.EADDRINUSE:
            raise ValueError(f"--port {port}: {host}:{port} is already in use (another viewer or server?); give "
                             "another --port, or --port 0 for any free one") from None  # fmt: skip
        raise ValueError(f"--host {host} --port {port}: cannot listen there ({err.strerror or err})") from None
    sock.set_inheritable(True)
    return sock


def serve(
    path: str | Path | None = None,
    host: str = DEFAULT_HOST,
    port: int = DEFAULT_PORT,
    *,
    allow_remote: bool = False,
    log_level: str = "warning",
) -> None:
    """Run the viewer until interrupted (refuses a non-loopback ``host`` without ``allow_remote``,
    which also widens the Host check; a port in use is a ``ValueError`` saying so)."""
    import uvicorn

    warning = check_bind(host, allow_remote)
    if warning:
        print(warning, file=sys.stderr)
    app = create_app(path, allow_remote=allow_remote, host=host)
    sock = bind(host, port)
    port = sock.getsockname()[1]
    n = len(app.state.episodes)
    what = f"{n} recorded episode(s) under {path}" if path is not None else "waiting for live envs"
    print(f"smarts viz: http://{_url_host(host)}:{port}/ ({what}; Ctrl-C stops)", flush=True)
    config = uvicorn.Config(app, host=host, port=port, log_level=log_level, ws_max_size=MAX_EPISODE_BYTES)
    try:
        uvicorn.Server(config).run(sockets=[sock])
    finally:
        sock.close()


def _url_host(host: str) -> str:
    return f"[{host}]" if ":" in host else host


class BackgroundServer:
    """The viewer in a thread of this process (``train enjoy --viz``, tests); ``url`` once started."""

    def __init__(self, path: str | Path | None = None, host: str = DEFAULT_HOST, port: int = 0, *,
                 allow_remote: bool = False):  # fmt: skip
        import threading

        import uvicorn

        check_bind(host, allow_remote)
        self.app = create_app(path, allow_remote=allow_remote, host=host)
        self._socket = bind(host, port)
        config = uvicorn.Config(self.app, host=host, port=self._socket.getsockname()[1], log_level="warning",
                                ws_max_size=MAX_EPISODE_BYTES)  # fmt: skip
        self.server = uvicorn.Server(config)
        self._thread = threading.Thread(target=self.server.run, kwargs={"sockets": [self._socket]},
                                        name="smarts-viz-server", daemon=True)  # fmt: skip
        self._thread.start()
        import time

        deadline = time.monotonic() + 30
        while not self.server.started:
            if not self._thread.is_alive() or time.monotonic() > deadline:
                raise RuntimeError(f"the viewer server did not start on {host}:{port}")
            time.sleep(0.02)
        sock = self.server.servers[0].sockets[0]
        self.host, self.port = sock.getsockname()[:2]
        self.url = f"http://{_url_host(host)}:{self.port}"

    def stop(self) -> None:
        self.server.should_exit = True
        self._thread.join(timeout=10)
        self._socket.close()

    def __enter__(self) -> "BackgroundServer":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stop()
