import math

import numpy as np
import pytest

from smarts.comms import TRAFFIC_PAYLOAD_FIELDS, CommsConfig, SenderKind, V2VNetwork
from smarts.core.vehicle_table import Role, VehicleTable
from tests.comms.support import delivered_from, rows_of, table_with


def one_step(net, table, senders, receivers, step=0, channels=0, receiver_channels=0):
    payloads = np.zeros((len(senders), net.config.message_size), dtype=np.float32)
    net.send(step, table, senders, channels, payloads)
    net.broadcast_traffic(step, table)
    return net.deliver(step, table, receivers, receiver_channels)


def test_range_is_measured_from_where_the_sender_was():
    poses = {"s": (0.0, 0.0, 0.0), "near": (99.0, 0.0, 0.0), "far": (0.0, 101.0, 0.0)}
    table, rows = table_with(poses)
    net = V2VNetwork(CommsConfig(range=100.0), table.capacity, seed=1)
    got = one_step(net, table, rows_of(rows, "s"), rows_of(rows, "near", "far"))
    assert delivered_from(got, 0) == [rows["s"]]
    assert delivered_from(got, 1) == []

    # With latency the sender's position at send time counts, not where it is at delivery.
    net = V2VNetwork(CommsConfig(range=100.0, latency=1), table.capacity, seed=1)
    net.send(0, table, rows_of(rows, "s"), 0, np.zeros((1, 8)))
    table.x[rows["s"]] = 1000.0
    got = net.deliver(1, table, rows_of(rows, "near", "far"))
    assert delivered_from(got, 0) == [rows["s"]]
    assert got.pose[0, 0, 0] == pytest.approx(-99.0)


def test_latency_delivers_exactly_once_after_that_many_steps():
    table, rows = table_with({"s": (0.0, 0.0, 0.0), "r": (10.0, 0.0, 0.0)})
    net = V2VNetwork(CommsConfig(latency=3, message_size=2), table.capacity, seed=1)
    receivers = rows_of(rows, "r")
    delivered = {}
    for step in range(10):
        if step == 5:
            net.send(step, table, rows_of(rows, "s"), 0, np.array([[7.0, -0.5]]))
        got = net.deliver(step, table, receivers)
        delivered[step] = (got.count[0], got.age[0, 0], got.payload[0, 0].tolist())
    assert [s for s, d in delivered.items() if d[0]] == [8]
    assert delivered[8] == (1, 3, [1.0, -0.5])  # age 3; the payload clipped to payload_bound 1


