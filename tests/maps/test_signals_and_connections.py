import numpy as np

from smarts.maps import load_map
from smarts.scenario import builtin_map_path


def test_signal_programs_and_controlled_connections_are_compiled():
    m = load_map(builtin_map_path("intersection_4way_1lane_signal"))
    assert m.tls_ids == ["center"]
    phases = slice(m.tls_phase_offsets[0], m.tls_phase_offsets[1])
    assert m.tls_phase_duration[phases].sum() > 0
    states = m.tls_phase_state[phases]
    assert {len(s) for s in states} == {16}  # one char per link of the 4 x 4 movements
    # Every movement from an approach lane is controlled by the signal with its own link index.
    assert (m.conn_tls == 0).all()
    assert sorted(m.conn_link.tolist()) == list(range(16))
    west_to_north = [
        k
        for k in range(len(m.conn_from))
        if m.lane_ids[m.conn_from[k]] == "west_in_0" and m.lane_ids[m.conn_to[k]] == "north_out_0"
    ]
    (k,) = west_to_north
    assert m.conn_dir[k] == "l" and m.lane_internal[m.conn_via[k]]


def test_priority_junction_marks_the_main_road_major():
    m = load_map(builtin_map_path("t_junction"))
    assert m.tls_ids == []
    from_road = np.array([m.road_ids[m.lane_road[lane]] for lane in m.conn_from])
    straight_on_main = (from_road == "west_in") & (m.conn_dir == "s")
    assert m.conn_major[straight_on_main].all()
    assert not m.conn_major[from_road == "south_in"].any()  # the side road yields
