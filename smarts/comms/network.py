"""The V2V network: messages queued by latency, delivered by range, channel, loss and bandwidth.

Per step the env calls ``send`` (the agents' messages), ``broadcast_traffic`` (connected traffic
vehicles' state messages) and then ``deliver`` (what each agent receives this step). A message sent at
step t is delivered at step t + latency, exactly once, to each receiver that

1. is not its sender (compared by table row),
2. is tuned to its channel (traffic on channel -1 is heard on every channel),
3. is within ``range`` of the position the sender had when it sent (the receiver's position is
   taken at delivery: a message reaches whoever is near the place it was sent from),
4. does not lose it (a seeded Bernoulli draw per (message, receiver), hashed from the seed, the send
   step, the message's slot and the receiver's row, so it does not depend on call order),
5. has bandwidth left: the survivors are ranked nearest sender first (ties: the order queued, so
   agents' messages before traffic's when ``send`` comes first) and the first ``receive_limit`` are
   kept; the rest are dropped, not postponed. Latency is fixed, so all messages delivered in a step
   are equally recent and distance is the only ranking that matters.

Messages wait in a ring of ``latency + 1`` slots of one step each; a slot holds up to ``capacity``
messages (one per table row per step). Which traffic vehicles are connected is drawn once per
vehicle id (a keyed hash of the seed and the id) when an id first appears in a row, so the draw
does not depend on rows or on the step. Each call is a few numpy operations and one compiled
kernel; no Python object exists per message.
"""

from __future__ import annotations

import hashlib
import math
import operator
from dataclasses import dataclass
from enum import IntEnum

import numba
import numpy as np

from smarts.comms.config import CommsConfig
from smarts.core.geometry import wrap_scalar
from smarts.core.vehicle_table import COLUMN, Role, VehicleTable

TRAFFIC_PAYLOAD_FIELDS: tuple[str, ...] = (
    "x", "y", "heading", "speed", "accel", "yaw_rate", "length", "width",
)
"""What a connected traffic vehicle broadcasts (world frame, SI units), in payload order; a payload
shorter than this keeps the leading fields, a longer one is zero-padded."""

TRAFFIC_PAYLOAD_BOUND = 1.0e5
"""Traffic payload values are clipped to +-this (world coordinates of any map fit)."""

BROADCAST_ROLES: tuple[Role, ...] = (Role.TRAFFIC, Role.REPLAY)
"""Roles whose vehicles may be connected; agents talk through their actions, pedestrians do not."""


class SenderKind(IntEnum):
    NONE = 0  # padding
    AGENT = 1
    TRAFFIC = 2


@dataclass
class Received:
    """What each receiver got this step, nearest sender first; padding has mask False.

    sender_row int64[n, M]: the sender's table row when it sent (-1 for padding).
    sender_kind int8[n, M]: a ``SenderKind``.
    pose float64[n, M, 3]: the sender's pose when it sent, in the receiver's frame now:
        dx forward, dy left (m), dheading (rad, wrapped to (-pi, pi]).
    age int32[n, M]: steps since the message was sent.
    payload float32[n, M, message_size].
    mask bool[n, M]; count int64[n] (messages per receiver).
    """

    sender_row: np.ndarray
    sender_kind: np.ndarray
    pose: np.ndarray
    age: np.ndarray
    payload: np.ndarray
    mask: np.ndarray
    count: np.ndarray

    @classmethod
    def empty(cls, n: int, max_messages: int, message_size: int) -> Received:
        return cls(
            sender_row=np.full((n, max_messages), -1, dtype=np.int64),
            sender_kind=np.zeros((n, max_messages), dtype=np.int8),
            pose=np.zeros((n, max_messages, 3)),
            age=np.zeros((n, max_messages), dtype=np.int32),
            payload=np.zeros((n, max_messages, message_size), dtype=np.float32),
            mask=np.zeros((n, max_messages), dtype=bool),
            count=np.zeros(n, dtype=np.int64),
        )


