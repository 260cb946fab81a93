"""Live messages as a source sends them to ``/ws/source``, built by hand so that a test can bend
one field at a time; and the raw clients that send them with any Host or Origin."""

from __future__ import annotations

import http.client
import json
import socket
from typing import Any

PAYLOAD = "<img src=x onerror=\"window.__pwned=1;document.title='pwned'\">"
"""Markup that runs script if a page writes it as HTML."""


def scene(lanes: int = 2) -> dict[str, Any]:
    """A straight road of ``lanes`` parallel lanes, 100 m long."""
    return {
        "version": 1,
        "source": "hand-made",
        "bounds": [0.0, 0.0, 100.0, 4.0 * lanes],
        "lanes": [
            {
                "id": f"main_{i}",
                "road": "main",
                "index": i,
                "internal": False,
                "width": 3.5,
                "speed_limit": 13.9,
                "length": 100.0,
                "points": [[0.0, 2.0 + 4 * i], [100.0, 2.0 + 4 * i]],
                "successors": [],
                "predecessors": [],
            }  # fmt: skip
            for i in range(lanes)
        ],
        "junctions": [],
        "signals": [],
    }


def episode(**meta: Any) -> dict[str, Any]:
    """An episode message; ``meta`` replaces fields of the metadata."""
    base = {"scenario": "hand_made", "seed": 0, "dt": 0.1, "episode": 1, "agent_ids": ["agent_0"], "live": True}
    return {"type": "episode", "meta": {**base, **meta}, "scene": scene()}


def frame(step: int = 1, vehicles: int = 3) -> dict[str, Any]:
    """A frame message: ``vehicles`` cars on lane 0, the first one driven by agent_0."""
    ids = ["agent_0", *(f"car-{i:06d}" for i in range(1, vehicles))]
    return {
        "type": "frame",
        "frame": {
            "step": step, "t": round(0.1 * step, 4), "ids": ids, "x": [5.0 + 7 * i for i in range(vehicles)],
            "y": [2.0] * vehicles, "h": [0.0] * vehicles, "speed": [10.0] * vehicles, "length": [4.6] * vehicles,
            "width": [1.9] * vehicles, "role": [1] + [3] * (vehicles - 1), "lane": [0] * vehicles, "signals": [],
            "agents": {"agent_0": {"vehicle": "agent_0", "action": [0.5, 0.0, 0.0], "reward": 0.1, "events": [],
                                   "neighbours": [[12.0, 2.0, 1.0]], "waypoints": [[[10.0, 2.0], [12.0, None]]]}},
        },
    }  # fmt: skip


def text(message: dict[str, Any]) -> str:
    return json.dumps(message)


def request(port: int, path: str, headers: dict[str, str] | None = None) -> tuple[int, dict[str, str], bytes]:
    """GET ``path`` from 127.0.0.1:``port`` sending exactly ``headers`` (Host included: default
    127.0.0.1:port); the path goes out as given, escapes and all."""
    headers = {"Host": f"127.0.0.1:{port}", **(headers or {})}
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
    try:
        conn.putrequest("GET", path, skip_host=True, skip_accept_encoding=True)
        for k, v in headers.items():
            conn.putheader(k, v)
        conn.endheaders()
        r = conn.getresponse()
        return r.status, {k.lower(): v for k, v in r.getheaders()}, r.read()
    finally:
        conn.close()


def ws_connect(port: int, path: str, host: str | None = None, origin: str | None = None, **kwargs: Any):
    """A websocket to 127.0.0.1:``port`` whose handshake says ``Host: host`` (default the real
    address) and ``Origin: origin`` (none by default, as a non-browser client)."""
    from websockets.sync.client import connect

    sock = socket.create_connection(("127.0.0.1", port), timeout=30)
    uri = f"ws://{host or f'127.0.0.1:{port}'}{path}"
    return connect(uri, sock=sock, origin=origin, open_timeout=30, **kwargs)
