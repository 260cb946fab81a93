"""Agent interfaces: YAML validation naming the field, round trips, and the spaces they give."""

import numpy as np
import pytest
import yaml

from smarts.core.errors import InterfaceError
from smarts.core.vehicle_table import VehicleType
from smarts.scenario import ScenarioError, read_scenario, scenario_to_yaml
from smarts.sensors.interface import (
    RASTER_LAYERS,
    AgentInterface,
    LidarInterface,
    RasterInterface,
    interface_from_dict,
)
from smarts.sensors.observation import (
    ObservationConfig,
    neighbour_feature_names,
    observation_space,
)
from tests.builders import agent, make_spec

DEFAULT_SHAPES = {
    "ego": (12,),
    "neighbours": (8, 9),
    "neighbour_mask": (8,),
    "waypoints": (3, 20, 3),
    "waypoint_mask": (3, 20),
    "goal": (4,),
    "signal": (4,),
    "events": (8,),
}


def _spec(interface):
    return make_spec([agent(), agent(lane=1, interface=interface)])


def test_the_default_interface_gives_the_basic_observation_unchanged():
    space = observation_space(AgentInterface())
    assert {k: s.shape for k, s in space.spaces.items()} == DEFAULT_SHAPES
    assert all(s.dtype == np.float32 for s in space.spaces.values())
    assert make_spec([agent()]).agents[0].interface is None


def test_observation_config_maps_onto_an_interface():
    interface = ObservationConfig(neighbours=4, neighbour_radius=20.0, waypoints=10, waypoint_spacing=3).interface()
    assert (interface.neighbours.count, interface.neighbours.radius) == (4, 20.0)
    assert (interface.waypoints.count, interface.waypoints.spacing) == (10, 3)
    space = observation_space(ObservationConfig(neighbours=4, waypoints=10))
    assert space["neighbours"].shape == (4, 9) and space["waypoints"].shape == (3, 10, 3)


def test_every_sensor_adds_keys_or_trailing_columns():
    data = {
        "ego": {"extended": True},
        "neighbours": {"count": 6, "radius": 40, "extended": True},
        "waypoints": {"count": 12, "spacing": 1},
        "occlusion": {"enabled": True, "mode": "flag", "range": 35},
        "rasters": {"size": 32, "resolution": 1.0, "layers": ["occupancy", "drivable"], "rgb": True},
        "lidar": {"rays": 90, "range": 25, "noise": 0.1},
        "signals": False,
    }
    interface = _spec(data).agents[1].interface
    assert interface.lidar == LidarInterface(rays=90, range=25.0, noise=0.1)
    space = observation_space(interface)
    shapes = {k: s.shape for k, s in space.spaces.items()}
    assert shapes["ego"] == (13,)
    names = neighbour_feature_names(interface)
    assert len(names) == 9 + 5 + len(VehicleType) + 1 and names[-1] == "visible_fraction" and names[12] == "lane_index"
    assert shapes["neighbours"] == (6, len(names)) and shapes["waypoints"] == (3, 12, 3)
    assert "signal" not in shapes
    assert shapes["rasters"] == (2, 32, 32) and space["rasters"].dtype == np.uint8
    assert shapes["rgb"] == (32, 32, 3) and space["rgb"].dtype == np.uint8
    assert shapes["lidar"] == (90,) and shapes["lidar_hit"] == (90,)
    assert space["lidar"].high.max() == pytest.approx(25.0)


