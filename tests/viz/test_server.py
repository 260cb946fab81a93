"""The viewer server over real HTTP and websockets (uvicorn on 127.0.0.1): the page and its
files, recorded episodes and benchmark logs as JSON, live streaming, and the bind refusal."""

from __future__ import annotations

import json
import subprocess
import sys
import time
import urllib.error
import urllib.request

import pytest

from smarts.viz.server import BackgroundServer, check_bind


def get(url: str) -> tuple[int, bytes, str]:
    try:
        with urllib.request.urlopen(url, timeout=60) as r:
            return r.status, r.read(), r.headers.get("content-type", "")
    except urllib.error.HTTPError as err:
        return err.code, err.read(), err.headers.get("content-type", "")


@pytest.fixture(scope="module")
def server(recorded, benchmark_log, tmp_path_factory):
    folder = tmp_path_factory.mktemp("served")
    (folder / "rec.rec.npz").write_bytes(recorded["path"].read_bytes())
    logs = folder / "adaptive" / "logs" / "zoo_keep-lane"
    logs.mkdir(parents=True)
    (logs / "episode_000.npz").write_bytes(benchmark_log.read_bytes())
    (folder / "notes.npz").write_bytes(b"neither")  # skipped: not an episode
    with BackgroundServer(folder) as srv:
        yield srv


def test_page_and_assets_are_served_locally(server):
    status, body, kind = get(server.url + "/")
    assert status == 200 and "text/html" in kind and b'<canvas id="canvas">' in body
    for name, mime in (("viz.js", "javascript"), ("viz.css", "text/css")):
        status, body, kind = get(f"{server.url}/static/{name}")
        assert status == 200 and mime in kind and len(body) > 500
    page = get(server.url + "/")[1] + get(server.url + "/static/viz.js")[1]
    assert b"http://" not in page and b"https://" not in page  # nothing fetched from the network
    assert server.host == "127.0.0.1"


def test_episode_list_and_recording(server, recorded):
    listing = json.loads(get(server.url + "/api/episodes")[1])
    kinds = {e["name"]: e["kind"] for e in listing["episodes"]}
    assert kinds == {"adaptive/logs/zoo_keep-lane/episode_000.npz": "log", "rec.rec.npz": "recording"}
    index = [e["id"] for e in listing["episodes"] if e["kind"] == "recording"][0]
    status, body, _ = get(f"{server.url}/api/episodes/{index}")
    episode = json.loads(body)
    assert status == 200 and episode["kind"] == "recording"
    assert len(episode["frames"]) == recorded["steps"] + 1
    frame = episode["frames"][30]
    truth = recorded["truth"][30]
    assert sorted(frame["ids"]) == sorted(truth)
    i = frame["ids"].index("agent_0")
    assert frame["speed"][i] == pytest.approx(truth["agent_0"][2], abs=0.01)
    assert {"id", "road", "index", "width", "speed_limit", "successors", "predecessors"} <= set(
        episode["scene"]["lanes"][0]
    )


def test_benchmark_log_episode_has_map_and_metrics(server):
    listing = json.loads(get(server.url + "/api/episodes")[1])
    index = [e["id"] for e in listing["episodes"] if e["kind"] == "log"][0]
    episode = json.loads(get(f"{server.url}/api/episodes/{index}")[1])
    assert episode["kind"] == "log" and episode["meta"]["scenario"] == "a01_straight_free"
    assert episode["scene"]["lanes"] and episode["frames"]
    assert 0 <= episode["metrics"]["episode"]["S_bench"] <= 1
    assert set(episode["metrics"]["agents"]) == set(episode["meta"]["agent_ids"])
    agent = episode["meta"]["agent_ids"][0]
    assert episode["frames"][0]["agents"][agent]["log"]["speed_limit"] > 0


def test_unknown_episode_is_404(server):
    status, body, _ = get(server.url + "/api/episodes/99")
    assert status == 404 and b"no episode 99" in body


