"""The viewer page in a real headless browser (Debian's chromium through selenium): it loads a
recorded episode and draws its vehicles, clicking an agent or a lane opens its panel, seeking
moves time, a live env streams into it, a benchmark log shows its metrics; a screenshot is taken.
Markup in a recording's metadata, a recording's file name or a live episode is shown as text and
runs nothing, and the page's Content-Security-Policy blocks inline script.

Run with ``python -m pytest -m browser tests/viz`` (the default test run leaves these out;
.ci/run installs chromium and runs them). A missing browser fails, it does not skip.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from smarts.viz.recording import read_recording
from smarts.viz.server import BackgroundServer

pytestmark = pytest.mark.browser

CHROMIUM = "/usr/bin/chromium"
CHROMEDRIVER = "/usr/bin/chromedriver"
FLAGS = ("--headless --no-sandbox --disable-gpu --disable-quic --no-first-run --disable-background-networking "
         "--disable-component-update --disable-sync --disable-dev-shm-usage --window-size=1280,800").split()  # fmt: skip


@pytest.fixture(scope="module")
def browser():
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    for path in (CHROMIUM, CHROMEDRIVER):
        assert Path(path).is_file(), f"{path} is missing: apt-get install -y chromium chromium-driver"
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in FLAGS:
        options.add_argument(flag)
    profile = tempfile.mkdtemp(prefix="smarts-viz-chromium-")
    options.add_argument(f"--user-data-dir={profile}")
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    driver.set_page_load_timeout(60)
    yield driver
    driver.quit()
    shutil.rmtree(profile, ignore_errors=True)


@pytest.fixture(scope="module")
def served(recorded, benchmark_log, benchmark_log_with_traffic, tmp_path_factory):
    """Episode 0: the recording; 1: the a01 benchmark log; 2: the a09 one (lead, traffic, signals)."""
    folder = tmp_path_factory.mktemp("page")
    (folder / "a.rec.npz").write_bytes(recorded["path"].read_bytes())
    for log in (benchmark_log, benchmark_log_with_traffic):
        logs = folder / "adaptive" / "001" / "logs" / "zoo_keep-lane" / log.parent.name
        logs.mkdir(parents=True)
        (logs / "episode_000.npz").write_bytes(log.read_bytes())
    with BackgroundServer(folder) as srv:
        yield srv


def wait_for(driver, script: str, timeout: float = 30.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = driver.execute_script(script)
        if value:
            return value
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for: {script}")


def open_episode(driver, url: str, episode: str) -> None:
    driver.get(f"{url}/?episode={episode}")
    wait_for(driver, "return window.viz.ep && window.viz.ep.frames.length > 0")


def click_canvas_at(driver, x: float, y: float) -> None:
    """A real mouse click at canvas CSS pixel (x, y)."""
    from selenium.webdriver.common.action_chains import ActionChains

    canvas = driver.find_element("id", "canvas")
    rect = canvas.rect
    ActionChains(driver).move_to_element_with_offset(
        canvas, x - rect["width"] / 2, y - rect["height"] / 2
    ).click().perform()


def body_point(driver, vehicle: str) -> list[float]:
    """Canvas CSS pixel inside a vehicle's box, off its heading mark (a quarter length behind its
    centre)."""
    return driver.execute_script(
        "const v = window.viz, f = v.ep.frames[v.cur], i = f.ids.indexOf(arguments[0]);"
        "const d = -f.length[i] / 4;"
        "return v.screenOfPoint(f.x[i] + d * Math.cos(f.h[i]), f.y[i] + d * Math.sin(f.h[i]));", vehicle)  # fmt: skip


def pixel(driver, x: float, y: float) -> list[int]:
    return driver.execute_script(
        "const c = document.getElementById('canvas'); const s = c.width / c.clientWidth;"
        "return Array.from(c.getContext('2d').getImageData(arguments[0] * s, arguments[1] * s, 1, 1).data);", x, y)  # fmt: skip


def field(driver, table: str, name: str) -> str:
    return driver.find_element("css selector", f'#{table} td[data-field="{name}"]').text


def test_recorded_episode_draws_vehicles_and_agent_panel(browser, served, recorded):
    rec = read_recording(recorded["path"])
    open_episode(browser, served.url, "0")
    assert wait_for(browser, "return document.getElementById('status').textContent").startswith("recording")
    step = 40
    browser.execute_script("window.viz.goTo(arguments[0])", step)
    frame = rec.frame(step)
    roles = frame["vehicle_role"]
    traffic = frame["vehicle_ids"][int(np.flatnonzero(roles == 3)[0])]
    x, y = body_point(browser, traffic)
    time.sleep(0.2)
    assert pixel(browser, x, y)[:3] == [70, 130, 230]  # a traffic vehicle's colour where it is
    agent = rec.agent_ids[0]
    x, y = body_point(browser, agent)
    assert pixel(browser, x, y)[:3] == [230, 60, 50]
    click_canvas_at(browser, x, y)
    wait_for(browser, "return !document.getElementById('agent-panel').hidden")
    assert browser.find_element("id", "agent-id").text == agent
    speed = float(frame["vehicle_state"][frame["vehicle_ids"].index(agent), 3])
    assert field(browser, "agent-table", "speed") == f"{speed:.2f} m/s"
    assert field(browser, "agent-table", "reward") != "–"
    action = rec.frame(step)["agents"][agent]["action"]  # the fields by name and unit
    for name, value in zip(("dx (m)", "dy (m)", "dheading (rad)"), action):
        assert float(field(browser, "agent-table", f"action {name}")) == pytest.approx(float(value), abs=6e-4)
    assert field(browser, "agent-table", "lane").startswith(("south_in", ":center"))


def test_click_lane_shows_its_details(browser, served, recorded):
    rec = read_recording(recorded["path"])
    open_episode(browser, served.url, "0")
    lanes = rec.scene["lanes"]
    frame = rec.frame(0)
    xy = frame["vehicle_state"][:, :2]
    for k, lane in enumerate(lanes):  # a road lane with no vehicle near its middle
        mid = (
            np.asarray(lane["points"])[len(lane["points"]) // 2]
            if len(lane["points"]) > 2
            else np.mean(lane["points"], 0)
        )
        if not lane["internal"] and lane["length"] > 30 and (not len(xy) or np.hypot(*(xy - mid).T).min() > 8):
            break
    x, y = browser.execute_script("return window.viz.screenOfPoint(arguments[0], arguments[1])", *mid.tolist())
    click_canvas_at(browser, x, y)
    wait_for(browser, "return !document.getElementById('lane-panel').hidden")
    assert browser.find_element("id", "lane-id").text == lane["id"]
    assert field(browser, "lane-table", "road") == lane["road"]
    assert field(browser, "lane-table", "width") == f"{lane['width']:.2f} m"
    successors = ", ".join(lanes[i]["id"] for i in lane["successors"]) or "none"
    assert field(browser, "lane-table", "successors") == successors
    assert browser.execute_script("return window.viz.selectedLane") == k


def test_seek_and_step_move_time(browser, served, recorded):
    from selenium.webdriver.common.action_chains import ActionChains

    open_episode(browser, served.url, "0")
    assert browser.execute_script("return window.viz.cur") == 0
    seek = browser.find_element("id", "seek")
    ActionChains(browser).move_to_element_with_offset(seek, seek.rect["width"] * 0.25, 0).click().perform()
    cur = wait_for(browser, "return window.viz.cur")
    assert cur > recorded["steps"] * 0.6
    shown = browser.find_element("id", "time").text
    assert shown == f"t = {cur * 0.1:.1f} s · step {cur}"
    browser.find_element("id", "step-back").click()
    assert browser.execute_script("return window.viz.cur") == cur - 1
    browser.find_element("id", "play").click()
    time.sleep(1.0)
    browser.find_element("id", "play").click()
    assert browser.execute_script("return window.viz.cur") > cur


def test_benchmark_log_shows_metrics(browser, served):
    open_episode(browser, served.url, "1")
    assert "S_bench" in browser.find_element("id", "episode-table").text
    agent = browser.execute_script("return window.viz.ep.meta.agent_ids[0]")
    browser.execute_script("window.viz.goTo(20)")
    x, y = browser.execute_script("return window.viz.screenOf(arguments[0])", agent)
    click_canvas_at(browser, x, y)
    wait_for(browser, "return !document.getElementById('agent-panel').hidden")
    assert "Benchmark costs" in browser.find_element("id", "agent-metrics").text
    assert float(field(browser, "agent-table", "speed_limit")) > 0


def test_benchmark_log_draws_the_lead_the_traffic_and_the_signals(browser, served, benchmark_log_with_traffic):
    from smarts.benchmark.metrics import read_episode

    log = read_episode(benchmark_log_with_traffic)
    scene = log.scene
    lead = scene.leads["agent_0"]
    # A row where the lead and a traffic vehicle are both on the map near the agent.
    row = next(k for k in range(scene.num_rows)
               if (ids := [scene.ids[i] for i in scene.index[scene.at(k)]]) and lead in ids and len(ids) >= 3)  # fmt: skip
    open_episode(browser, served.url, "2")
    assert "the lead" in browser.find_element("id", "episode-table").text  # the note says what a log holds
    step = browser.execute_script("return window.viz.ep.frames.findIndex((f) => Math.abs(f.t - arguments[0]) < 1e-4)",
                                  float(scene.time[row]))  # fmt: skip
    browser.execute_script("window.viz.goTo(arguments[0])", step)
    frame = browser.execute_script("return window.viz.ep.frames[window.viz.cur]")
    assert lead in frame["ids"] and frame["role"][frame["ids"].index(lead)] == 6
    traffic = [v for v, r in zip(frame["ids"], frame["role"]) if r == 3]
    assert traffic and len(frame["signals"]) == log.signals == 16
    time.sleep(0.2)
    for vehicle, colour in ((lead, [29, 233, 182]), (traffic[0], [70, 130, 230]), ("agent_0", [230, 60, 50])):
        x, y = body_point(browser, vehicle)
        assert pixel(browser, x, y)[:3] == colour, vehicle
    # The agent's panel names its lead.
    click_canvas_at(browser, *body_point(browser, "agent_0"))
    wait_for(browser, "return !document.getElementById('agent-panel').hidden")
    assert field(browser, "agent-table", "lead") == lead


def test_the_camera_follows_the_selected_agent(browser, served):
    open_episode(browser, served.url, "2")
    browser.execute_script("window.viz.goTo(10)")
    click_canvas_at(browser, *body_point(browser, "agent_0"))
    wait_for(browser, "return window.viz.selectedAgent === 'agent_0'")

    def centre_and_agent():
        return browser.execute_script(
            "const v = window.viz, f = v.ep.frames[v.cur], i = f.ids.indexOf('agent_0');"
            "return [v.view.cx, v.view.cy, f.x[i], f.y[i], v.view.scale];")  # fmt: skip

    for k in (10, 40, 80):
        browser.execute_script("window.viz.goTo(arguments[0])", k)
        wait_for(browser, "return !window.viz.dirty")
        cx, cy, x, y, scale = centre_and_agent()
        assert (cx, cy) == pytest.approx((x, y)) and scale >= 5, k
    # Unticked, the view stays where it is.
    browser.find_element("id", "follow-cam").click()
    before = centre_and_agent()
    browser.execute_script("window.viz.goTo(120)")
    wait_for(browser, "return !window.viz.dirty")
    after = centre_and_agent()
    assert after[:2] == before[:2] and after[2] != before[2]
    browser.find_element("id", "follow-cam").click()


def test_live_env_streams_into_the_page(browser, tmp_path):
    from smarts.env import DrivingParallelEnv
    from smarts.viz.watch import WatchedEnv

    with BackgroundServer() as srv:
        env = WatchedEnv(DrivingParallelEnv("intersection_4way_signal_right"), live=srv.url)
        assert env.publisher.connected.wait(30)
        obs, _ = env.reset(seed=0)
        browser.get(f"{srv.url}/?episode=live")
        wait_for(browser, "return window.viz.ep && window.viz.ep.kind === 'live'")
        deadline = time.monotonic() + 30
        while not env.publisher.watching and time.monotonic() < deadline:
            time.sleep(0.02)
        for _ in range(30):
            obs, *_ = env.step({a: 0.4 * obs[a]["waypoints"][0, 1] for a in env.agents})
        frames = wait_for(browser, "return window.viz.ep.frames.length >= 30 && window.viz.ep.frames.length")
        assert frames == 30
        x, y = body_point(browser, "agent_0")
        time.sleep(0.2)
        assert pixel(browser, x, y)[:3] == [230, 60, 50]
        row = env.sim.table.row_of["agent_0"]
        last = browser.execute_script(
            "const f = window.viz.ep.frames.at(-1); return [f.step, f.x[f.ids.indexOf('agent_0')]]"
        )
        assert last[0] == 30 and abs(last[1] - env.sim.table.x[row]) < 0.01
        env.close()


def test_screenshot(browser, served, tmp_path):
    open_episode(browser, served.url, "0")
    agent = browser.execute_script("return window.viz.ep.meta.agent_ids[0]")
    browser.execute_script(  # step 60, zoomed in around the junction
        "const v = window.viz; v.goTo(60); v.view.cx = 0; v.view.cy = -10; v.view.scale *= 3; v.dirty = true;"
    )
    x, y = browser.execute_script("return window.viz.screenOf(arguments[0])", agent)
    click_canvas_at(browser, x, y)
    wait_for(browser, "return !document.getElementById('agent-panel').hidden")
    out = Path(os.environ.get("SMARTS_VIZ_SCREENSHOT", tmp_path / "viz.png"))
    assert browser.save_screenshot(str(out))
    from PIL import Image

    with Image.open(out) as image:
        assert image.size[0] >= 1000 and np.asarray(image.convert("RGB")).std() > 10


def test_click_traffic_vehicle_shows_its_role_and_speed(browser, served, recorded):
    rec = read_recording(recorded["path"])
    open_episode(browser, served.url, "0")
    browser.execute_script("window.viz.goTo(40)")
    frame = rec.frame(40)
    k = int(np.flatnonzero(frame["vehicle_role"] == 3)[0])
    vehicle = frame["vehicle_ids"][k]
    click_canvas_at(browser, *body_point(browser, vehicle))
    wait_for(browser, "return !document.getElementById('vehicle-panel').hidden")
    assert browser.find_element("id", "vehicle-id").text == vehicle
    assert field(browser, "vehicle-table", "role") == "traffic"
    assert field(browser, "vehicle-table", "speed") == f"{float(frame['vehicle_state'][k, 3]):.2f} m/s"
    assert browser.find_element("id", "agent-panel").get_attribute("hidden") is not None


def test_jump_to_the_next_event(browser, finished):
    from selenium.webdriver.support.ui import Select

    rec = read_recording(finished)
    goal = rec.meta["events"].index("reached_goal")
    first = {a: int(np.flatnonzero(rec.arrays["agent_events"][:, j, goal])[0]) for j, a in enumerate(rec.agent_ids)}
    with BackgroundServer(finished) as srv:
        open_episode(browser, srv.url, "0")
        Select(browser.find_element("id", "event")).select_by_visible_text("reached_goal")
        browser.find_element("id", "next-event").click()
        agent, step = min(first.items(), key=lambda item: item[1])
        assert browser.execute_script("return window.viz.cur") == step
        assert browser.find_element("id", "agent-id").text == agent
        assert "reached_goal" in field(browser, "agent-table", "events")
        browser.find_element("id", "next-event").click()  # the other agent's arrival comes next
        other = max(first.items(), key=lambda item: item[1])
        assert browser.execute_script("return window.viz.cur") == other[1]
        assert browser.find_element("id", "agent-id").text == other[0]


# ------------------------------------------------------------------------------- hostile text
def hostile_copy(source: Path, path: Path, text: str) -> Path:
    """A copy of a recording whose scenario, one event name, its first agent and that agent's
    vehicle are all called ``text``."""
    with np.load(source, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    meta = json.loads(str(arrays["metadata"]))
    agent = meta["agent_ids"][0]
    meta["scenario"] = text
    meta["events"] = [*meta["events"], text]
    meta["agent_ids"][0] = text
    meta["vehicle_ids"] = [text if v == agent else v for v in meta["vehicle_ids"]]
    arrays["metadata"] = np.array(json.dumps(meta))
    np.savez_compressed(path, **arrays)
    return path


def assert_no_script_ran(driver) -> None:
    """The payload's handler did not run and no element was made from it."""
    time.sleep(0.5)  # a failed image load would have fired its handler by now
    assert driver.execute_script("return window.__pwned") is None
    assert driver.title == "smarts viz"
    assert driver.execute_script("return document.querySelectorAll('img, [onerror]').length") == 0


