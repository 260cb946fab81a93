"""Built-in traffic: the same seed gives the same traffic; another seed another."""

import numpy as np

from smarts.core.spec.traffic import FlowSpec, TrafficSpec
from tests.traffic.builtin_support import step, traffic_rows, traffic_sim

TRAFFIC = TrafficSpec(
    density="high",
    flows=[
        FlowSpec("extra", route=["west_in", "north_out"], probability=0.2, depart_lane="random", depart_speed="random")
    ],
)


def _trajectories(seed: int, steps: int = 400) -> dict[str, list]:
    sim, provider = traffic_sim("intersection_4way_2lane_signal", TRAFFIC, "west_out", signals=True, seed=seed)
    out: dict[str, list] = {}
    for _ in range(steps):
        step(sim)
        t = sim.table
        for row in traffic_rows(provider):
            out.setdefault(t.ids[row], []).append((sim.step_count, t.x[row], t.y[row], t.heading[row], t.speed[row]))
    return out


def test_same_seed_gives_identical_traffic():
    a, b = _trajectories(7), _trajectories(7)
    assert a.keys() == b.keys() and len(a) > 20
    for vid in a:
        assert np.array_equal(np.array(a[vid]), np.array(b[vid])), vid


def test_another_seed_gives_other_traffic():
    a, b = _trajectories(7), _trajectories(8)
    assert a.keys() != b.keys() or any(not np.array_equal(np.array(a[v]), np.array(b[v])) for v in a)


def test_reset_replays_the_episode():
    sim, provider = traffic_sim("t_junction", TrafficSpec(density="high"), "west_out", seed=3)
    step(sim, 200)
    first = {sim.table.ids[r]: sim.table.x[r] for r in traffic_rows(provider)}
    sim.reset()
    sim.agent_done[:] = True
    sim.remove_done_agents()
    step(sim, 200)
    again = {sim.table.ids[r]: sim.table.x[r] for r in traffic_rows(provider)}
    assert first == again and len(first) > 5