@pytest.mark.parametrize(
    ("interface", "message"),
    [
        ({"lidar": {"rays": 0}}, "agents[1].interface.lidar.rays: input should be greater than or equal to 1, got 0"),
        ({"lidar": {"rays": 8.5}}, "agents[1].interface.lidar.rays: input should be a valid integer"),
        ({"lidar": {"range": -1}}, "agents[1].interface.lidar.range: input should be greater than 0"),
        ({"lidar": {"noise": -0.1}}, "agents[1].interface.lidar.noise: input should be greater than or equal to 0"),
        ({"lidar": {"rayz": 3}}, "agents[1].interface.lidar.rayz: unknown field; did you mean 'rays'?"),
        (
            {"rasters": {"layers": ["drivable", "roads"]}},
            "agents[1].interface.rasters.layers[1]: input should be 'drivable', 'lanes'",
        ),
        ({"rasters": {"layers": ["route", "route"]}}, "agents[1].interface.rasters.layers[1]: 'route' is listed twice"),
        ({"rasters": {"layers": "route"}}, "agents[1].interface.rasters.layers: input should be a valid list"),
        ({"rasters": {"layers": []}}, "agents[1].interface.rasters: expected at least one layer or rgb: true"),
        ({"rasters": {"size": 0}}, "agents[1].interface.rasters.size: input should be greater than or equal to 1"),
        ({"rasters": {"resolution": 0}}, "agents[1].interface.rasters.resolution: input should be greater than 0"),
        ({"rasters": {"rgb": "yes"}}, "agents[1].interface.rasters.rgb: input should be a valid boolean"),
        ({"occlusion": {"mode": "ghost"}}, "agents[1].interface.occlusion.mode: input should be 'hide' or 'flag'"),
        ({"occlusion": []}, "agents[1].interface.occlusion: input should be a valid dictionary"),
        (
            {"neighbours": {"count": -2}},
            "agents[1].interface.neighbours.count: input should be greater than or equal to 1",
        ),
        (
            {"neighbours": {"radius": True}},
            "agents[1].interface.neighbours.radius: input should be a valid number, got True",
        ),
        (
            {"waypoints": {"spacing": 0}},
            "agents[1].interface.waypoints.spacing: input should be greater than or equal to 1",
        ),
        ({"signals": 1}, "agents[1].interface.signals: input should be a valid boolean, got 1"),
        ({"lidars": {}}, "agents[1].interface.lidars: unknown field; did you mean 'lidar'?"),
        ([1, 2], "agents[1].interface: input should be a valid dictionary"),
    ],
)
def test_invalid_fields_are_named(interface, message):
    with pytest.raises(ScenarioError) as err:
        _spec(interface)
    assert str(err.value).startswith("test-scenario: " + message)


def test_interfaces_built_in_code_are_validated_too():
    with pytest.raises(ValueError, match=r"interface\.lidar\.rays: input should be greater than or equal to 1"):
        LidarInterface(rays=0)
    with pytest.raises(ValueError, match=r"interface\.rasters\.layers\[0\]"):
        RasterInterface(layers=("sky",))


def test_spec_round_trips_through_yaml_with_interfaces():
    interface = {
        "occlusion": {"enabled": True},
        "rasters": {"layers": ["drivable", "route"], "rgb": True},
        "lidar": True,  # on with its defaults
        "neighbours": {"extended": True},
    }
    spec = _spec(interface)
    assert spec.agents[1].interface.lidar == LidarInterface()
    again = read_scenario(yaml.safe_load(scenario_to_yaml(spec)), source="again")
    assert again == spec
    assert again.agents[0].interface is None
    assert interface_from_dict({"lidar": None, "rasters": False}) == AgentInterface()


def test_equal_interfaces_compare_equal_so_they_share_a_group():
    a = interface_from_dict({"rasters": {"layers": list(RASTER_LAYERS)}})
    b = AgentInterface(rasters=RasterInterface())
    assert a == b and hash(a) == hash(b)


def test_interface_from_dict_reports_every_problem_naming_the_first_field():
    with pytest.raises(InterfaceError) as err:
        interface_from_dict({"lidar": {"rays": 0, "rayz": 3}, "signals": "yes"}, "agents[0].interface")
    assert err.value.path == "agents[0].interface.lidar.rays"
    lines = str(err.value).splitlines()
    assert lines[0] == "agents[0].interface.lidar.rays: input should be greater than or equal to 1, got 0"
    assert lines[1].startswith("agents[0].interface.lidar.rayz: unknown field; did you mean 'rays'?")
    assert lines[2] == "agents[0].interface.signals: input should be a valid boolean, got 'yes'"