def test_non_loopback_bind_is_refused_without_the_flag():
    with pytest.raises(ValueError, match="--host 0.0.0.0: refusing.*--allow-remote"):
        check_bind("0.0.0.0", allow_remote=False)
    for host in ("127.0.0.1", "localhost", "::1", "127.0.0.2"):
        assert check_bind(host, allow_remote=False) is None
    assert "warning" in check_bind("0.0.0.0", allow_remote=True)
    cmd = [sys.executable, "-m", "smarts.viz", "--host", "0.0.0.0", "--port", "0"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "refusing to serve beyond this machine" in done.stderr
    assert "Traceback" not in done.stderr


def test_allow_remote_warns_and_serves(tmp_path):
    cmd = [sys.executable, "-m", "smarts.viz", "--host", "0.0.0.0", "--port", "0", "--allow-remote"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        warning = proc.stderr.readline()
        started = proc.stdout.readline()
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    assert warning.startswith("warning: serving on 0.0.0.0") and "no authentication" in warning
    assert "waiting for live envs" in started


def test_live_stream_builds_no_frames_until_a_page_watches():
    from websockets.sync.client import connect

    from smarts.env import DrivingParallelEnv
    from smarts.viz.watch import WatchedEnv

    with BackgroundServer() as srv:
        env = WatchedEnv(DrivingParallelEnv("intersection_4way_signal_right"), live=srv.url)
        assert env.publisher.connected.wait(30)
        built = []
        original = env.capture.world
        env.capture.world = lambda sim: built.append(1) or original(sim)
        obs, _ = env.reset(seed=0)
        for _ in range(20):
            obs, *_ = env.step({a: 0.4 * obs[a]["waypoints"][0, 1] for a in env.agents})
        assert built == []  # nobody watching: no frame was built
        with connect(srv.url.replace("http", "ws") + "/ws/live") as page:
            first = json.loads(page.recv(timeout=30))
            assert first["type"] == "episode" and first["meta"]["scenario"] == "intersection_4way_signal_right"
            deadline = time.monotonic() + 30
            while not env.publisher.watching and time.monotonic() < deadline:
                time.sleep(0.02)
            assert env.publisher.watching
            for _ in range(5):
                obs, *_ = env.step({a: 0.4 * obs[a]["waypoints"][0, 1] for a in env.agents})
            frame = json.loads(page.recv(timeout=30))
            assert frame["type"] == "frame" and "agent_0" in frame["frame"]["ids"]
            sim = env.sim
            row = sim.table.row_of["agent_0"]
            assert frame["frame"]["step"] == 21  # the first step after the page connected
            assert abs(frame["frame"]["x"][frame["frame"]["ids"].index("agent_0")] - sim.table.x[row]) < 10
        deadline = time.monotonic() + 30
        while env.publisher.watching and time.monotonic() < deadline:
            time.sleep(0.02)
        assert not env.publisher.watching  # the page left: frames stop again
        env.close()


def test_bad_paths_are_named_without_a_traceback(tmp_path):
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not an episode")
    for path, problem in ((tmp_path / "missing", "no such file or folder"),
                          (junk, "neither an episode recording nor a benchmark episode log")):  # fmt: skip
        done = subprocess.run([sys.executable, "-m", "smarts.viz", str(path), "--port", "0"], capture_output=True,
                              text=True, timeout=120)  # fmt: skip
        assert done.returncode == 2 and f"error: {path}: {problem}" in done.stderr
        assert "Traceback" not in done.stderr


def test_malformed_recording_is_reported_to_the_page(recorded, tmp_path):
    import numpy as np

    with np.load(recorded["path"], allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    arrays["agent_vehicle"] = arrays["agent_vehicle"][:-1]
    np.savez_compressed(tmp_path / "cut.rec.npz", **arrays)
    with BackgroundServer(tmp_path) as srv:
        status, body, _ = get(srv.url + "/api/episodes/0")
    error = json.loads(body)["error"]
    assert status == 422 and "cut.rec.npz" in error and "agent_vehicle" in error
