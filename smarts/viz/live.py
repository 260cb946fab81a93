"""Streams a running env's frames to a viewer server, at no cost while nobody watches.

A background thread holds one websocket to the server's ``/ws/source`` (connecting, and
reconnecting every few seconds, without ever blocking the env). The server says whether a browser
is watching; until one is, the env builds no frames at all (``watching`` is a plain attribute
read). Frames wait in a short queue; when the page or the network falls behind, the oldest are
dropped rather than slowing the simulation.
"""

from __future__ import annotations

import json
import queue
import threading
from typing import Any
from urllib.parse import urlparse

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8765
DEFAULT_URL = f"http://{DEFAULT_HOST}:{DEFAULT_PORT}"
"""Where ``smarts viz`` serves by default, so where live envs look for it."""
RETRY_SECONDS = 2.0


def source_url(url: str) -> str:
    """The websocket address of a server's source endpoint from its page address."""
    parsed = urlparse(url if "://" in url else f"http://{url}")
    if parsed.scheme not in ("http", "https", "ws", "wss") or not parsed.hostname:
        raise ValueError(f"live viewer address {url!r}: expected http://HOST:PORT")
    scheme = "wss" if parsed.scheme in ("https", "wss") else "ws"
    return f"{scheme}://{parsed.netloc}/ws/source"


class LivePublisher:
    """Sends episodes and frames to a viewer server from a background thread."""

    def __init__(self, url: str = DEFAULT_URL, queue_size: int = 32):
        self.url = source_url(url)
        self.watching = False
        self.connected = threading.Event()
        self._queue: queue.Queue[str | None] = queue.Queue(maxsize=queue_size)
        self._episode: str | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="smarts-viz-live", daemon=True)
        self._thread.start()

    def episode(self, meta: dict[str, Any], scene: dict[str, Any]) -> None:
        """A new episode begins (sent on every connection, so a restarted server learns it too)."""
        self._episode = json.dumps({"type": "episode", "meta": meta, "scene": scene}, allow_nan=False)
        self._put(self._episode)

    def frame(self, frame: dict[str, Any]) -> None:
        """One page frame (``smarts.viz.capture.frame_json``); dropped when nobody watches."""
        if self.watching:
            self._put(json.dumps({"type": "frame", "frame": frame}, allow_nan=False))

    def _put(self, message: str) -> None:
        if not self.connected.is_set():
            return
        while True:
            try:
                self._queue.put_nowait(message)
                return
            except queue.Full:
                try:
                    self._queue.get_nowait()  # the oldest frame goes
                except queue.Empty:
                    pass

    def close(self) -> None:
        self._stop.set()
        try:
            self._queue.put_nowait(None)
        except queue.Full:
            pass
        self._thread.join(timeout=5)

    # ------------------------------------------------------------------ the thread
    def _run(self) -> None:
        from websockets.exceptions import WebSocketException
        from websockets.sync.client import connect

        while not self._stop.is_set():
            try:
                with connect(self.url, open_timeout=RETRY_SECONDS, max_size=None) as ws:
                    self.connected.set()
                    if self._episode is not None:
                        ws.send(self._episode)
                    self._serve(ws)
            except (OSError, WebSocketException, TimeoutError):
                pass
            finally:
                self.connected.clear()
                self.watching = False
            self._stop.wait(RETRY_SECONDS)

    def _serve(self, ws) -> None:
        from websockets.exceptions import ConnectionClosed

        while not self._stop.is_set():
            try:
                reply = ws.recv(timeout=0)
            except TimeoutError:
                reply = None
            except ConnectionClosed:
                return
            if reply is not None:
                self._note(reply)
                continue
            try:
                message = self._queue.get(timeout=0.05)
            except queue.Empty:
                continue
            if message is None:
                return
            ws.send(message)

    def _note(self, reply: str | bytes) -> None:
        try:
            data = json.loads(reply)
        except ValueError:
            return
        if isinstance(data, dict) and data.get("type") == "watching":
            self.watching = bool(data.get("value"))
