import numpy as np
import pytest

from smarts.core.vehicle_table import Role, VehicleTable, VehicleType


def test_rows_are_stable_and_reused_after_removal():
    table = VehicleTable(capacity=4)
    rows = [table.add(f"v{i}", owner=0, role=Role.TRAFFIC, x=i, y=0, heading=0) for i in range(3)]
    assert rows == [0, 1, 2]
    table.remove(1)
    assert table.row_of == {"v0": 0, "v2": 2}
    assert table.add("v3", owner=0, role=Role.TRAFFIC, x=9, y=0, heading=0) == 1
    assert table.row_of["v2"] == 2 and table.x[2] == 2


def test_full_table_and_duplicate_ids_are_clear_errors():
    table = VehicleTable(capacity=1)
    table.add("a", owner=0, role=Role.AGENT, x=0, y=0, heading=0)
    with pytest.raises(ValueError, match="'a' is already"):
        table.add("a", owner=0, role=Role.AGENT, x=0, y=0, heading=0)
    with pytest.raises(RuntimeError, match="capacity 1"):
        table.add("b", owner=0, role=Role.AGENT, x=0, y=0, heading=0)


def test_transfer_changes_owner_without_touching_state():
    table = VehicleTable(capacity=2)
    row = table.add("a", owner=0, role=Role.TRAFFIC, x=3, y=4, heading=1, speed=5)
    table.transfer([row], owner=1, role=Role.AGENT)
    assert table.owner[row] == 1 and table.role[row] == Role.AGENT
    assert (table.x[row], table.y[row], table.speed[row]) == (3, 4, 5)
    assert list(table.rows_owned_by(1)) == [row]
    with pytest.raises(ValueError, match="hold no vehicle"):
        table.transfer([1], owner=0)


def test_corners_of_a_rotated_box():
    table = VehicleTable(capacity=1)
    row = table.add("a", owner=0, role=Role.AGENT, x=1, y=2, heading=np.pi / 2, length=4, width=2)
    corners = table.corners(np.array([row]))[0]
    # Heading north: front is +y, left is -x.
    np.testing.assert_allclose(corners, [[0, 4], [2, 4], [2, 0], [0, 0]], atol=1e-12)


def test_type_defaults_apply_when_dimensions_are_not_given():
    table = VehicleTable(capacity=1)
    row = table.add("bus", owner=0, role=Role.TRAFFIC, x=0, y=0, heading=0, vtype=VehicleType.BUS)
    assert table.length[row] > 10 and table.width[row] > 2.4
