"""The viewer under hostile input, over real HTTP and websockets (uvicorn on 127.0.0.1): requests
and websockets from another site (foreign Host or Origin, DNS rebinding) are refused, live
messages are checked and re-serialised, memory stays bounded, odd paths and binary frames are
clean refusals, and a bad recording in a folder is skipped with one warning."""

from __future__ import annotations

import json
import logging
import re
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from websockets.exceptions import ConnectionClosed

from smarts.viz.server import LIVE_HISTORY_BYTES, MAX_FRAME_BYTES, STATIC_DIR, BackgroundServer, create_app
from tests.viz.messages import episode, frame, request, scene, text, ws_connect

ROUTES = ["/", "/static/viz.js", "/static/viz.css", "/api/episodes", "/api/episodes/0", "/no/such/route"]


@pytest.fixture(scope="module")
def server(recorded, tmp_path_factory):
    folder = tmp_path_factory.mktemp("guarded")
    (folder / "secret_run.rec.npz").write_bytes(recorded["path"].read_bytes())
    with BackgroundServer(folder) as srv:
        yield srv


@pytest.fixture
def server_log():
    """Every record the server logs (uvicorn's own and the viewer's), formatted with tracebacks."""
    lines: list[str] = []

    class Keep(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            lines.append(logging.Formatter("%(name)s %(levelname)s %(message)s").format(record))

    handler = Keep()
    loggers = [logging.getLogger(name) for name in ("uvicorn", "uvicorn.error", "uvicorn.asgi", "smarts.viz")]
    for lg in loggers:
        lg.addHandler(handler)
    yield lines
    for lg in loggers:
        lg.removeHandler(handler)


def closed(ws, timeout: float = 30) -> ConnectionClosed:
    """The close the server sent (after any messages it sent first)."""
    deadline = time.monotonic() + timeout
    try:
        while time.monotonic() < deadline:
            ws.recv(timeout=deadline - time.monotonic())
    except ConnectionClosed as err:
        return err
    raise AssertionError("the server did not close the websocket")


def wait_for_page(srv) -> None:
    """Until the server counts a connected page as watching."""
    deadline = time.monotonic() + 30
    while not srv.app.state.hub.pages:
        assert time.monotonic() < deadline, "the page was not registered"
        time.sleep(0.02)


def silent(ws, seconds: float = 0.5) -> bool:
    """Whether nothing arrives on ``ws`` for ``seconds``."""
    try:
        ws.recv(timeout=seconds)
    except TimeoutError:
        return True
    return False


# ------------------------------------------------------------------------------- Host and Origin
@pytest.mark.parametrize("route", ROUTES)
def test_foreign_host_is_refused_on_every_route(server, route):
    """DNS rebinding: a page of attacker.example whose name now points at 127.0.0.1."""
    for host in ("attacker.example", f"attacker.example:{server.port}", f"localhost:{server.port + 1}",
                 f"127.0.0.1.attacker.example:{server.port}", "", f"127.0.0.1:{server.port};x"):  # fmt: skip
        status, _, body = request(server.port, route, {"Host": host})
        assert status == 403, (host, status)
        assert b"secret_run" not in body and b"forbidden" in body


def test_loopback_names_with_the_bound_port_are_served(server):
    for host in (f"127.0.0.1:{server.port}", f"localhost:{server.port}", f"[::1]:{server.port}",
                 f"LOCALHOST:{server.port}"):  # fmt: skip
        status, _, body = request(server.port, "/api/episodes", {"Host": host})
        assert status == 200 and b"secret_run" in body, host


def test_foreign_origin_is_refused(server):
    port = server.port
    for origin in ("http://attacker.example", f"http://attacker.example:{port}", "null",
                   f"http://localhost:{port + 1}", f"ftp://127.0.0.1:{port}", f"http://127.0.0.1:{port}/x"):  # fmt: skip
        status, _, body = request(port, "/api/episodes", {"Origin": origin})
        assert status == 403 and b"secret_run" not in body, origin
    status, _, body = request(port, "/api/episodes", {"Origin": f"http://127.0.0.1:{port}"})
    assert status == 200 and b"secret_run" in body


@pytest.mark.parametrize("path", ["/ws/source", "/ws/live"])
def test_websockets_refuse_foreign_origin_and_host(server, path, server_log):
    hub = server.app.state.hub
    for host, origin in ((None, "http://attacker.example"), (None, f"http://attacker.example:{server.port}"),
                         (f"attacker.example:{server.port}", None), (None, f"http://localhost:{server.port + 1}")):  # fmt: skip
        with ws_connect(server.port, path, host=host, origin=origin) as ws:
            if path == "/ws/source":
                try:
                    ws.send(text(episode(scenario="pushed from elsewhere")))
                except ConnectionClosed:
                    pass
            err = closed(ws)
            assert err.rcvd is not None and err.rcvd.code == 1008, (host, origin)
            assert "Origin" in err.rcvd.reason or "Host" in err.rcvd.reason
    assert hub.episode is None and not hub.pages and not hub.sources
    assert not any("Traceback" in line for line in server_log)
    with ws_connect(server.port, path, origin=f"http://127.0.0.1:{server.port}") as ws:  # the page's own origin
        if path == "/ws/source":
            assert json.loads(ws.recv(timeout=30)) == {"type": "watching", "value": False}
        else:
            assert silent(ws)


def test_allow_remote_widens_the_host_but_not_the_origin(recorded, tmp_path):
    (tmp_path / "a.rec.npz").write_bytes(recorded["path"].read_bytes())
    with BackgroundServer(tmp_path, allow_remote=True) as srv:
        port = srv.port
        for host in (f"192.0.2.7:{port}", f"[2001:db8::1]:{port}", f"{socket.gethostname()}:{port}"):
            assert request(port, "/api/episodes", {"Host": host})[0] == 200, host
        assert request(port, "/api/episodes", {"Host": f"attacker.example:{port}"})[0] == 403
        same = {"Host": f"192.0.2.7:{port}", "Origin": f"http://192.0.2.7:{port}"}
        assert request(port, "/api/episodes", same)[0] == 200
        other = {"Host": f"192.0.2.7:{port}", "Origin": f"http://203.0.113.9:{port}"}
        assert request(port, "/api/episodes", other)[0] == 403
    with BackgroundServer(tmp_path) as srv:  # without the flag an address is not enough
        assert request(srv.port, "/api/episodes", {"Host": f"192.0.2.7:{srv.port}"})[0] == 403


def test_page_has_a_content_security_policy(server):
    status, headers, body = request(server.port, "/")
    assert status == 200
    policy = dict(part.strip().split(" ", 1) for part in headers["content-security-policy"].split(";"))
    assert policy["default-src"] == "'self'" and policy["script-src"] == "'self'" and policy["object-src"] == "'none'"
    assert "unsafe" not in headers["content-security-policy"]
    assert policy["connect-src"].split() == [
        "'self'",
        f"ws://127.0.0.1:{server.port}",
        f"wss://127.0.0.1:{server.port}",
    ]
    assert headers["x-content-type-options"] == "nosniff"
    html = (STATIC_DIR / "index.html").read_text()
    assert not re.search(r"<script(?![^>]*\bsrc=)", html) and "<style" not in html  # nothing inline to allow
    assert not re.search(r"\son[a-z]+\s*=|\sstyle\s*=|javascript:", html)
    js = (STATIC_DIR / "viz.js").read_text()
    assert not re.search(r"innerHTML|outerHTML|insertAdjacentHTML|document\.write|eval\(|new Function", js)


# ------------------------------------------------------------------------------- odd paths
@pytest.mark.parametrize("path", ["/api/episodes/%C2%B2", "/static/viz.js%00.png", "/api/episodes/-1",
                                  "/api/episodes/99999999999999999999999", "/static/%2e%2e/server.py",
                                  "/static/../server.py", "/static/index.html%00", "/api/episodes/1%00"])  # fmt: skip
def test_odd_paths_are_refused_not_a_server_error(server, path, server_log):
    status, _, body = request(server.port, path)
    assert status in (400, 404), (path, status)
    assert b"import" not in body  # no file of the package beyond the page's own
    assert not any("Traceback" in line or "Exception" in line for line in server_log)


# ------------------------------------------------------------------------------- live messages
MALFORMED = [
    # (case, message text, fragment the refusal names)
    ("not JSON", "<script>alert(1)</script>", "Invalid JSON"),
    ("unknown type", '{"type": "script", "code": "alert(1)"}', "tag 'script'"),
    ("meta is markup", text({**episode(), "meta": "<img src=x onerror=alert(1)>"}), "meta"),
    ("missing scene", json.dumps({"type": "episode", "meta": episode()["meta"]}), "scene"),
    ("scenario not a string", text(episode(scenario={"html": "<b>"})), "meta.scenario"),
    ("extra field", text({**episode(), "html": "<script>alert(1)</script>"}), "html"),
    ("extra meta field", text(episode(onload="alert(1)")), "meta.onload"),
    ("lanes not a list", text({**episode(), "scene": {**scene(), "lanes": "<b>"}}), "scene.lanes"),
    ("NaN bounds", text(episode()).replace('"bounds": [0.0', '"bounds": [NaN'), "scene.bounds.0"),
    (
        "successor out of range",
        text({**episode(), "scene": {**scene(), "lanes": [{**scene()["lanes"][0], "successors": [7]}]}}),
        "successors",
    ),  # fmt: skip
    ("deep nesting", '{"type": "episode", "meta": ' + "[" * 5000 + "]" * 5000 + "}", "recursion"),
    ("frame before the episode", text(frame()), "before any episode"),
]


@pytest.mark.parametrize("case, message, fragment", MALFORMED, ids=[m[0] for m in MALFORMED])
def test_malformed_message_is_refused_not_relayed(case, message, fragment, server_log):
    with BackgroundServer() as srv:
        with ws_connect(srv.port, "/ws/live") as page, ws_connect(srv.port, "/ws/source") as source:
            wait_for_page(srv)
            source.send(message)
            err = closed(source)
            assert err.rcvd.code == 1008 and fragment in err.rcvd.reason, err.rcvd.reason
            assert silent(page)  # nothing reached the page
        assert srv.app.state.hub.episode is None
    assert any(fragment in line for line in server_log if "refused a /ws/source message" in line)
    assert not any("Traceback" in line for line in server_log)


def test_frames_that_do_not_fit_their_episode_are_refused():
    with BackgroundServer() as srv, ws_connect(srv.port, "/ws/live") as page:
        wait_for_page(srv)
        for change, fragment in ((lambda f: f["x"].pop(), "x: 2 values for 3 vehicles"),
                                 (lambda f: f["lane"].__setitem__(0, 2), "lane: an index outside"),
                                 (lambda f: f["agents"]["agent_0"].__setitem__("vehicle", "nobody"), "vehicle"),
                                 (lambda f: f.__setitem__("t", "<b>"), "frame.t")):  # fmt: skip
            with ws_connect(srv.port, "/ws/source") as source:
                source.send(text(episode()))
                assert json.loads(page.recv(timeout=30))["type"] == "episode"
                bad = frame()
                change(bad["frame"])
                source.send(text(bad))
                err = closed(source)
                assert err.rcvd.code == 1008 and fragment in err.rcvd.reason, err.rcvd.reason
                assert silent(page)


def test_relayed_messages_are_re_serialised():
    """Accepted messages reach the page as the server writes them, not as the source did."""
    with BackgroundServer() as srv, ws_connect(srv.port, "/ws/live") as page:
        wait_for_page(srv)
        with ws_connect(srv.port, "/ws/source") as source:
            source.send("  " + text(episode(scenario="a\u2028b")).replace(", ", ",   "))
            got = page.recv(timeout=30)
            assert "   " not in got and json.loads(got)["meta"]["scenario"] == "a\u2028b"
            source.send(text(frame(step=1)))
            assert json.loads(page.recv(timeout=30))["frame"]["ids"] == frame()["frame"]["ids"]


@pytest.mark.parametrize("path", ["/ws/source", "/ws/live"])
def test_binary_websocket_message_is_refused_without_a_traceback(path, server_log):
    with BackgroundServer() as srv:
        with ws_connect(srv.port, path) as ws:
            ws.send(b"\x00\x01 not text")
            if path == "/ws/source":
                err = closed(ws)
                assert err.rcvd.code == 1003 and "binary" in err.rcvd.reason
            else:  # a page may send anything: it is ignored and the page stays connected
                assert silent(ws)
                wait_for_page(srv)
                with ws_connect(srv.port, "/ws/source") as source:
                    source.send(text(episode()))
                    assert json.loads(ws.recv(timeout=30))["type"] == "episode"
        time.sleep(0.3)
    assert not any("Traceback" in line or "KeyError" in line for line in server_log), server_log


def test_oversized_frame_is_refused():
    with BackgroundServer() as srv, ws_connect(srv.port, "/ws/live"), ws_connect(srv.port, "/ws/source") as source:
        source.send(text(episode()))
        source.send(text(frame(vehicles=MAX_FRAME_BYTES // 40)))
        err = closed(source)
        assert err.rcvd.code == 1009 and "the limit is" in err.rcvd.reason
        assert not srv.app.state.hub.frames


def big_frame(step: int) -> str:
    """A valid frame of about 1 MiB (20,000 vehicles)."""
    return text(frame(step=step, vehicles=20_000))


def rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmRSS")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_unwatched_frames_do_not_grow_the_server():
    """800 frames of 1 MiB with nobody watching: the server process stays flat."""
    port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "smarts.viz", "--port", str(port)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        assert "waiting for live envs" in proc.stdout.readline()
        deadline = time.monotonic() + 60
        while True:
            try:
                ws = ws_connect(port, "/ws/source")
                break
            except OSError:
                assert time.monotonic() < deadline, "the viewer did not start"
                time.sleep(0.1)
        with ws:
            assert json.loads(ws.recv(timeout=30)) == {"type": "watching", "value": False}
            ws.send(text(episode()))
            message = big_frame(1)
            for _ in range(20):
                ws.send(message)
            time.sleep(1.0)
            before = rss_mib(proc.pid)
            for _ in range(800):
                ws.send(message)
        # closed: the server answered the close after reading every frame before it
        with ws_connect(port, "/ws/live") as page:
            assert json.loads(page.recv(timeout=60))["type"] == "episode"
            assert silent(page)  # no frame was kept for it
        after = rss_mib(proc.pid)
        assert after - before < 150, (before, after)
    finally:
        proc.terminate()
        _, err = proc.communicate(timeout=30)
    assert "Traceback" not in err


def test_watched_history_is_bounded_in_bytes():
    with BackgroundServer() as srv, ws_connect(srv.port, "/ws/live", max_size=None) as page:
        wait_for_page(srv)
        hub = srv.app.state.hub
        got: list[str] = []

        def read() -> None:
            try:
                while True:
                    got.append(page.recv(timeout=120))
            except (ConnectionClosed, TimeoutError):
                pass

        threading.Thread(target=read, daemon=True).start()
        n = LIVE_HISTORY_BYTES // 800_000 + 20  # frames of ~0.8 MB as the server writes them
        message = big_frame(1)
        with ws_connect(srv.port, "/ws/source") as source:
            source.send(text(episode()))
            for _ in range(n):
                source.send(message)
            deadline = time.monotonic() + 120
            while len(got) < n + 1 and time.monotonic() < deadline:
                time.sleep(0.05)
        assert len(got) == n + 1  # the page saw every frame
        assert sum(len(f) for f in hub.frames) <= LIVE_HISTORY_BYTES  # the newest that fit
        assert 0 < len(hub.frames) < n


# ------------------------------------------------------------------------------- recordings
def bad_recordings(folder: Path, good: Path) -> dict[str, str]:
    """Bad files beside a good recording; file name -> what the warning must say."""
    (folder / "good.rec.npz").write_bytes(good.read_bytes())
    (folder / "empty.rec.npz").write_bytes(b"")
    np.savez(folder / "list_meta.rec.npz", metadata=np.array(json.dumps([1, 2])), scene=np.array("{}"))
    np.savez(folder / "not_json.rec.npz", metadata=np.array("{nope"), scene=np.array("{}"))
    (folder / "cut.rec.npz").write_bytes(good.read_bytes()[:300])
    return {"empty.rec.npz": "not a readable .npz", "list_meta.rec.npz": "metadata is a JSON list",
            "not_json.rec.npz": "metadata is not valid JSON", "cut.rec.npz": "not a readable .npz"}  # fmt: skip


def test_bad_recordings_are_skipped_with_one_warning_each(recorded, tmp_path):
    expected = bad_recordings(tmp_path, recorded["path"])
    warned: list[tuple[Path, str]] = []
    app = create_app(tmp_path, warn=lambda path, problem: warned.append((path, problem)))
    assert [e.name for e in app.state.episodes] == ["good.rec.npz"]
    assert sorted(p.name for p, _ in warned) == sorted(expected)
    for path, problem in warned:
        assert expected[path.name] in problem, (path, problem)


def test_viewer_starts_and_serves_the_good_recordings(recorded, tmp_path, capfd):
    bad_recordings(tmp_path, recorded["path"])
    with BackgroundServer(tmp_path) as srv:
        listing = json.loads(request(srv.port, "/api/episodes")[2])
        assert [e["name"] for e in listing["episodes"]] == ["good.rec.npz"]
        status, _, body = request(srv.port, "/api/episodes/0")
        assert status == 200 and json.loads(body)["kind"] == "recording"
    err = capfd.readouterr().err
    for name in ("empty.rec.npz", "list_meta.rec.npz", "not_json.rec.npz", "cut.rec.npz"):
        assert len(re.findall(rf"warning: skipping \S*{re.escape(name)}: ", err)) == 1, err
    assert "Traceback" not in err