def test_loss_rate_matches_probability_and_is_reproducible():
    n_receivers, steps, p = 100, 100, 0.3
    poses = {"s": (0.0, 0.0, 0.0)} | {f"r{i}": (float(i % 10), float(i // 10), 0.0) for i in range(n_receivers)}
    table, rows = table_with(poses, capacity=128)
    receivers = rows_of(rows, *[f"r{i}" for i in range(n_receivers)])

    def run(seed):
        net = V2VNetwork(CommsConfig(loss=p), table.capacity, seed=seed)
        return np.stack([one_step(net, table, rows_of(rows, "s"), receivers, step=k).mask[:, 0] for k in range(steps)])

    first = run(7)
    lost = 1.0 - first.mean()
    assert abs(lost - p) < 0.02  # 10,000 draws: 4.4 standard deviations
    assert np.array_equal(first, run(7))
    assert not np.array_equal(first, run(8))
    # Losses are independent per receiver: no step loses the message for everyone.
    assert first.any(axis=1).all()


def test_bandwidth_keeps_the_nearest_senders_in_distance_order():
    poses = {"r": (0.0, 0.0, 0.0)} | {f"s{i}": (float(10 * (10 - i)), 0.0, 0.0) for i in range(10)}
    table, rows = table_with(poses)
    senders = rows_of(rows, *[f"s{i}" for i in range(10)])
    net = V2VNetwork(CommsConfig(bandwidth=3, max_messages=8), table.capacity, seed=1)
    got = one_step(net, table, senders, rows_of(rows, "r"))
    assert got.count[0] == 3 and got.mask[0].sum() == 3
    assert delivered_from(got, 0) == [rows["s9"], rows["s8"], rows["s7"]]
    assert got.pose[0, :3, 0].tolist() == [10.0, 20.0, 30.0]
    assert (got.sender_row[0, 3:] == -1).all() and (got.sender_kind[0, 3:] == SenderKind.NONE).all()

    # A byte budget of 2.5 messages gives 2; without any limit max_messages caps the observation.
    config = CommsConfig(message_size=8, bandwidth_bytes=120)  # 48 bytes per message
    got = one_step(V2VNetwork(config, table.capacity, seed=1), table, senders, rows_of(rows, "r"))
    assert delivered_from(got, 0) == [rows["s9"], rows["s8"]]
    got = one_step(V2VNetwork(CommsConfig(max_messages=4), table.capacity, 1), table, senders, rows_of(rows, "r"))
    assert got.count[0] == 4


def test_equally_near_senders_keep_the_order_queued():
    poses = {"r": (0.0, 0.0, 0.0), "t": (0.0, 10.0, 0.0), "a": (0.0, -10.0, 0.0), "b": (10.0, 0.0, 0.0)}
    table, rows = table_with(poses, traffic=("t",))
    net = V2VNetwork(CommsConfig(penetration=1.0, bandwidth=2), table.capacity, seed=1)
    got = one_step(net, table, rows_of(rows, "b", "a"), rows_of(rows, "r"))
    assert delivered_from(got, 0) == [rows["b"], rows["a"]]  # the traffic message is dropped


def test_channels_isolate_and_traffic_on_every_channel_reaches_all():
    poses = {"a": (0.0, 0.0, 0.0), "b": (5.0, 0.0, 0.0), "c": (10.0, 0.0, 0.0), "t": (0.0, 5.0, 0.0)}
    table, rows = table_with(poses, traffic=("t",))
    config = CommsConfig(channels=2, penetration=1.0, traffic_channel=1)
    net = V2VNetwork(config, table.capacity, seed=1)
    abc = rows_of(rows, "a", "b", "c")
    got = one_step(net, table, abc, abc, channels=np.array([0, 1, 0]), receiver_channels=np.array([0, 1, 0]))
    assert delivered_from(got, 0) == [rows["c"]]  # a hears c only (b is on channel 1)
    assert delivered_from(got, 1) == [rows["t"]]  # b hears traffic on channel 1 only
    assert delivered_from(got, 2) == [rows["a"]]

    config = CommsConfig(channels=2, penetration=1.0, traffic_channel=-1)
    net = V2VNetwork(config, table.capacity, seed=1)
    got = one_step(net, table, abc, abc, channels=np.array([0, 1, 0]), receiver_channels=np.array([0, 1, 0]))
    assert all(rows["t"] in delivered_from(got, i) for i in range(3))


def test_a_sender_never_hears_itself():
    table, rows = table_with({"a": (0.0, 0.0, 0.0), "b": (1.0, 0.0, 0.0)})
    net = V2VNetwork(CommsConfig(), table.capacity, seed=1)
    got = one_step(net, table, rows_of(rows, "a", "b"), rows_of(rows, "a", "b"))
    assert delivered_from(got, 0) == [rows["b"]] and delivered_from(got, 1) == [rows["a"]]
    assert (got.sender_kind[got.mask] == SenderKind.AGENT).all()


def _traffic_table(n: int, capacity: int) -> VehicleTable:
    table = VehicleTable(capacity)
    for i in range(n):
        table.add(f"flow.{i}", owner=1, role=Role.TRAFFIC, x=float(i), y=0.0, heading=0.0)
    return table


def test_penetration_picks_that_fraction_stably_per_vehicle_id():
    n, p = 2000, 0.3
    table = _traffic_table(n, capacity=2048)
    net = V2VNetwork(CommsConfig(penetration=p), table.capacity, seed=11)
    connected = net.is_connected(table)
    assert abs(connected.sum() / n - p) < 0.03  # 3 standard deviations
    assert net.broadcast_traffic(0, table) == connected.sum()
    assert np.array_equal(net.is_connected(table), connected)  # stable across steps

    # The pick follows the vehicle id, not the row: re-added elsewhere, a vehicle keeps it.
    picked = int(np.flatnonzero(connected)[0])
    vid = table.ids[picked]
    table.remove([0, picked])
    new_row = table.add(vid, owner=1, role=Role.TRAFFIC, x=0.0, y=0.0, heading=0.0)
    assert new_row == 0 and net.is_connected(table)[0]
    # Agents never broadcast, even when their id would be picked.
    table.transfer([0], owner=0, role=Role.AGENT)
    assert not net.is_connected(table)[0]

    net.reset(seed=12)
    assert not np.array_equal(net.is_connected(table), connected)
    assert V2VNetwork(CommsConfig(penetration=0.0), table.capacity, 1).is_connected(table).sum() == 0


def test_traffic_messages_carry_the_standard_state_payload():
    table, rows = table_with({"r": (0.0, 0.0, 0.0), "t": (3.0, 4.0, 0.5)}, traffic=("t",))
    table.accel[rows["t"]], table.yaw_rate[rows["t"]] = 1.5, 0.1
    for size in (10, 3):
        net = V2VNetwork(CommsConfig(penetration=1.0, message_size=size), table.capacity, seed=1)
        got = one_step(net, table, rows_of(rows, "r"), rows_of(rows, "r"))
        assert got.sender_kind[0, 0] == SenderKind.TRAFFIC
        expected = [getattr(table, f)[rows["t"]] for f in TRAFFIC_PAYLOAD_FIELDS][:size]
        np.testing.assert_allclose(got.payload[0, 0, : len(expected)], expected, rtol=1e-6)
        assert (got.payload[0, 0, len(expected) :] == 0).all()


def test_relative_pose_is_in_the_receiver_frame():
    # Receiver faces north at (3, 4); a sender 10 m north of it facing west is 10 m ahead, turned +90deg.
    table, rows = table_with({"r": (3.0, 4.0, math.pi / 2), "s": (3.0, 14.0, math.pi)})
    net = V2VNetwork(CommsConfig(), table.capacity, seed=1)
    got = one_step(net, table, rows_of(rows, "s"), rows_of(rows, "r"))
    np.testing.assert_allclose(got.pose[0, 0], [10.0, 0.0, math.pi / 2], atol=1e-12)

    rng = np.random.default_rng(0)
    poses = {f"v{i}": (*rng.uniform(-30, 30, 2), rng.uniform(-math.pi, math.pi)) for i in range(6)}
    table, rows = table_with(poses)
    all_rows = rows_of(rows, *poses)
    got = one_step(V2VNetwork(CommsConfig(), table.capacity, 1), table, all_rows, all_rows)
    for i, r in enumerate(all_rows):
        for j in range(got.count[i]):
            s = got.sender_row[i, j]
            dx, dy = table.x[s] - table.x[r], table.y[s] - table.y[r]
            c, sn = math.cos(table.heading[r]), math.sin(table.heading[r])
            dh = (table.heading[s] - table.heading[r] + math.pi) % (2 * math.pi) - math.pi
            np.testing.assert_allclose(got.pose[i, j, :2], [c * dx + sn * dy, -sn * dx + c * dy], atol=1e-9)
            assert math.isclose(math.cos(got.pose[i, j, 2] - dh), 1.0, abs_tol=1e-12)


def _scripted_run(seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(0)  # the same motion every run; only the network seed varies
    n_agents, n_traffic = 6, 30
    table = VehicleTable(64)
    for i in range(n_agents):
        table.add(f"agent_{i}", owner=0, role=Role.AGENT, x=10.0 * i, y=0.0, heading=0.0)
    for i in range(n_traffic):
        table.add(f"car.{i}", owner=1, role=Role.TRAFFIC, x=4.0 * i, y=3.0, heading=0.1)
    config = CommsConfig(
        channels=2, latency=2, loss=0.2, penetration=0.5, bandwidth=5, message_size=4, range=60.0, traffic_channel=-1
    )
    net = V2VNetwork(config, table.capacity, seed=seed)
    agents = np.arange(n_agents)
    out = []
    for step in range(20):
        alive = table.alive_rows
        table.x[alive] += rng.uniform(0, 2, alive.size)
        channels = rng.integers(0, 2, n_agents)
        net.send(step, table, agents, channels, rng.uniform(-1, 1, (n_agents, 4)))
        net.broadcast_traffic(step, table)
        got = net.deliver(step, table, agents, channels)
        out += [got.sender_row, got.pose, got.payload]
    return out


def test_same_seed_same_deliveries():
    first, again, other = _scripted_run(3), _scripted_run(3), _scripted_run(4)
    assert all(np.array_equal(a, b) for a, b in zip(first, again))
    assert not all(np.array_equal(a, b) for a, b in zip(first, other))


def test_reset_drops_queued_messages():
    table, rows = table_with({"s": (0.0, 0.0, 0.0), "r": (1.0, 0.0, 0.0)})
    net = V2VNetwork(CommsConfig(latency=1), table.capacity, seed=1)
    net.send(0, table, rows_of(rows, "s"), 0, np.zeros((1, 8)))
    net.reset()
    assert net.deliver(1, table, rows_of(rows, "r")).count[0] == 0


def test_bad_sends_are_clear_errors():
    table, rows = table_with({"s": (0.0, 0.0, 0.0)})
    net = V2VNetwork(CommsConfig(channels=2, message_size=2), table.capacity, seed=1)
    s = rows_of(rows, "s")
    with pytest.raises(ValueError, match=r"shape \(1, 3\); expected \(1, 2\)"):
        net.send(0, table, s, 0, np.zeros((1, 3)))
    with pytest.raises(ValueError, match=r"from 's' has payload \[0.0, nan\]; expected finite"):
        net.send(0, table, s, 0, np.array([[0.0, np.nan]]))
    with pytest.raises(ValueError, match=r"from 's' is on channel 2; expected a channel in \[0, 1\]"):
        net.send(0, table, s, np.array([2]), np.zeros((1, 2)))
    with pytest.raises(ValueError, match=r"sender row 99 is not a row"):
        net.send(0, table, np.array([99]), 0, np.zeros((1, 2)))
    with pytest.raises(ValueError, match=r"receiver row -1 is not a row"):
        net.deliver(0, table, np.array([-1]))
    # A rejected send queues nothing: the sender's good message later is the only one.
    table.add("r", owner=0, role=Role.AGENT, x=1.0, y=0.0, heading=0.0)
    net.send(0, table, s, 0, np.ones((1, 2)))
    assert net.deliver(0, table, np.array([table.row_of["r"]])).count.tolist() == [1]
    with pytest.raises(TypeError, match="CommsConfig"):
        V2VNetwork({"range": 5}, 4)