class V2VNetwork:
    """Message queues and delivery rules for one simulation (see the module docstring)."""

    def __init__(self, config: CommsConfig, capacity: int, seed: int = 0):
        if not isinstance(config, CommsConfig):
            raise TypeError(f"V2VNetwork: config must be a CommsConfig, got {type(config).__name__}")
        if capacity <= 0:
            raise ValueError(f"V2VNetwork: capacity must be positive, got {capacity}")
        self.config = config
        self.capacity = int(capacity)
        self.slots = config.latency + 1
        size = config.message_size
        self._slot_step = np.full(self.slots, -1, dtype=np.int64)  # the send step a slot holds
        self._count = np.zeros(self.slots, dtype=np.int64)
        self._row = np.zeros((self.slots, capacity), dtype=np.int64)
        self._kind = np.zeros((self.slots, capacity), dtype=np.int8)
        self._channel = np.zeros((self.slots, capacity), dtype=np.int64)
        self._pose = np.zeros((self.slots, capacity, 3))
        self._payload = np.zeros((self.slots, capacity, size), dtype=np.float32)
        self._traffic_fields = min(size, len(TRAFFIC_PAYLOAD_FIELDS))
        self._traffic_columns = np.array(
            [COLUMN[f] for f in TRAFFIC_PAYLOAD_FIELDS[: self._traffic_fields]], dtype=np.int64
        )
        # Connected traffic: per row, valid for the vehicle id last seen in that row.
        self._connected = np.zeros(capacity, dtype=bool)
        self._ids_seen: list[str | None] = [None] * capacity
        self.reset(seed)

    # ------------------------------------------------------------------ episode
    def reset(self, seed: int | None = None) -> None:
        """Drop every queued message; a new seed redraws loss and connected vehicles."""
        if seed is not None:
            self.seed = int(seed)
            self._seed64 = np.uint64(self.seed & _MASK64)
            self._seed_key = (self.seed & _MASK64).to_bytes(8, "little")
        self._slot_step[:] = -1
        self._count[:] = 0
        self._connected[:] = False
        self._ids_seen = [None] * self.capacity

    # ------------------------------------------------------------------ sending
    def send(
        self,
        step: int,
        table: VehicleTable,
        sender_rows: np.ndarray,
        channels: np.ndarray | int,
        payloads: np.ndarray,
    ) -> None:
        """Queue one message per sender row: the sender's current pose, a channel and a payload
        ``[n, message_size]`` (clipped to +-payload_bound)."""
        rows = np.asarray(sender_rows, dtype=np.int64)
        n = rows.shape[0]
        if n == 0:
            return
        payloads = np.asarray(payloads)
        if payloads.dtype.kind != "f":
            payloads = payloads.astype(np.float64)
        size = self.config.message_size
        if payloads.shape != (n, size):
            raise ValueError(
                f"V2V send: payloads have shape {payloads.shape}; expected ({n}, {size}): one "
                f"row of message_size floats per sender"
            )
        channels = np.asarray(channels, dtype=np.int64)
        if channels.ndim == 0:
            channels = np.full(n, channels, dtype=np.int64)
        elif channels.shape != (n,):
            raise ValueError(f"V2V send: channels have shape {channels.shape}; expected ({n},)")
        slot, start = self._open_slot(step, n)
        bad = _enqueue_agents(
            rows, channels, payloads, table.data, self.config.channels, self.config.payload_bound,
            start, self._row[slot], self._kind[slot], self._channel[slot], self._pose[slot],
            self._payload[slot],
        )
        if bad >= 0:
            raise ValueError(self._bad_message(table, rows[bad], channels[bad], payloads[bad]))
        self._count[slot] = start + n

    def _bad_message(self, table: VehicleTable, row: int, channel: int, payload) -> str:
        if not 0 <= row < table.capacity:
            return f"V2V send: sender row {int(row)} is not a row of the vehicle table"
        who = repr(table.ids[row])
        if not 0 <= channel < self.config.channels:
            return (
                f"V2V send: message from {who} is on channel {int(channel)}; expected a channel "
                f"in [0, {self.config.channels - 1}]"
            )
        return f"V2V send: message from {who} has payload {payload.tolist()}; expected finite numbers"

    def broadcast_traffic(self, step: int, table: VehicleTable) -> int:
        """Queue the state message of every connected traffic vehicle; returns how many."""
        if self.config.penetration <= 0.0:
            return 0
        self._refresh_connected(table)
        slot, start = self._open_slot(step, 0)
        n = _enqueue_traffic(
            self._connected, table.alive, table.role, _BROADCASTS, table.data,
            self._traffic_columns, self.config.traffic_channel, start, self._row[slot],
            self._kind[slot], self._channel[slot], self._pose[slot], self._payload[slot],
        )
        if n < 0:
            raise RuntimeError(self._overflow_message(step))
        self._count[slot] = start + n
        return n

    def is_connected(self, table: VehicleTable) -> np.ndarray:
        """bool[capacity]: live rows whose vehicle broadcasts traffic state messages."""
        self._refresh_connected(table)
        return self._connected & table.alive & _BROADCASTS[table.role]

    def _refresh_connected(self, table: VehicleTable) -> None:
        """Draw connectedness for the rows whose vehicle id changed (departures and arrivals)."""
        if table.capacity != self.capacity:
            raise ValueError(
                f"V2V network built for {self.capacity} rows, table has {table.capacity}"
            )
        ids = table.ids
        if ids == self._ids_seen:  # the common case: one C-level list comparison
            return
        changed = np.fromiter(
            map(operator.ne, ids, self._ids_seen), dtype=bool, count=self.capacity
        )
        p = self.config.penetration
        for row in np.flatnonzero(changed).tolist():
            vid = ids[row]
            self._connected[row] = vid is not None and self._id_uniform(vid) < p
            self._ids_seen[row] = vid

    def _id_uniform(self, vehicle_id: str) -> float:
        """A uniform number in [0, 1) fixed by the seed and the vehicle id (not the row)."""
        digest = hashlib.blake2b(
            vehicle_id.encode(), digest_size=8, key=self._seed_key, person=b"v2v-penetrate"
        ).digest()
        return (int.from_bytes(digest, "little") >> 11) * _INV_2_53

    def _open_slot(self, step: int, n: int) -> tuple[int, int]:
        """Slot of ``step`` (emptied if it held an older step) and its first free index, with
        room checked for ``n`` more messages."""
        if step < 0:
            raise ValueError(f"V2V: step must be >= 0, got {step}")
        slot = step % self.slots
        if self._slot_step[slot] != step:
            self._slot_step[slot] = step
            self._count[slot] = 0
        start = int(self._count[slot])
        if start + n > self.capacity:
            raise RuntimeError(self._overflow_message(step))
        return slot, start

    def _overflow_message(self, step: int) -> str:
        return (
            f"V2V: more than {self.capacity} messages sent in step {step} (one per table row is "
            "the most a step holds)"
        )

    # ------------------------------------------------------------------ delivery
    def deliver(
        self,
        step: int,
        table: VehicleTable,
        receiver_rows: np.ndarray,
        receiver_channels: np.ndarray | int = 0,
    ) -> Received:
        """The messages sent ``latency`` steps ago that reach each receiver this step."""
        rows = np.asarray(receiver_rows, dtype=np.int64)
        n = rows.shape[0]
        config = self.config
        out = Received.empty(n, config.max_messages, config.message_size)
        if n == 0:
            return out
        sent = step - config.latency
        slot = sent % self.slots
        # Nothing was sent at step ``sent`` (or the slot moved on): only the rows are checked.
        count = int(self._count[slot]) if sent >= 0 and self._slot_step[slot] == sent else 0
        channels = np.asarray(receiver_channels, dtype=np.int64)
        if channels.ndim == 0:
            channels = np.full(n, channels, dtype=np.int64)
        elif channels.shape != (n,):
            raise ValueError(
                f"V2V deliver: receiver_channels has shape {channels.shape}; expected ({n},)"
            )
        bad = _deliver(
            count, self._row[slot], self._kind[slot], self._channel[slot],
            self._pose[slot], self._payload[slot], table.data, rows, channels,
            config.range * config.range, config.loss, self._seed64, sent, config.receive_limit,
            config.latency, out.sender_row, out.sender_kind, out.pose, out.age, out.payload,
            out.mask, out.count,
        )
        if bad >= 0:
            raise ValueError(f"V2V deliver: receiver row {int(rows[bad])} is not a row of the vehicle table")
        return out


