"""Physical fields of a scenario file are bounded in the schema (no map needed): speeds, step
counts and length, times, flow rates, seeds and the vehicle table's size, each problem naming its
field."""

from __future__ import annotations

import pytest

from smarts.scenario import ScenarioError, read_scenario
from tests.builders import with_

CROSS = {
    "name": "cross",
    "map": "builtin:intersection_4way_1lane",
    "agents": [{"mission": {"start": {"road": "west_in", "offset": 20, "speed": 8}, "goal": {"road": "north_out"}}}],
}


BOUNDS = [
    # (field, value, expected message after "inline: <field>: ")
    ("agents__0__mission__start__speed", 1e30, "input should be less than or equal to 70, got 1e+30"),
    ("agents__0__mission__start__speed", float("inf"), "input should be a finite number, got inf"),
    ("agents__0__mission__start__speed", -1.0, "input should be greater than or equal to 0, got -1.0"),
    ("agents__0__mission__start__offset", float("nan"), "input should be a finite number, got nan"),
    ("agents__0__mission__start__heading", float("inf"), "input should be a finite number, got inf"),
    ("episode_steps", 10**21, "input should be less than or equal to 10000000, got 1000000000000000000000"),
    ("step_length", 0.0, "input should be greater than 0, got 0.0"),
    ("step_length", 1.5, "input should be less than or equal to 1, got 1.5"),
    ("seed", 2**64, "input should be less than or equal to 18446744073709551615, got 18446744073709551616"),
    ("vehicle_capacity", 10**9, "input should be less than or equal to 100000, got 1000000000"),
    ("traffic__flows__0__rate", 1e9, "input should be less than or equal to 10000, got 1000000000.0"),
    ("traffic__flows__0__end", 1e300, "input should be less than or equal to 10000000, got 1e+300"),
    (
        "traffic__flows__0__depart_speed",
        200.0,
        "expected one of max, desired, random or a speed in m/s from 0 to 70, got 200.0",
    ),
    ("traffic__flows__0__depart_speed", 56.0, "expected at most vehicle type 'car''s max_speed (55 m/s), got 56"),
    ("traffic__trips__0__depart", 1e12, "input should be less than or equal to 10000000, got 1000000000000.0"),
    ("traffic__vehicle_types__fast__max_speed", 100.0, "input should be less than or equal to 70, got 100.0"),
    ("traffic__pedestrians__0__rate", 1e6, "input should be less than or equal to 10000, got 1000000.0"),
    ("traffic__pedestrians__0__speed", 30.0, "input should be less than or equal to 10, got 30.0"),
]


@pytest.mark.parametrize("dotted,value,expected", BOUNDS, ids=[f"{b[0].replace('__', '.')}={b[1]!r}" for b in BOUNDS])
def test_physical_fields_are_bounded_naming_the_field(dotted, value, expected):
    data = with_(CROSS, traffic={
        "engine": "sumo",
        "vehicle_types": {"fast": {}},
        "flows": [{"id": "f", "route": ["west_in"], "rate": 60}],
        "trips": [{"id": "t", "route": ["east_in"]}],
        "pedestrians": [{"id": "p", "origin": "west_in", "destination": "east_out", "rate": 60}],
    })  # fmt: skip
    read_scenario(data, source="inline")  # valid as it is
    with pytest.raises(ScenarioError) as info:
        read_scenario(with_(data, **{dotted: value}), source="inline")
    assert (
        str(info.value)
        == f"inline: {dotted.replace('__', '.').replace('.0.', '[0].').replace('.0', '[0]')}: {expected}"
    )


def test_the_bounds_are_at_their_documented_values():
    from smarts.core.simulation import SEED_MAX
    from smarts.core.spec import scenario, traffic

    assert (scenario.MAX_SPEED, traffic.MAX_FLOW_RATE, scenario.MAX_EPISODE_STEPS) == (70.0, 10_000.0, 10_000_000)
    assert scenario.SEED_MAX == SEED_MAX == 2**64 - 1
    edge = with_(
        CROSS, seed=2**64 - 1, episode_steps=10_000_000, step_length=1.0, agents__0__mission__start__speed=70.0
    )
    spec = read_scenario(edge)
    assert (spec.seed, spec.episode_steps, spec.agents[0].mission.start.speed) == (2**64 - 1, 10_000_000, 70.0)
