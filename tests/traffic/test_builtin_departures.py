"""Built-in traffic: departures from flows, trips and density levels."""

import numpy as np
import pytest

from smarts.core.spec.traffic import DENSITY_RATES, FlowSpec, TrafficSpec, TripSpec
from smarts.maps import load_map
from smarts.scenario import builtin_map_path
from smarts.traffic.density import density_flows
from tests.traffic.builtin_support import step, traffic_rows, traffic_sim


def _departure_times(sim, provider, steps):
    """First time each traffic vehicle id is seen."""
    seen = {}
    for k in range(steps + 1):
        if k:
            step(sim)
        for row in traffic_rows(provider):
            seen.setdefault(sim.table.ids[row], sim.time)
    return seen


def test_rate_flow_departs_evenly_spaced_from_its_begin():
    traffic = TrafficSpec(flows=[FlowSpec("f", route=["main"], rate=720, begin=2.0, depart_lane=0)])
    sim, provider = traffic_sim("straight_3lane", traffic, "main")
    seen = _departure_times(sim, provider, 595)  # up to t = 59.5 s
    assert sorted(seen) == sorted(f"f.{n}" for n in range(12))  # t = 2, 7, ..., 57
    times = np.array([seen[f"f.{n}"] for n in range(12)])
    assert times[0] == pytest.approx(2.0)
    assert np.allclose(np.diff(times), 5.0)


def test_probability_flow_departs_at_random_but_at_its_mean_rate():
    traffic = TrafficSpec(flows=[FlowSpec("p", route=["main"], probability=0.5, depart_lane="free")])
    counts, first_times = [], []
    for seed in (1, 2):
        sim, provider = traffic_sim("straight_3lane", traffic, "main", seed=seed)
        seen = _departure_times(sim, provider, 2000)  # 200 s: 100 expected
        counts.append(len(seen))
        first_times.append(sorted(seen.values())[:5])
    assert all(60 < c < 140 for c in counts)
    assert first_times[0] != first_times[1]  # the seed changes the stream


def test_trip_departs_at_its_time_lane_position_and_speed():
    trip = TripSpec("lead", route=["main"], depart=2.0, depart_lane=1, depart_pos=40.0, depart_speed=12.0)
    sim, provider = traffic_sim("straight_3lane", TrafficSpec(trips=[trip]), "main")
    step(sim, 19)
    assert "lead" not in sim.table.row_of
    step(sim)  # t = 2.0
    row = sim.table.row_of["lead"]
    assert sim.road_map.lane_ids[sim.table.lane[row]] == "main_1"
    assert sim.table.s[row] == pytest.approx(40.0, abs=1e-6)
    assert sim.table.speed[row] == pytest.approx(12.0)
    assert sim.table.owner[row] == provider.provider_id


def test_a_trip_at_time_zero_exists_right_after_reset():
    trip = TripSpec("first", route=["main"], depart_pos=20.0, depart_lane="first")
    sim, _ = traffic_sim("straight_3lane", TrafficSpec(trips=[trip]), "main", lane=2)
    row = sim.table.row_of["first"]
    assert sim.road_map.lane_ids[sim.table.lane[row]] == "main_0"


def test_departure_waits_until_its_spot_is_clear():
    # A stopped agent stands on the spot: the trip cannot enter until it is gone.
    trip = TripSpec("blocked", route=["eastbound"], depart_pos=10.0)
    sim, provider = traffic_sim(
        "straight_2lane_twoway", TrafficSpec(trips=[trip]), "eastbound", keep_agent=True, offset=12.0, speed=0.0
    )
    step(sim, 10)
    assert "blocked" not in sim.table.row_of and provider.pending.sum() == 1
    sim.agent_done[:] = True
    sim.remove_done_agents()
    step(sim)
    assert "blocked" in sim.table.row_of


def test_density_flows_share_the_entry_rate_among_reachable_exits():
    m = load_map(builtin_map_path("t_junction"))
    flows = density_flows(TrafficSpec(density="medium"), m)
    by_entry = {}
    for f in flows:
        by_entry.setdefault(f.route[0], []).append(f)
    assert set(by_entry) == {"west_in", "east_in", "south_in"}
    for entry, items in by_entry.items():
        assert sum(f.probability for f in items) * 3600 == pytest.approx(DENSITY_RATES["medium"])
        exits = {f.route[-1] for f in items}
        assert len(exits) == 2 and entry.replace("_in", "_out") not in exits  # no U-turns
    assert density_flows(TrafficSpec(density="none"), m) == []


def test_density_traffic_enters_from_every_entry_road():
    sim, provider = traffic_sim("intersection_4way_1lane", TrafficSpec(density="high"), "west_in")
    seen = _departure_times(sim, provider, 600)
    entries = {vid.split(".")[1] for vid in seen}
    assert entries == {"west_in", "east_in", "north_in", "south_in"}
