"""Kernel records hold the simulation's own arrays: a kernel writing through one writes the
simulation, and a simulation that replaced one of its arrays would leave the record on the old one."""

import numpy as np

from smarts.core.sim_records import sim_tables, tables_of
from smarts.env.assembly import build_simulation
from tests.builders import agent, make_spec

FORWARD = np.array([1.0, 0.0, 0.0])


def _same_memory(a, b) -> bool:
    return isinstance(a, np.ndarray) and a.__array_interface__ == b.__array_interface__


def _leaves(fields, prefix=""):
    for name, value in zip(fields._fields, fields):
        if hasattr(value, "_fields"):
            yield from _leaves(value, f"{prefix}{name}.")
        else:
            yield f"{prefix}{name}", value


def test_the_records_hold_the_arrays_the_simulation_keeps_after_resets_and_steps():
    sim = build_simulation(make_spec([agent(offset=10.0), agent(lane=1, offset=30.0)]))
    sim.reset()
    sim_tables(sim)
    built = dict(_leaves(sim.__dict__["_sim_tables_fields"]))
    for _ in range(5):
        sim.step({a: FORWARD for a in sim.agent_ids})
    sim.reset(seed=3)
    sim.step({a: FORWARD for a in sim.agent_ids})
    now = dict(_leaves(tables_of(sim)))
    stale = [name for name, value in now.items()
             if isinstance(value, np.ndarray) and not _same_memory(value, built[name])]  # fmt: skip
    assert not stale, f"the simulation replaced arrays its kernel record holds: {stale}"
    assert sim_tables(sim) is sim.__dict__["_sim_tables"]


def test_events_written_through_the_record_are_the_simulations():
    sim = build_simulation(make_spec([agent(offset=10.0)]))
    sim.reset()
    for _ in range(3):
        sim.step({a: FORWARD for a in sim.agent_ids})
    assert sim.agent_prev_row[0] == sim.agent_row[0]  # written by the events kernel
    assert sim.route_progress[0] > 2.9  # written by the route-progress kernel (1 m a step)
