"""Built-in traffic: malformed traffic specs fail at construction, naming the field."""

import pytest

from smarts.core.spec.traffic import (
    FlowSpec,
    PedestrianFlowSpec,
    TrafficSpec,
    TripSpec,
    VehicleTypeSpec,
)
from smarts.maps import load_map
from smarts.scenario import ScenarioError, builtin_map_path
from smarts.traffic.builtin import BuiltinTrafficProvider


def unchecked(model, *args, **fields):
    """``model`` built without its checks (``model_construct``): a spec the spec models refuse, to
    show the engine's own check names the field too."""
    return model.model_construct(**dict(zip(model.model_fields, args)), **fields)


@pytest.fixture(scope="module")
def t_junction():
    return load_map(builtin_map_path("t_junction"))


def _build(road_map, **traffic):
    return BuiltinTrafficProvider(TrafficSpec.model_construct(**traffic), road_map, 0.1)


@pytest.mark.parametrize(
    "traffic, field, words",
    [
        (
            {"flows": [unchecked(FlowSpec, "f", route=["west_in", "nowhere"], rate=100)]},
            "traffic.flows[0].route",
            "unknown road 'nowhere'",
        ),
        (
            {"flows": [unchecked(FlowSpec, "f", route=["east_out", "west_in"], rate=100)]},
            "traffic.flows[0].route",
            "does not connect",
        ),
        (
            {"flows": [unchecked(FlowSpec, "f", route=["west_in", "east_out"], rate=100, vehicle_type="tank")]},
            "traffic.flows[0].vehicle_type",
            "unknown vehicle type 'tank'",
        ),
        (
            {"flows": [unchecked(FlowSpec, "f", route=["west_in"], rate=100, probability=0.1)]},
            "traffic.flows[0]",
            "exactly one of rate",
        ),
        ({"flows": [unchecked(FlowSpec, "f", route=["west_in"], rate=-5)]}, "traffic.flows[0].rate", "> 0"),
        (
            {"flows": [unchecked(FlowSpec, "f", route=["west_in"], rate=100, depart_lane=3)]},
            "traffic.flows[0].depart_lane",
            "1 lane",
        ),
        (
            {"flows": [unchecked(FlowSpec, "f", route=["west_in"], rate=100, depart_pos=500.0)]},
            "traffic.flows[0].depart_pos",
            "long",
        ),
        (
            {"flows": [unchecked(FlowSpec, "f", route=["west_in"], rate=100, depart_speed="fast")]},
            "traffic.flows[0].depart_speed",
            "'fast'",
        ),
        (
            {"trips": [unchecked(TripSpec, "t", origin="south_in", destination="atlantis")]},
            "traffic.trips[0].destination",
            "unknown road 'atlantis'",
        ),
        (
            {"trips": [unchecked(TripSpec, "t", origin=":center_0", destination="west_out")]},
            "traffic.trips[0].origin",
            "inside a junction",
        ),
        (
            {
                "vehicle_types": {"odd": unchecked(VehicleTypeSpec, "odd", base="tractor")},
                "trips": [unchecked(TripSpec, "t", route=["west_in"], vehicle_type="odd")],
            },
            "traffic.vehicle_types.odd.base",
            "'tractor'",
        ),
        ({"density": "rush"}, "traffic.density", "'rush'"),
        (
            {"pedestrians": [unchecked(PedestrianFlowSpec, "p", "west_in", "east_out", rate=60)]},
            "traffic.pedestrians",
            "sumo",
        ),
    ],
)
def test_bad_traffic_names_the_field(t_junction, traffic, field, words):
    with pytest.raises(ScenarioError) as err:
        _build(t_junction, **traffic)
    assert field in str(err.value) and words in str(err.value)


def test_a_route_of_passing_points_is_completed(t_junction):
    provider = _build(t_junction, flows=[FlowSpec("f", route=["west_in", "east_out"], rate=60)])
    roads = [t_junction.road_ids[r] for r in provider.routes.routes[provider.sources[0].route]]
    assert roads == ["west_in", "east_out"]
