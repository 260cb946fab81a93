"""The diagnostic's scenarios: agents (and, for the sensor case, built-in traffic) cruising on the
six-lane highway so that every one stays live for the measured steps."""

from __future__ import annotations

from smarts.scenario import ScenarioSpec, read_scenario

PERF_MAP = "builtin:highway_6lane_ramp"
PERF_ROAD = "main_0"
LANES = 6
SPACING = 12.0  # metres between agents in the same lane
CRUISE_SPEED = 8.0
ROAD_LENGTH = 455.0
END_MARGIN = 15.0  # metres kept clear of the road's end


SENSOR_INTERFACE = {
    "neighbours": {"extended": True},
    "occlusion": {"enabled": True, "mode": "hide"},
    "rasters": {
        "size": 64,
        "resolution": 0.5,
        "layers": ["drivable", "lanes", "route", "occupancy", "occlusion"],
        "rgb": True,
    },
    "lidar": {"rays": 64, "range": 30.0},
}
SENSOR_COMMS = {
    "range": 100.0,
    "latency": 1,
    "loss": 0.05,
    "message_size": 8,
    "max_messages": 8,
    "penetration": 0.5,
    "traffic_channel": -1,
}
TRAFFIC_SPACING = 14.0  # metres between traffic rows: room for every trip to depart at once


def sensor_scenario(n_agents: int, n_vehicles: int, steps: int, interface: dict | None = SENSOR_INTERFACE,
                    comms: dict | None = SENSOR_COMMS) -> ScenarioSpec:  # fmt: skip
    """``n_vehicles`` built-in traffic vehicles in rows of six, the agents in rows just ahead of
    them; everyone cruises at 8 m/s, so the traffic follows the agents and nobody collides. Every
    agent has ``interface`` (all sensors by default; None: the default observation) and the
    scenario ``comms`` (V2V by default; None: none)."""
    rows = -(-n_vehicles // LANES)
    first_agent = 5.0 + TRAFFIC_SPACING * rows
    agents = []
    for i in range(n_agents):
        offset = first_agent + TRAFFIC_SPACING * (i // LANES)
        start = {"road": PERF_ROAD, "lane": i % LANES, "offset": offset, "speed": CRUISE_SPEED}
        agent = {"id": f"agent_{i}", "mission": {"start": start, "goal": {"endless": True}}}
        agents.append(agent if interface is None else {**agent, "interface": interface})
    trips = [
        {
            "id": f"car_{k}",
            "origin": PERF_ROAD,
            "destination": "main_2",
            "depart": 0,
            "depart_lane": k % LANES,
            "depart_pos": 5.0 + TRAFFIC_SPACING * (k // LANES),
            "depart_speed": CRUISE_SPEED,
            "vehicle_type": "cruise",
        }  # fmt: skip
        for k in range(n_vehicles)
    ]
    cruise = {"max_speed": CRUISE_SPEED, "speed_dev": 0.0, "tau": 0.5, "min_gap": 2.0}
    return read_scenario(
        {
            "name": f"diagnostic_sensors_{n_agents}_agents_{n_vehicles}_vehicles",
            "map": PERF_MAP,
            "episode_steps": steps + 10,
            "vehicle_capacity": n_agents + n_vehicles + 16,
            "agents": agents,
            "traffic": {"engine": "builtin", "vehicle_types": {"cruise": cruise}, "trips": trips},
            **({"comms": comms} if comms is not None else {}),
            "events": {"terminate_on": ["collision", "off_road", "max_steps"]},
        },
        source="smarts.diagnostic",
    )


def perf_scenario(n_agents: int, steps: int) -> ScenarioSpec:
    """``n_agents`` endless agents, six abreast, ``SPACING`` apart, cruising at 8 m/s."""
    agents = []
    for i in range(n_agents):
        start = {"road": PERF_ROAD, "lane": i % LANES, "offset": 5.0 + SPACING * (i // LANES), "speed": CRUISE_SPEED}
        agents.append({"id": f"agent_{i}", "mission": {"start": start, "goal": {"endless": True}}})
    return read_scenario(
        {
            "name": f"diagnostic_{n_agents}_agents",
            "map": PERF_MAP,
            "episode_steps": steps + 10,
            "agents": agents,
            "events": {"terminate_on": ["collision", "off_road", "max_steps"]},
        },
        source="smarts.diagnostic",
    )
