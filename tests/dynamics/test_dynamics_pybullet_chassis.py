import math

import numpy as np
import pytest

from smarts.core.vehicle_table import Role, VehicleTable
from smarts.dynamics import ActionError
from smarts.dynamics.pybullet_chassis import (
    CENTRE_OF_MASS_ABOVE_AXLE,
    WHEEL_RADIUS,
    PhysicsWorld,
    apply_continuous,
)

DT = 0.1


@pytest.fixture
def world():
    w = PhysicsWorld(dt=DT)
    yield w
    w.close()


def drive(world, handles, throttle, brake, steering, seconds):
    n = len(handles)
    for _ in range(int(round(seconds / DT))):
        world.apply_controls(handles, np.full(n, throttle), np.full(n, brake), np.broadcast_to(steering, (n,)))
        world.step()
    return world.read_state(handles)


def test_car_at_rest_settles_and_stays_put(world):
    h = world.add_vehicle(3.0, -2.0, 0.4)
    state = drive(world, [h], 0.0, 0.0, 0.0, 5.0)
    assert world.base_height(h) == pytest.approx(WHEEL_RADIUS + CENTRE_OF_MASS_ABOVE_AXLE, abs=0.01)
    assert math.hypot(state.x[0] - 3.0, state.y[0] + 2.0) < 0.03
    assert state.heading[0] == pytest.approx(0.4, abs=1e-3)
    assert abs(state.speed[0]) < 0.01


def test_full_throttle_accelerates_forward_along_heading(world):
    heading = 0.7
    h = world.add_vehicle(0.0, 0.0, heading)
    state = drive(world, [h], 1.0, 0.0, 0.0, 3.0)
    assert state.speed[0] > 3.0
    assert math.atan2(state.y[0], state.x[0]) == pytest.approx(heading, abs=0.02)
    assert state.heading[0] == pytest.approx(heading, abs=0.02)
    # About max_drive_torque / (radius * mass) = 4 m/s^2, not more.
    assert state.speed[0] < 3.0 * 4.5


def test_initial_speed_and_brake_stop_within_plausible_distance(world):
    h = world.add_vehicle(0.0, 0.0, -1.0, speed=10.0)
    state = world.read_state([h])
    assert state.speed[0] == pytest.approx(10.0)
    state = drive(world, [h], 0.0, 1.0, 0.0, 3.0)
    assert abs(state.speed[0]) < 0.05
    distance = math.hypot(state.x[0], state.y[0])
    # v^2 / (2 mu g) = 5.1 m is the friction limit; a plausible brake stops within 4..15 m.
    assert 4.0 < distance < 15.0
    assert state.heading[0] == pytest.approx(-1.0, abs=0.1)  # no spin-out


def test_steering_left_turns_left_and_right_turns_right(world):
    handles = [
        world.add_vehicle(0.0, 0.0, 0.0, speed=8.0),
        world.add_vehicle(0.0, 30.0, 0.0, speed=8.0),
    ]
    state = drive(world, handles, 0.2, 0.0, np.array([0.5, -0.5]), 1.0)
    assert state.yaw_rate[0] > 0.3 and state.heading[0] > 0.3
    assert state.yaw_rate[1] < -0.3 and state.heading[1] < -0.3
    assert state.steering[0] > 0.2 and state.steering[1] < -0.2
    assert state.y[0] > 0.5 and state.y[1] < 29.5


def test_two_fresh_worlds_are_deterministic():
    results = []
    for _ in range(2):
        with PhysicsWorld(dt=DT) as w:
            handles = [w.add_vehicle(0.0, 0.0, 0.1, speed=5.0), w.add_vehicle(20.0, 4.0, 3.0)]
            for k in range(40):
                w.apply_controls(handles, [0.6, 1.0], [0.0, 0.1 * (k % 3)], [math.sin(0.2 * k), -0.3])
                w.step()
            results.append(np.array(w.read_state(handles)))
    np.testing.assert_array_equal(results[0], results[1])