_MASK64 = (1 << 64) - 1
_INV_2_53 = 1.0 / (1 << 53)
_AGENT, _TRAFFIC = int(SenderKind.AGENT), int(SenderKind.TRAFFIC)
_X, _Y, _H = COLUMN["x"], COLUMN["y"], COLUMN["heading"]
_BROADCASTS = np.zeros(max(Role) + 1, dtype=bool)
_BROADCASTS[[int(r) for r in BROADCAST_ROLES]] = True

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)


@numba.njit(cache=True, nogil=True, inline="always")
def _mix(z):  # pragma: no cover - compiled
    """SplitMix64 finaliser: a well-spread 64-bit hash of z."""
    z = (z ^ (z >> _S30)) * _MIX1
    z = (z ^ (z >> _S27)) * _MIX2
    return z ^ (z >> _S31)


@numba.njit(cache=True, nogil=True, inline="always")
def _loss_uniform(seed, sent_step, message, receiver_row):  # pragma: no cover - compiled
    """Uniform [0, 1) fixed by (seed, send step, message slot, receiver row)."""
    z = _mix(seed + _GOLDEN)
    z = _mix(z ^ np.uint64(sent_step))
    z = _mix(z ^ np.uint64(message))
    z = _mix(z ^ np.uint64(receiver_row))
    return float(z >> _S11) * 1.1102230246251565e-16  # 2**-53


