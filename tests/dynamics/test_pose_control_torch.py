"""The torch pose controller against the compiled one: same limits, same written columns.

Almost bit-identical (same float64 operations in the same order), not quite: torch's vectorised
sin/cos/atan2 round about one input in a thousand differently from libm's by one ulp, which shows
in about one row in 10^4 (relative difference <= 2e-14 in jerk, the most amplified column: an ulp of
speed divided by dt twice); 1e-12 (relative and absolute) holds with margin.
"""

import math

import numpy as np
import pytest
import torch

from smarts.core.vehicle_table import Role, VehicleTable
from smarts.dynamics import ActionError, ReachLimits, apply_relative_pose, apply_target_pose
from smarts.dynamics.pose_control_torch import apply_pose_torch, check_device_name, resolve_device

DT = 0.1
N = 600
WRITTEN = ("x", "y", "heading", "speed", "accel", "jerk", "yaw_rate", "lat_accel")
CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA GPU visible")


def random_state(seed: int, reverse: bool) -> tuple[VehicleTable, np.ndarray]:
    """N cars at random poses and speeds (some above max_speed, some backwards when reversing),
    a tenth of them with headings within 0.05 rad of +-pi so that turns wrap around."""
    rng = np.random.default_rng(seed)
    table = VehicleTable(N + 10)
    heading = rng.uniform(-math.pi, math.pi, N)
    heading[: N // 10] = math.pi - rng.uniform(0.0, 0.05, N // 10)
    heading[: N // 20] *= -1.0
    speed = rng.uniform(-8.0 if reverse else 0.0, 30.0, N)
    rows = np.array(
        [
            table.add(
                f"car{i}",
                owner=0,
                role=Role.AGENT,
                x=float(rng.uniform(-800, 800)),
                y=float(rng.uniform(-800, 800)),
                heading=float(heading[i]),
                speed=float(speed[i]),
            )
            for i in range(N)
        ]  # fmt: skip
    )
    table.accel[rows] = rng.normal(0.0, 3.0, N)
    order = rng.permutation(N)  # rows in any order
    return table, rows[order]


def random_requests(table: VehicleTable, rows: np.ndarray, seed: int, world_frame: bool) -> np.ndarray:
    """Requests from gentle to far beyond the limits (long, sideways, backwards, sharp turns)."""
    rng = np.random.default_rng(seed + 1)
    n = len(rows)
    scale = rng.choice([0.05, 1.0, 5.0], n)[:, None]
    req = rng.normal(0.0, 1.0, (n, 3)) * scale * np.array([2.0, 0.5, 0.4]) + np.array([1.0, 0.0, 0.0])
    req[: n // 8, 0] = -np.abs(req[: n // 8, 0])  # backward: stop (or reverse) requests
    req[n // 8 : n // 6, :2] = 0.0  # stand still at once
    if not world_frame:
        return req
    h = table.heading[rows]
    c, s = np.cos(h), np.sin(h)
    return np.stack(
        [
            table.x[rows] + c * req[:, 0] - s * req[:, 1],
            table.y[rows] + s * req[:, 0] + c * req[:, 1],
            h + req[:, 2] + rng.choice([0.0, 2 * math.pi, -2 * math.pi], n),
        ],  # fmt: skip
        axis=1,
    )


def compiled_and_torch(seed: int, world_frame: bool, limits: ReachLimits, device: torch.device):
    table, rows = random_state(seed, limits.allow_reverse)
    other, _ = random_state(seed, limits.allow_reverse)  # a copy (deepcopy would detach the column views)
    actions = random_requests(table, rows, seed, world_frame)
    (apply_target_pose if world_frame else apply_relative_pose)(table, rows, actions, DT, limits)
    apply_pose_torch(other, rows, actions, world_frame, DT, limits, device)
    return table, other, rows


def assert_same(compiled: VehicleTable, torched: VehicleTable, rows: np.ndarray) -> None:
    for name in WRITTEN:
        np.testing.assert_allclose(getattr(torched, name)[rows], getattr(compiled, name)[rows],
                                   rtol=1e-12, atol=1e-12, err_msg=name)  # fmt: skip
    assert np.isfinite(torched.data).all()
    others = np.ones(len(compiled.data), dtype=bool)
    others[[compiled.FLOAT_COLUMNS.index(c) for c in WRITTEN]] = False
    np.testing.assert_array_equal(torched.data[others], compiled.data[others])  # nothing else written


LIMITS = [ReachLimits(), ReachLimits(allow_reverse=True), ReachLimits(max_slip=0.0, max_speed=12.0, max_accel=2.0)]


@pytest.mark.parametrize("world_frame", [False, True], ids=["relative", "target"])
@pytest.mark.parametrize("limits", LIMITS, ids=["forward", "reverse", "tight"])
@pytest.mark.parametrize("seed", [0, 1])
def test_torch_stage_equals_compiled_kernel(seed, limits, world_frame):
    compiled, torched, rows = compiled_and_torch(seed, world_frame, limits, torch.device("cpu"))
    assert_same(compiled, torched, rows)
    # The comparison means something: most requests were beyond some limit, headings wrapped.
    table, rows0 = random_state(seed, limits.allow_reverse)
    asked = random_requests(table, rows0, seed, world_frame)
    if not world_frame:
        moved = np.hypot(compiled.x[rows] - table.x[rows], compiled.y[rows] - table.y[rows])
        assert np.mean(np.abs(moved - np.hypot(asked[:, 0], asked[:, 1])) > 1e-6) > 0.5
    crossed = np.sign(compiled.heading[rows]) != np.sign(table.heading[rows])
    assert np.sum(crossed & (np.abs(table.heading[rows]) > 3.0)) >= 5  # wrapped across +-pi
    assert np.all(np.abs(torched.heading[rows]) <= math.pi)


def test_limits_are_applied():
    """A request far beyond the limits gets the reachable speed and turn, not what it asked."""
    table = VehicleTable(4)
    rows = np.array([table.add("a", owner=0, role=Role.AGENT, x=0.0, y=0.0, heading=math.pi - 0.01, speed=10.0)])
    apply_pose_torch(table, rows, np.array([[50.0, 0.0, 1.0]]), False, DT, ReachLimits(), torch.device("cpu"))
    assert table.speed[0] == pytest.approx(10.0 + ReachLimits().max_accel * DT, abs=1e-12)
    assert table.yaw_rate[0] == pytest.approx(ReachLimits().max_yaw_rate, abs=1e-12)
    assert table.heading[0] == pytest.approx(-math.pi + 0.11, abs=1e-12)  # wrapped
    assert table.accel[0] == pytest.approx(ReachLimits().max_accel, abs=1e-9)


def test_empty_rows_and_bad_actions():
    table, rows = random_state(0, False)
    before = table.data.copy()
    apply_pose_torch(table, rows[:0], np.zeros((0, 3)), False, DT, ReachLimits(), torch.device("cpu"))
    np.testing.assert_array_equal(table.data, before)
    bad = np.zeros((2, 3))
    bad[1, 0] = np.nan
    with pytest.raises(ActionError, match=str(table.ids[rows[1]])):
        apply_pose_torch(table, rows[:2], bad, True, DT, ReachLimits(), torch.device("cpu"))
    np.testing.assert_array_equal(table.data, before)


def test_resolve_device():
    assert resolve_device("cpu") is None
    assert resolve_device("torch-cpu") == torch.device("cpu")
    for name in ("gpu", "cuda:x", "CPU", "", "cuda:"):
        with pytest.raises(ValueError, match=r"unknown device .*cpu, torch-cpu, cuda, cuda:N"):
            resolve_device(name)
    assert check_device_name("cuda:1") == "cuda:1"
    if torch.cuda.is_available():
        assert resolve_device("cuda") == torch.device("cuda")
        with pytest.raises(ValueError, match="only"):
            resolve_device(f"cuda:{torch.cuda.device_count()}")
    else:
        for name in ("cuda", "cuda:0"):
            with pytest.raises(ValueError, match="device: .*no CUDA GPU is visible"):
                resolve_device(name)


@CUDA
@pytest.mark.parametrize("world_frame", [False, True], ids=["relative", "target"])
@pytest.mark.parametrize("limits", LIMITS, ids=["forward", "reverse", "tight"])
def test_cuda_stage_equals_compiled_kernel(limits, world_frame):
    compiled, torched, rows = compiled_and_torch(3, world_frame, limits, torch.device("cuda"))
    assert_same(compiled, torched, rows)
