"""Scenario specs for tests, built on the project's own maps (real netconvert output)."""

from __future__ import annotations

import copy
import tempfile
from pathlib import Path

import pytest

from smarts.scenario import ScenarioSpec, read_scenario


def make_spec(agents: list[dict], *, map_name: str = "straight_2lane", **extra) -> ScenarioSpec:
    """A scenario spec from agent dicts (missions as in YAML), validated like a file."""
    data = {"name": "test", "map": f"builtin:{map_name}", "agents": agents, **extra}
    return read_scenario(data, source="test-scenario")


def agent(start_road="main", lane=0, offset=10.0, speed=10.0, goal=None, action_space="relative_target_pose", **kw):
    return {
        "action_space": action_space,
        "mission": {
            "start": {"road": start_road, "lane": lane, "offset": offset, "speed": speed},
            "goal": goal or {"endless": True},
        },
        **kw,
    }


def with_(base: dict, **changes) -> dict:
    """A deep copy of ``base`` with fields set, ``__`` between the parts of a path
    (``agents__0__mission__goal``)."""
    data = copy.deepcopy(base)
    for dotted, value in changes.items():
        node = data
        parts = dotted.split("__")
        for part in parts[:-1]:
            node = node[int(part)] if part.isdigit() else node.setdefault(part, {})
        node[int(parts[-1]) if parts[-1].isdigit() else parts[-1]] = value
    return data


def _permission_bits_bind() -> bool:
    """Whether a 0o500 folder refuses writes here (not for root, which bypasses the bits)."""
    with tempfile.TemporaryDirectory() as d:
        probe = Path(d) / "ro"
        probe.mkdir()
        probe.chmod(0o500)
        try:
            (probe / "x").write_text("")
        except PermissionError:
            return True
        finally:
            probe.chmod(0o700)
        return False


PERMISSIONS_SKIP = pytest.mark.skipif(
    not _permission_bits_bind(),
    reason="permission bits do not stop this user (root); the path-under-a-file tests cover the fallback",
)
