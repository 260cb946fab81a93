"""The episode recording: what WatchedEnv writes is what the simulator held, and it reads back
exactly; malformed files are refused naming the file and the array."""

from __future__ import annotations

import io
import json
import zipfile

import numpy as np
import pytest

from smarts.core.errors import LogError
from smarts.core.vehicle_table import Role
from smarts.viz.recording import FORMAT_NAME, read_recording, write_recording


def test_recording_holds_every_vehicle_of_every_step(recorded):
    rec = read_recording(recorded["path"])
    assert rec.meta["format"] == FORMAT_NAME
    assert rec.num_steps == recorded["steps"] + 1  # the reset state, then one row per step
    assert rec.agent_ids == recorded["agents"]
    for step in (1, 30, recorded["steps"]):
        frame = rec.frame(step)
        truth = recorded["truth"][step]
        assert sorted(frame["vehicle_ids"]) == sorted(truth)
        for vid, state in zip(frame["vehicle_ids"], frame["vehicle_state"]):
            x, y, _, speed = state[:4]  # x, y, heading, speed, length, width
            assert (x, y, speed) == pytest.approx(truth[vid], abs=1e-3)
    roles = set(rec.arrays["vehicle_role"].tolist())
    assert int(Role.AGENT) in roles and int(Role.TRAFFIC) in roles
    assert len(rec.scene["signals"]) > 0 and rec.arrays["signal_colour"].shape[1] == len(rec.scene["signals"])
    assert set(np.unique(rec.arrays["signal_colour"])) >= {1, 3}  # red and green both shown


def test_agents_actions_rewards_and_observations(recorded):
    rec = read_recording(recorded["path"])
    a = rec.arrays
    assert np.isnan(a["agent_reward"][0]).all() and np.isnan(a["agent_action"][0]).all()  # reset state
    assert np.isfinite(a["agent_reward"][1:]).all() and np.isfinite(a["agent_action"][1:, :, :2]).all()
    frame = rec.frame(10)
    agent = frame["agents"][rec.agent_ids[0]]
    i = frame["vehicle_ids"].index(agent["vehicle"])
    x, y = frame["vehicle_state"][i, :2]
    path = agent["waypoints"][0]
    first = path[~np.isnan(path[:, 0])][0]
    assert np.hypot(first[0] - x, first[1] - y) < 5.0  # waypoints start at the agent, in map coordinates
    assert any(
        len(rec.frame(k)["agents"].get(rec.agent_ids[0], {}).get("neighbours", [])) for k in range(rec.num_steps)
    )


def test_write_read_round_trip(recorded, tmp_path):
    rec = read_recording(recorded["path"])
    again = read_recording(write_recording(rec, tmp_path / "copy.rec.npz"))
    assert again.meta == rec.meta and again.scene == rec.scene
    for name, values in rec.arrays.items():
        np.testing.assert_array_equal(again.arrays[name], values, err_msg=name)
    assert json.dumps(again.page_json()["frames"], allow_nan=False) == json.dumps(
        rec.page_json()["frames"], allow_nan=False
    )


def _rewrite(src, dst, change):
    with np.load(src, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    change(arrays)
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    dst.write_bytes(buffer.getvalue())
    return dst


@pytest.mark.parametrize(
    "change, column",
    [
        (lambda a: a.pop("vehicle_state"), "vehicle_state"),
        (lambda a: a.__setitem__("vehicle_offsets", a["vehicle_offsets"][:-1]), "vehicle_offsets"),
        (lambda a: a.__setitem__("agent_vehicle", a["agent_vehicle"] + 1000), "agent_vehicle"),
        (lambda a: a.__setitem__("agent_reward", a["agent_reward"][:, :0]), "agent_reward"),
        (lambda a: a.__setitem__("metadata", np.array('{"format": "other"}')), "metadata"),
    ],
)
def test_malformed_recordings_name_file_and_array(recorded, tmp_path, change, column):
    bad = _rewrite(recorded["path"], tmp_path / "bad.rec.npz", change)
    with pytest.raises(LogError) as err:
        read_recording(bad)
    assert err.value.column == column and str(bad) in str(err.value)


def test_not_a_recording(tmp_path):
    junk = tmp_path / "junk.rec.npz"
    junk.write_bytes(b"not a zip")
    with pytest.raises(LogError, match="junk.rec.npz: not a readable .npz episode recording"):
        read_recording(junk)
    assert not zipfile.is_zipfile(junk)


def _edit_json(name: str, edit):
    """A change to ``_rewrite`` that edits the JSON entry ``name`` (metadata or scene)."""

    def change(arrays):
        value = json.loads(str(arrays[name]))
        edit(value)
        arrays[name] = np.array(json.dumps(value))

    return change


@pytest.mark.parametrize(
    "change, fragment",
    [
        (_edit_json("scene", lambda s: s["lanes"][0]["successors"].append(10**6)), "lanes.0.successors"),
        (_edit_json("scene", lambda s: s.__setitem__("lanes", "<b>")), "scene.lanes"),
        (_edit_json("scene", lambda s: s["lanes"][0].__setitem__("onclick", "x")), "onclick"),
        (_edit_json("metadata", lambda m: m.__setitem__("scenario", {"html": "<b>"})), "'scenario'"),
        (_edit_json("metadata", lambda m: m.__setitem__("events", 5)), "'events'"),
    ],
    ids=[
        "successor out of range",
        "lanes not a list",
        "unknown lane field",
        "scenario not a string",
        "events not a list",
    ],
)
def test_recording_map_and_names_are_checked_as_the_page_reads_them(recorded, tmp_path, change, fragment):
    """The page draws a recording's map and lists its names as they are: a file that would break
    it is refused naming the entry, like a live env's message."""
    bad = _rewrite(recorded["path"], tmp_path / "bad.rec.npz", change)
    with pytest.raises(LogError) as err:
        read_recording(bad)
    assert err.value.column in ("scene", "metadata") and fragment in str(err.value) and str(bad) in str(err.value)