def test_remove_vehicle_and_reset(world):
    a = world.add_vehicle(0.0, 0.0, 0.0, speed=5.0)
    b = world.add_vehicle(0.0, 10.0, 0.0, speed=5.0)
    assert world.vehicle_count == 2
    world.remove_vehicle(a)
    assert world.vehicle_count == 1
    state = drive(world, [b], 0.0, 0.0, 0.0, 0.5)
    assert state.x[0] == pytest.approx(2.5, abs=0.1)
    with pytest.raises(KeyError, match=f"no vehicle with handle {a}"):
        world.remove_vehicle(a)
    c = world.add_vehicle(5.0, 5.0, 1.0)
    assert world.read_state([c]).x[0] == pytest.approx(5.0)
    world.reset()
    assert world.vehicle_count == 0
    d = world.add_vehicle(1.0, 2.0, 0.0)
    assert world.read_state([d]).y[0] == pytest.approx(2.0)


def test_apply_continuous_writes_table_columns(world):
    table = VehicleTable(8)
    rows = np.array(
        [
            table.add("ego", owner=0, role=Role.AGENT, x=0.0, y=0.0, heading=0.0),
            table.add("other", owner=0, role=Role.AGENT, x=0.0, y=20.0, heading=0.0, speed=6.0),
        ]
    )
    handles = [world.add_vehicle(table.x[r], table.y[r], table.heading[r], table.speed[r]) for r in rows]
    actions = np.array([[1.0, 0.0, 0.0], [0.3, 0.0, 1.0]])
    for _ in range(10):
        apply_continuous(world, table, rows, handles, actions, DT)
    state = world.read_state(handles)
    np.testing.assert_array_equal(table.x[rows], state.x)
    np.testing.assert_array_equal(table.speed[rows], state.speed)
    assert table.accel[rows[0]] == pytest.approx(4.0, abs=0.5)
    assert abs(table.jerk[rows[0]]) < 5.0
    assert table.yaw_rate[rows[1]] > 0.5 and table.steering[rows[1]] > 0.4
    assert table.lat_accel[rows[1]] == pytest.approx(table.speed[rows[1]] * table.yaw_rate[rows[1]])

    before = table.x.copy()
    with pytest.raises(ActionError, match="other: continuous action component steering is nan"):
        apply_continuous(world, table, rows, handles, np.array([[1, 0, 0], [0, 0, np.nan]]), DT)
    np.testing.assert_array_equal(table.x, before)
    with pytest.raises(ValueError, match="differs from the physics world's dt"):
        apply_continuous(world, table, rows, handles, actions, 0.05)


def test_controls_are_clipped_to_their_ranges(world):
    a = world.add_vehicle(0.0, 0.0, 0.0, speed=8.0)
    b = world.add_vehicle(0.0, 30.0, 0.0, speed=8.0)
    world.apply_controls([a, b], [5.0, 1.0], [-3.0, 0.0], [9.0, 1.0])
    for _ in range(5):
        world.step()
    state = world.read_state([a, b])
    # Out-of-range controls act exactly like full throttle, no brake and full left lock.
    assert state.speed[0] == pytest.approx(state.speed[1], abs=1e-6)
    assert state.heading[0] == pytest.approx(state.heading[1], abs=1e-6)
    assert state.heading[0] > 0.1


def test_invalid_vehicle_and_world_parameters():
    with pytest.raises(ValueError, match="physics_hz"):
        PhysicsWorld(dt=DT, physics_hz=0)
    with PhysicsWorld(dt=DT) as w:
        with pytest.raises(ValueError, match="length"):
            w.add_vehicle(0.0, 0.0, 0.0, length=-1.0)
        with pytest.raises(ValueError, match="mass"):
            w.add_vehicle(0.0, 0.0, 0.0, mass=50.0)
