"""The viewer's web server: one page, the recorded episodes under a path, and live envs.

Routes: ``/`` the page and ``/static/*`` its files (shipped in the package; nothing is fetched
from the network); ``/api/episodes`` the list of recorded episodes and whether a live env is
connected; ``/api/episodes/{i}`` one episode as JSON; ``/ws/source`` where live envs
(``smarts.viz.live``) send episodes and frames; ``/ws/live`` where pages receive them. The server
tells sources whether any page is watching, so unwatched envs build no frames.

Binds 127.0.0.1 unless told otherwise: any other address needs ``allow_remote`` (the viewer has no
authentication).
"""

from __future__ import annotations

import asyncio
import ipaddress
import json
import sys
from collections import deque
from pathlib import Path
from typing import Any

from starlette.applications import Starlette
from starlette.responses import FileResponse, JSONResponse, Response
from starlette.routing import Mount, Route, WebSocketRoute
from starlette.staticfiles import StaticFiles
from starlette.websockets import WebSocket, WebSocketDisconnect

from smarts.viz.live import DEFAULT_HOST, DEFAULT_PORT
from smarts.viz.sources import EpisodeEntry, episode_json, find_episodes

STATIC_DIR = Path(__file__).parent / "static"
LIVE_HISTORY = 3000
"""Frames of the current live episode kept for pages that connect later (seek back)."""


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
    return (
        f"warning: serving on {host}: anyone who can reach this address can view these episodes "
        "(no authentication)"
    )


class LiveHub:
    """Relays the live env's episode and frames to every connected page."""

    def __init__(self) -> None:
        self.episode: str | None = None
        self.frames: deque[str] = deque(maxlen=LIVE_HISTORY)
        self.pages: set[WebSocket] = set()
        self.sources: set[WebSocket] = set()

    async def _send_all(self, sockets: set[WebSocket], text: str) -> None:
        for ws in list(sockets):
            try:
                await ws.send_text(text)
            except Exception:
                sockets.discard(ws)

    async def _tell_sources(self) -> None:
        await self._send_all(self.sources, json.dumps({"type": "watching", "value": bool(self.pages)}))

    async def source(self, ws: WebSocket) -> None:
        await ws.accept()
        self.sources.add(ws)
        await ws.send_text(json.dumps({"type": "watching", "value": bool(self.pages)}))
        try:
            while True:
                text = await ws.receive_text()
                if text.startswith('{"type": "episode"'):  # smarts.viz.live writes these two
                    self.episode = text
                    self.frames.clear()
                elif text.startswith('{"type": "frame"'):
                    self.frames.append(text)
                else:
                    continue
                await self._send_all(self.pages, text)
        except WebSocketDisconnect:
            pass
        finally:
            self.sources.discard(ws)

    async def page(self, ws: WebSocket) -> None:
        await ws.accept()
        if self.episode is not None:
            await ws.send_text(self.episode)
            for text in list(self.frames):
                await ws.send_text(text)
        self.pages.add(ws)
        await self._tell_sources()
        try:
            while True:
                await ws.receive_text()  # pages only listen; this notices when they leave
        except WebSocketDisconnect:
            pass
        finally:
            self.pages.discard(ws)
            await self._tell_sources()


def create_app(path: str | Path | None = None) -> Starlette:
    """The viewer app for the episodes under ``path`` (None: live envs only)."""
    episodes: list[EpisodeEntry] = find_episodes(path) if path is not None else []
    hub = LiveHub()

    async def index(request) -> Response:
        return FileResponse(STATIC_DIR / "index.html", headers={"Cache-Control": "no-store"})

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
        if not raw.isdigit() or int(raw) >= len(episodes):
            return JSONResponse({"error": f"no episode {raw}; there are {len(episodes)}"}, status_code=404)
        try:
            body = await asyncio.to_thread(episode_json, episodes[int(raw)])
        except ValueError as err:  # LogError and friends: say which file and what is wrong
            return JSONResponse({"error": str(err)}, status_code=422)
        return Response(body, media_type="application/json")

    routes = [
        Route("/", index),
        Route("/api/episodes", list_episodes),
        Route("/api/episodes/{index}", get_episode),
        WebSocketRoute("/ws/source", hub.source),
        WebSocketRoute("/ws/live", hub.page),
        Mount("/static", StaticFiles(directory=STATIC_DIR), name="static"),
    ]
    app = Starlette(routes=routes)
    app.state.hub = hub
    app.state.episodes = episodes
    return app


def serve(
    path: str | Path | None = None,
    host: str = DEFAULT_HOST,
    port: int = DEFAULT_PORT,
    *,
    allow_remote: bool = False,
    log_level: str = "warning",
) -> None:
    """Run the viewer until interrupted (refuses a non-loopback ``host`` without ``allow_remote``)."""
    import uvicorn

    warning = check_bind(host, allow_remote)
    if warning:
        print(warning, file=sys.stderr)
    app = create_app(path)
    n = len(app.state.episodes)
    what = f"{n} recorded episode(s) under {path}" if path is not None else "waiting for live envs"
    print(f"smarts viz: http://{host}:{port}/ ({what}; Ctrl-C stops)", flush=True)
    uvicorn.run(app, host=host, port=port, log_level=log_level, ws_max_size=64 * 2**20)


class BackgroundServer:
    """The viewer in a thread of this process (``train enjoy --viz``, tests); ``url`` once started."""

    def __init__(self, path: str | Path | None = None, host: str = DEFAULT_HOST, port: int = 0, *,
                 allow_remote: bool = False):  # fmt: skip
        import threading

        import uvicorn

        check_bind(host, allow_remote)
        self.app = create_app(path)
        config = uvicorn.Config(self.app, host=host, port=port, log_level="warning", ws_max_size=64 * 2**20)
        self.server = uvicorn.Server(config)
        self._thread = threading.Thread(target=self.server.run, name="smarts-viz-server", daemon=True)
        self._thread.start()
        import time

        deadline = time.monotonic() + 30
        while not self.server.started:
            if not self._thread.is_alive() or time.monotonic() > deadline:
                raise RuntimeError(f"the viewer server did not start on {host}:{port}")
            time.sleep(0.02)
        sock = self.server.servers[0].sockets[0]
        self.host, self.port = sock.getsockname()[:2]
        self.url = f"http://{host}:{self.port}"

    def stop(self) -> None:
        self.server.should_exit = True
        self._thread.join(timeout=10)

    def __enter__(self) -> "BackgroundServer":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stop()
