"""Scenario specs for tests, built on the project's own maps (real netconvert output)."""

from __future__ import annotations

from smarts.scenario import ScenarioSpec


def make_spec(agents: list[dict], *, map_name: str = "straight_2lane", **extra) -> ScenarioSpec:
    """A scenario spec from agent dicts (missions as in YAML), validated like a file."""
    data = {"name": "test", "map": f"builtin:{map_name}", "agents": agents, **extra}
    return ScenarioSpec.from_dict(data, source="test-scenario")


def agent(start_road="main", lane=0, offset=10.0, speed=10.0, goal=None, action_space="relative_target_pose", **kw):
    return {
        "action_space": action_space,
        "mission": {
            "start": {"road": start_road, "lane": lane, "offset": offset, "speed": speed},
            "goal": goal or {"endless": True},
        },
        **kw,
    }