def shown_literally(driver, payload: str) -> None:
    """The payload is on the page as the text it is: scenario, event list, agents, agent panel."""
    from selenium.webdriver.support.ui import Select

    assert field(driver, "episode-table", "scenario") == payload
    assert payload in field(driver, "episode-table", "agents").split(", ")
    assert payload in [o.text for o in Select(driver.find_element("id", "event")).options]
    driver.execute_script("window.viz.selectedAgent = arguments[0]; window.viz.goTo(0);", payload)
    wait_for(driver, "return !document.getElementById('agent-panel').hidden")
    assert driver.find_element("id", "agent-id").text == payload
    assert field(driver, "agent-table", "vehicle") == payload


def test_recording_metadata_is_shown_as_text_not_run(browser, recorded, tmp_path):
    from tests.viz.messages import PAYLOAD

    hostile_copy(recorded["path"], tmp_path / "hostile.rec.npz", PAYLOAD)
    with BackgroundServer(tmp_path) as srv:
        open_episode(browser, srv.url, "0")
        assert PAYLOAD in browser.find_element("id", "status").text
        shown_literally(browser, PAYLOAD)
        assert_no_script_ran(browser)


def test_recording_file_name_is_shown_as_text_not_run(browser, recorded, tmp_path):
    from selenium.webdriver.support.ui import Select

    from tests.viz.messages import PAYLOAD

    (tmp_path / f"{PAYLOAD}.rec.npz").write_bytes(recorded["path"].read_bytes())
    with BackgroundServer(tmp_path) as srv:
        open_episode(browser, srv.url, "0")
        options = [o.text for o in Select(browser.find_element("id", "episode")).options]
        assert options == [f"{PAYLOAD}.rec.npz (recording)", "live"]
        assert_no_script_ran(browser)


