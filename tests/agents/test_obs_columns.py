"""The agents' named observation columns (``agents.obs_columns``) are the env's, and agents/ index
the observation by those names, never by bare numbers."""

import ast
from pathlib import Path

import pytest

from agents.obs_columns import (
    GOAL_XY,
    NEIGHBOUR_XY,
    Ego,
    Goal,
    Neighbour,
    Signal,
    Waypoint,
    WaypointPath,
    column_names,
)
from smarts.sensors import observation as env_obs
from smarts.sensors.interface import interface_from_dict

AGENTS = Path(__file__).resolve().parents[2] / "agents"


@pytest.mark.parametrize(
    ("layout", "env_names"),
    [
        (Ego, env_obs.EGO_FEATURE_NAMES),
        (Neighbour, env_obs.NEIGHBOUR_FEATURE_NAMES),
        (Goal, env_obs.GOAL_FEATURE_NAMES),
        (Signal, env_obs.SIGNAL_FEATURE_NAMES),
        (Waypoint, env_obs.WAYPOINT_FEATURE_NAMES),
        (WaypointPath, env_obs.PATH_NAMES),
    ],
)
def test_names_are_the_envs(layout, env_names):
    assert column_names(layout) == tuple(env_names)
    assert sorted(int(m) for m in layout) == list(range(len(env_names)))


def test_slices_name_the_position_columns():
    assert column_names(Neighbour)[NEIGHBOUR_XY] == ("dx", "dy")
    assert column_names(Goal)[GOAL_XY] == ("dx", "dy")


@pytest.mark.parametrize(
    "interface",
    [
        {"signals": True},
        {
            "signals": True,
            "ego": {"extended": True},
            "neighbours": {"count": 4, "extended": True},
            "occlusion": {"enabled": True},
            "waypoints": {"count": 7},
        },
    ],  # fmt: skip
)
def test_the_env_observation_has_these_columns_first(interface):
    """The shapes the env builds, and with extended sensors the named columns still come first."""
    iface = interface_from_dict(interface)
    space = env_obs.observation_space(iface).spaces
    assert env_obs.ego_feature_names(iface)[: len(Ego)] == column_names(Ego)
    assert env_obs.neighbour_feature_names(iface)[: len(Neighbour)] == column_names(Neighbour)
    assert space["ego"].shape == (len(env_obs.ego_feature_names(iface)),)
    assert space["neighbours"].shape[-1] == len(env_obs.neighbour_feature_names(iface))
    assert space["goal"].shape == (len(Goal),)
    assert space["signal"].shape == (len(Signal),)
    assert space["waypoints"].shape[0] == len(WaypointPath) and space["waypoints"].shape[-1] == len(Waypoint)
    assert space["waypoint_mask"].shape[0] == len(WaypointPath)


OBS_KEYS = {"ego", "neighbours", "goal", "signal", "waypoints", "waypoint_mask"}
OBS_NAMES = {"ego", "nb", "goal", "sig", "wp"}
"""Names the agents give observation arrays (``ego = row["ego"]``, ``nb = row["neighbours"]``, ...)."""


def _observation_array(node: ast.expr) -> bool:
    """``ego``, ``nb``, ... or ``obs["ego"]``, ``row["neighbours"]`` (a key of the observation)."""
    if isinstance(node, ast.Name):
        return node.id in OBS_NAMES
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):  # ego.astype(...)
        return _observation_array(node.func.value)
    return (isinstance(node, ast.Subscript) and isinstance(node.slice, ast.Constant)
            and node.slice.value in OBS_KEYS)  # fmt: skip


def _numbers(index: ast.expr) -> list[int]:
    """Integer literals used directly as an index or slice bound."""
    parts = index.elts if isinstance(index, ast.Tuple) else [index]
    found = []
    for part in parts:
        bounds = [part.lower, part.upper] if isinstance(part, ast.Slice) else [part]
        for b in bounds:
            if isinstance(b, ast.UnaryOp) and isinstance(b.op, ast.USub):
                b = b.operand
            if isinstance(b, ast.Constant) and type(b.value) is int:
                found.append(b.value)
    return found


def test_agents_index_the_observation_by_name():
    raw = []
    for path in sorted(AGENTS.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Subscript) and _observation_array(node.value) and _numbers(node.slice):
                raw.append(f"{path.relative_to(AGENTS.parent)}:{node.lineno}: {ast.unparse(node)}")
    assert not raw, "raw observation column numbers (use agents.obs_columns):\n" + "\n".join(raw)
