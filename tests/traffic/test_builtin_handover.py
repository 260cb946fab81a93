"""Built-in traffic: taking over vehicles from other providers and letting them go."""

import numpy as np
import pytest

from smarts.core.spec.traffic import TrafficSpec, TripSpec
from smarts.core.vehicle_table import Role
from smarts.env.assembly import build_simulation
from smarts.traffic.builtin import BuiltinTrafficProvider
from tests.builders import agent, make_spec
from tests.traffic.builtin_support import step, traffic_sim


def test_a_finished_agent_vehicle_is_driven_on_by_traffic():
    spec_agent = agent("main", lane=1, offset=50.0, speed=10.0)
    spec_agent["mission"]["on_end"] = "traffic"
    spec = make_spec([spec_agent], map_name="straight_2lane", traffic={"engine": "builtin"})
    sim = build_simulation(spec)
    found = [p for p in sim.providers if isinstance(p, BuiltinTrafficProvider)]
    provider = found[0] if found else BuiltinTrafficProvider(TrafficSpec(), sim.road_map, sim.dt)
    if not found:
        sim.add_provider(provider)
    sim.reset()
    row = int(sim.agent_row[0])
    x0, y0, v0 = sim.table.x[row], sim.table.y[row], sim.table.speed[row]
    assert provider.can_accept(sim, np.array([row])).all()
    sim.agent_done[0] = True
    sim.remove_done_agents()  # hands the vehicle back to traffic
    assert sim.table.owner[row] == provider.provider_id and sim.table.role[row] == Role.TRAFFIC
    assert (sim.table.x[row], sim.table.y[row], sim.table.speed[row]) == (x0, y0, v0)
    xs = []
    for _ in range(100):
        step(sim)
        if not sim.table.alive[row]:
            break
        xs.append(sim.table.x[row])
        assert sim.road_map.lane_ids[sim.table.lane[row]] in ("main_0", "main_1")
    assert np.all(np.diff(xs) > 0) and xs[-1] > x0 + 50.0
    # It drives on to the end of the road and leaves there.
    step(sim, 250)
    assert not sim.table.alive[row]


def test_an_off_lane_vehicle_cannot_be_taken_over():
    sim, provider = traffic_sim("straight_2lane", TrafficSpec(), "main", keep_agent=True)
    row = int(sim.agent_row[0])
    sim.table.x[row], sim.table.y[row] = 150.0, 40.0  # far beside the road
    assert not provider.can_accept(sim, np.array([row]))[0]
    with pytest.raises(ValueError, match="not on a lane"):
        provider.accept(sim, np.array([row]))


def test_released_vehicles_are_no_longer_driven():
    trip = TripSpec("car", route=["main"], depart_pos=20.0)
    sim, provider = traffic_sim("straight_2lane", TrafficSpec(trips=[trip]), "main", lane=1, offset=290.0)
    row = sim.table.row_of["car"]
    step(sim, 5)
    provider.release(sim, np.array([row]))
    x = sim.table.x[row]
    step(sim, 5)
    assert sim.table.x[row] == x and sim.table.alive[row]