@numba.njit(cache=True, nogil=True)
def _enqueue_agents(
    rows, channels, payloads, data, n_channels, bound, start, q_row, q_kind, q_channel, q_pose,
    q_payload,
):  # pragma: no cover - compiled
    """Write agents' messages into a slot from ``start``; returns the index of the first bad
    message (channel out of range or non-finite payload) without writing anything, else -1."""
    n, size = payloads.shape
    for i in range(n):
        if rows[i] < 0 or rows[i] >= data.shape[1]:
            return i
        if channels[i] < 0 or channels[i] >= n_channels:
            return i
        for p in range(size):
            if not math.isfinite(payloads[i, p]):
                return i
    for i in range(n):
        k, r = start + i, rows[i]
        q_row[k] = r
        q_kind[k] = _AGENT
        q_channel[k] = channels[i]
        q_pose[k, 0], q_pose[k, 1], q_pose[k, 2] = data[_X, r], data[_Y, r], data[_H, r]
        for p in range(size):
            q_payload[k, p] = min(max(payloads[i, p], -bound), bound)
    return -1


@numba.njit(cache=True, nogil=True)
def _enqueue_traffic(
    connected, alive, role, broadcasts, data, columns, channel, start, q_row, q_kind, q_channel,
    q_pose, q_payload,
):  # pragma: no cover - compiled
    """Write the state message of every live connected traffic row from ``start``; returns how
    many, or -1 when the slot overflows."""
    capacity, size = q_payload.shape
    n_fields = columns.shape[0]
    k = start
    for r in range(alive.shape[0]):
        if not (connected[r] and alive[r] and broadcasts[role[r]]):
            continue
        if k >= capacity:
            return -1
        q_row[k] = r
        q_kind[k] = _TRAFFIC
        q_channel[k] = channel
        q_pose[k, 0], q_pose[k, 1], q_pose[k, 2] = data[_X, r], data[_Y, r], data[_H, r]
        for p in range(n_fields):
            v = data[columns[p], r]
            q_payload[k, p] = min(max(v, -TRAFFIC_PAYLOAD_BOUND), TRAFFIC_PAYLOAD_BOUND)
        for p in range(n_fields, size):
            q_payload[k, p] = 0.0
        k += 1
    return k - start


@numba.njit(cache=True, nogil=True)
def _deliver(
    count, s_row, s_kind, s_channel, s_pose, s_payload, data, receivers, r_channels,
    range2, loss, seed, sent_step, limit, age, o_row, o_kind, o_pose, o_age, o_payload, o_mask,
    o_count,
):  # pragma: no cover - compiled
    for i in range(receivers.shape[0]):
        if receivers[i] < 0 or receivers[i] >= data.shape[1]:
            return i
    dist2 = np.empty(count)
    index = np.empty(count, dtype=np.int64)
    size = s_payload.shape[1]
    for i in range(receivers.shape[0]):
        r = receivers[i]
        rx, ry, rh = data[_X, r], data[_Y, r], data[_H, r]
        m = 0
        for k in range(count):
            if s_row[k] == r:
                continue
            ch = s_channel[k]
            if ch >= 0 and ch != r_channels[i]:
                continue
            ddx, ddy = s_pose[k, 0] - rx, s_pose[k, 1] - ry
            d2 = ddx * ddx + ddy * ddy
            if d2 > range2:
                continue
            if loss > 0.0 and _loss_uniform(seed, sent_step, k, r) < loss:
                continue
            dist2[m] = d2
            index[m] = k
            m += 1
        take = min(m, limit)
        c, s = math.cos(rh), math.sin(rh)
        for j in range(take):
            # Partial selection sort: the j-th nearest (ties: sent first) among the rest.
            best = j
            for q in range(j + 1, m):
                if dist2[q] < dist2[best] or (dist2[q] == dist2[best] and index[q] < index[best]):
                    best = q
            dist2[j], dist2[best] = dist2[best], dist2[j]
            index[j], index[best] = index[best], index[j]
            k = index[j]
            ddx, ddy = s_pose[k, 0] - rx, s_pose[k, 1] - ry
            o_row[i, j] = s_row[k]
            o_kind[i, j] = s_kind[k]
            o_pose[i, j, 0] = c * ddx + s * ddy
            o_pose[i, j, 1] = -s * ddx + c * ddy
            o_pose[i, j, 2] = wrap_scalar(s_pose[k, 2] - rh)
            o_age[i, j] = age
            for p in range(size):
                o_payload[i, j, p] = s_payload[k, p]
            o_mask[i, j] = True
        o_count[i] = take
    return -1
