import numpy as np

from smarts.core.events import NotMovingTracker, box_collisions
from smarts.core.vehicle_table import Role, VehicleTable


def _boxes(poses, length=4.0, width=2.0):
    table = VehicleTable(capacity=len(poses))
    for i, (x, y, h) in enumerate(poses):
        table.add(str(i), owner=0, role=Role.TRAFFIC, x=x, y=y, heading=h, length=length, width=width)
    rows = table.alive_rows
    radius = 0.5 * np.hypot(table.length[rows], table.width[rows])
    return box_collisions(table.corners(rows), table.x[rows], table.y[rows], radius)


def test_overlapping_boxes_collide_and_separated_do_not():
    assert _boxes([(0, 0, 0), (3.9, 0, 0)]).tolist() == [True, True]
    assert _boxes([(0, 0, 0), (4.1, 0, 0)]).tolist() == [False, False]


def test_separating_axis_of_a_rotated_box():
    # Circles overlap (centres 3.2 m apart, radii 2.24 m) but the boxes do not: the second box is
    # rotated 90 degrees and sits beyond the first one's front edge (front at x=2, its edge at x=2.2).
    assert _boxes([(0, 0, 0), (3.2, 0, np.pi / 2)]).tolist() == [False, False]
    # Rotated 45 degrees, its corner reaches into the first box.
    assert _boxes([(0, 0, 0), (3.5, 0, np.pi / 4)]).tolist() == [True, True]


def test_only_the_colliding_pair_is_flagged():
    hits = _boxes([(0, 0, 0), (3, 0.5, 0.2), (50, 0, 0)])
    assert hits.tolist() == [True, True, False]


def test_not_moving_after_window_and_reset_by_motion():
    tracker = NotMovingTracker(capacity=2, seconds=2.0, distance=1.0)
    rows = np.array([0, 1])
    tracker.reset_rows(rows, np.zeros(2), np.zeros(2), 0.0)
    flags = []
    for k in range(1, 31):
        t = 0.1 * k
        x = np.array([0.0, 0.6 * t])  # row 1 moves 0.6 m/s
        flags.append(tracker.update(rows, x, np.zeros(2), t))
    flags = np.array(flags)
    assert not flags[:19, 0].any() and flags[19:, 0].all()  # stuck from t = 2.0 s
    assert not flags[:, 1].any()  # moves 1 m every 1.7 s