def test_live_episode_is_shown_as_text_not_run(browser):
    from tests.viz.messages import PAYLOAD, episode, frame, text, ws_connect

    live_frame = frame()
    f = live_frame["frame"]
    f["ids"][0] = PAYLOAD
    f["agents"] = {PAYLOAD: {**f["agents"]["agent_0"], "vehicle": PAYLOAD, "events": [PAYLOAD]}}
    with BackgroundServer() as srv, ws_connect(srv.port, "/ws/source") as source:
        source.send(text(episode(scenario=PAYLOAD, agent_ids=[PAYLOAD], events=[PAYLOAD])))
        browser.get(f"{srv.url}/?episode=live")
        wait_for(browser, "return window.viz.ep && window.viz.ep.kind === 'live'")
        while json.loads(source.recv(timeout=30)) != {"type": "watching", "value": True}:
            pass  # the page is watching: frames are kept and relayed
        source.send(text(live_frame))
        wait_for(browser, "return window.viz.ep.frames.length === 1")
        assert browser.find_element("id", "status").text == f"live: {PAYLOAD} (seed 0)"
        shown_literally(browser, PAYLOAD)
        assert field(browser, "agent-table", "events") == PAYLOAD
        assert_no_script_ran(browser)


def test_content_security_policy_blocks_inline_script(browser, served):
    open_episode(browser, served.url, "0")
    browser.execute_script(
        "const s = document.createElement('script'); s.textContent = 'window.__inline = 1;'; document.body.append(s);"
        "const d = document.createElement('div'); d.setAttribute('onclick', 'window.__inline = 2'); "
        "document.body.append(d); d.click();")  # fmt: skip
    time.sleep(0.2)
    assert browser.execute_script("return window.__inline") is None
    assert browser.execute_script("return window.viz.ep.frames.length") > 0  # the page's own script runs
