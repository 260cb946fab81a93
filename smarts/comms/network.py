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
from collections.abc import Sequence
from enum import IntEnum
from typing import NamedTuple

import numpy as np

from smarts.comms.config import CommsConfig
from smarts.compiled import njit
from smarts.core.geometry import wrap_scalar
from smarts.core.vehicle_table import COLUMN, Role, VehicleTable
from smarts.records import declare, freeze_fields

TRAFFIC_PAYLOAD_FIELDS: tuple[str, ...] = (
    "x",
    "y",
    "heading",
    "speed",
    "accel",
    "yaw_rate",
    "length",
    "width",
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


class Received(NamedTuple):
    """What each receiver got this step, nearest sender first; padding has mask False.

    sender_row int64[n, M]: the sender's table row when it sent (-1 for padding).
    sender_kind int8[n, M]: a ``SenderKind``.
    pose float64[n, M, 3]: the sender's pose when it sent, in the receiver's frame now:
        dx forward, dy left (m), dheading (rad, wrapped to (-pi, pi]).
    age int32[n, M]: steps since the message was sent.
    payload float32[n, M, message_size].
    mask bool[n, M]; count int64[n] (messages per receiver).

    A named tuple: ``_deliver`` makes one in compiled code.
    """

    sender_row: np.ndarray
    sender_kind: np.ndarray
    pose: np.ndarray
    age: np.ndarray
    payload: np.ndarray
    mask: np.ndarray
    count: np.ndarray


class Queue(NamedTuple):
    """The message rings of every episode: slot s of episode e holds the messages sent at step
    ``slot_step[e, s]``, the first ``count[e, s]`` along the message axis (C = capacity)."""

    slot_step: np.ndarray  # int64[E, S] the send step a slot holds, -1 none
    count: np.ndarray  # int64[E, S]
    row: np.ndarray  # int64[E, S, C] the sender's row
    kind: np.ndarray  # int8[E, S, C] a SenderKind
    channel: np.ndarray  # int64[E, S, C] -1: every channel
    pose: np.ndarray  # float64[E, S, C, 3] the sender's x, y, heading when it sent
    payload: np.ndarray  # float32[E, S, C, message_size]


class Rule(NamedTuple):
    """The numbers of a ``CommsConfig`` that the kernels apply."""

    capacity: int  # rows per episode, messages per slot
    channels: int
    payload_bound: float
    traffic_channel: int
    range2: float  # squared range
    loss: float
    latency: int
    limit: int  # receive_limit
    max_messages: int


class NetworkState(NamedTuple):
    """What the kernels of one ``V2VNetworks`` read besides a call's arguments: its own arrays,
    built once and changed in place (frozen in ``__init__``)."""

    rule: Rule
    queue: Queue
    seeds: np.ndarray  # uint64[E]
    connected: np.ndarray  # bool[E, C] rows whose traffic vehicle broadcasts
    traffic_columns: np.ndarray  # int64[fields] table columns of a traffic payload
    broadcasts: np.ndarray  # bool[roles] roles that may be connected


class Receiver(NamedTuple):
    """One receiver in ``_deliver`` (compiled code only)."""

    row: int
    channel: int
    x: float
    y: float


declare(NetworkState)


@njit(nogil=True)
def _freeze(fields):  # pragma: no cover - compiled
    """The frozen record of this module's records (see ``smarts.records``)."""
    return freeze_fields(fields)


class V2VNetworks:
    """The message queues and delivery rules of ``episodes`` episodes with one ``config``, in one
    set of arrays (see the module docstring): every call serves all the episodes at once.

    Rows are each episode's own (0 to ``capacity`` - 1, the rows of its block of a simulation's
    table, whose first row is ``base[e]``), so an episode's losses and connected vehicles are those
    it has alone. Queues hold ``latency + 1`` slots of one step per episode."""

    def __init__(self, config: CommsConfig, capacity: int, seeds: Sequence[int]):
        if not isinstance(config, CommsConfig):
            raise TypeError(f"V2VNetwork: config must be a CommsConfig, got {type(config).__name__}")
        if capacity <= 0:
            raise ValueError(f"V2VNetwork: capacity must be positive, got {capacity}")
        self.config = config
        self.capacity = int(capacity)
        self.episodes = n = len(seeds)
        self.slots = config.latency + 1
        size = config.message_size
        self._queue = Queue(
            slot_step=np.full((n, self.slots), -1, dtype=np.int64),
            count=np.zeros((n, self.slots), dtype=np.int64),
            row=np.zeros((n, self.slots, capacity), dtype=np.int64),
            kind=np.zeros((n, self.slots, capacity), dtype=np.int8),
            channel=np.zeros((n, self.slots, capacity), dtype=np.int64),
            pose=np.zeros((n, self.slots, capacity, 3)),
            payload=np.zeros((n, self.slots, capacity, size), dtype=np.float32),
        )
        self._traffic_fields = min(size, len(TRAFFIC_PAYLOAD_FIELDS))
        self._traffic_columns = np.array(
            [COLUMN[f] for f in TRAFFIC_PAYLOAD_FIELDS[: self._traffic_fields]], dtype=np.int64
        )
        # Connected traffic: per row, valid for the vehicle (table serial) last seen in that row.
        self._connected = np.zeros((n, capacity), dtype=bool)
        self._serial_seen = np.zeros((n, capacity), dtype=np.int64)
        self.seeds = np.zeros(n, dtype=np.uint64)
        self._seed_keys: list[bytes] = [b""] * n
        # The arrays above are only ever changed in place, so the record stays theirs.
        self._state = _freeze(NetworkState(
            rule=Rule(
                capacity=self.capacity, channels=int(config.channels), payload_bound=float(config.payload_bound),
                traffic_channel=int(config.traffic_channel), range2=float(config.range * config.range),
                loss=float(config.loss), latency=int(config.latency), limit=int(config.receive_limit),
                max_messages=int(config.max_messages),
            ),
            queue=self._queue, seeds=self.seeds, connected=self._connected,
            traffic_columns=self._traffic_columns, broadcasts=_BROADCASTS,
        ))  # fmt: skip
        self.reset(np.arange(n), list(seeds))

    # ------------------------------------------------------------------ episode
    def reset(self, episodes: np.ndarray, seeds: Sequence[int | None] | None = None) -> None:
        """Drop every queued message of ``episodes``; a new seed redraws loss and connected vehicles."""
        episodes = np.asarray(episodes, dtype=np.int64)
        for k, e in enumerate(episodes.tolist()):
            if seeds is not None and seeds[k] is not None:
                seed = int(seeds[k])
                self.seeds[e] = np.uint64(seed & _MASK64)
                self._seed_keys[e] = (seed & _MASK64).to_bytes(8, "little")
        self._queue.slot_step[episodes] = -1
        self._queue.count[episodes] = 0
        self._connected[episodes] = False
        self._serial_seen[episodes] = 0

    # ------------------------------------------------------------------ sending
    def send(
        self,
        steps: np.ndarray,
        data: np.ndarray,
        base: np.ndarray,
        episode: np.ndarray,
        rows: np.ndarray,
        channels: np.ndarray,
        payloads: np.ndarray,
    ) -> int:
        """Queue one message per sender: episode ``episode[i]`` (ascending), its row ``rows[i]``
        (the episode's own; the pose is read at ``base[episode] + row`` of ``data``), a channel and
        a payload (clipped to +-payload_bound). ``steps[e]``: each episode's step. Returns -1, or
        the index of the first bad message (nothing is queued then)."""
        if rows.shape[0] == 0:
            return -1
        size = self.config.message_size
        if payloads.shape != (rows.shape[0], size):
            raise ValueError(
                f"V2V send: payloads have shape {payloads.shape}; expected ({rows.shape[0]}, {size}): one "
                f"row of message_size floats per sender"
            )
        bad = _enqueue_agents(self._state, steps, episode, rows, channels, payloads, data, base)
        if bad == -2:
            raise RuntimeError(self._overflow_message())
        return bad

    def broadcast_traffic(
        self,
        steps: np.ndarray,
        tables: Sequence[VehicleTable],
        whole: VehicleTable,
        base: np.ndarray,
        episodes: np.ndarray,
    ) -> None:
        """Queue the state message of every connected traffic vehicle of ``episodes``
        (``tables[e]``: episode ``e``'s own table, for vehicle ids; ``whole``: the table whose row
        ``base[e] + r`` is its row ``r``)."""
        if self.config.penetration <= 0.0 or episodes.shape[0] == 0:
            return
        self._refresh_connected(tables, episodes)
        if _enqueue_traffic(self._state, steps, episodes, whole.alive, whole.role, whole.data, base) < 0:
            raise RuntimeError(self._overflow_message())

    def is_connected(self, table: VehicleTable, episode: int = 0) -> np.ndarray:
        """bool[capacity]: live rows of episode ``episode`` (``table``, its own) that broadcast."""
        self._refresh_connected([table] * (episode + 1), np.array([episode]))
        return self._connected[episode] & table.alive & _BROADCASTS[table.role]

    def _refresh_connected(self, tables: Sequence[VehicleTable], episodes: np.ndarray) -> None:
        """Draw connectedness for the rows whose vehicle changed (departures and arrivals)."""
        p = self.config.penetration
        for e in episodes.tolist():
            table = tables[e]
            if table.capacity != self.capacity:
                raise ValueError(f"V2V network built for {self.capacity} rows, table has {table.capacity}")
            changed = np.flatnonzero(table.serial != self._serial_seen[e])
            if changed.size == 0:
                continue
            ids = table.ids
            for row in changed.tolist():
                vid = ids[row] if table.alive[row] else None
                self._connected[e, row] = vid is not None and self._id_uniform(e, vid) < p
                self._serial_seen[e, row] = table.serial[row]

    def _id_uniform(self, episode: int, vehicle_id: str) -> float:
        """A uniform number in [0, 1) fixed by the episode's seed and the vehicle id (not the row)."""
        digest = hashlib.blake2b(
            vehicle_id.encode(), digest_size=8, key=self._seed_keys[episode], person=b"v2v-penetrate"
        ).digest()
        return (int.from_bytes(digest, "little") >> 11) * _INV_2_53

    def _overflow_message(self) -> str:
        return f"V2V: more than {self.capacity} messages sent in one step (one per table row is the most a step holds)"

    # ------------------------------------------------------------------ delivery
    def deliver(
        self,
        steps: np.ndarray,
        data: np.ndarray,
        base: np.ndarray,
        episode: np.ndarray,
        rows: np.ndarray,
        channels: np.ndarray,
    ) -> Received:
        """The messages sent ``latency`` steps ago that reach each receiver (episode
        ``episode[i]``, its row ``rows[i]``, tuned to ``channels[i]``) at its episode's step."""
        bad, got = _deliver(self._state, steps, episode, rows, channels, data, base)
        if bad >= 0:
            raise ValueError(f"V2V deliver: receiver row {int(rows[bad])} is not a row of the vehicle table")
        return got


class V2VNetwork:
    """The V2V network of one simulation (one episode): ``V2VNetworks`` with one episode, whose
    rows are the table's own."""

    def __init__(self, config: CommsConfig, capacity: int, seed: int = 0):
        self.net = V2VNetworks(config, capacity, [seed])
        self.config = config
        self.capacity = self.net.capacity
        self.seed = int(seed)
        self._base = np.zeros(1, dtype=np.int64)
        self._one = np.zeros(1, dtype=np.int64)

    def reset(self, seed: int | None = None) -> None:
        """Drop every queued message; a new seed redraws loss and connected vehicles."""
        if seed is not None:
            self.seed = int(seed)
        self.net.reset(np.zeros(1, dtype=np.int64), [seed])

    def send(self, step: int, table: VehicleTable, sender_rows, channels, payloads) -> None:
        """Queue one message per sender row: the sender's current pose, a channel and a payload
        ``[n, message_size]`` (clipped to +-payload_bound)."""
        rows = np.asarray(sender_rows, dtype=np.int64)
        n = rows.shape[0]
        if n == 0:
            return
        if step < 0:
            raise ValueError(f"V2V: step must be >= 0, got {step}")
        payloads = np.asarray(payloads)
        if payloads.dtype.kind != "f":
            payloads = payloads.astype(np.float64)
        channels = np.asarray(channels, dtype=np.int64)
        if channels.ndim == 0:
            channels = np.full(n, channels, dtype=np.int64)
        elif channels.shape != (n,):
            raise ValueError(f"V2V send: channels have shape {channels.shape}; expected ({n},)")
        bad = self.net.send(np.array([step]), table.data, self._base, np.zeros(n, np.int64), rows, channels, payloads)
        if bad >= 0:
            raise ValueError(self._bad_message(table, rows[bad], channels[bad], payloads[bad]))

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
        if step < 0:
            raise ValueError(f"V2V: step must be >= 0, got {step}")
        if self.config.penetration <= 0.0:
            return 0
        before = self._queued(step)
        self.net.broadcast_traffic(np.array([step]), [table], table, self._base, self._one)
        return self._queued(step) - before

    def _queued(self, step: int) -> int:
        slot = step % self.net.slots
        queue = self.net._queue
        return int(queue.count[0, slot]) if queue.slot_step[0, slot] == step else 0

    def is_connected(self, table: VehicleTable) -> np.ndarray:
        """bool[capacity]: live rows whose vehicle broadcasts traffic state messages."""
        return self.net.is_connected(table)

    def deliver(self, step: int, table: VehicleTable, receiver_rows, receiver_channels=0) -> Received:
        """The messages sent ``latency`` steps ago that reach each receiver this step."""
        rows = np.asarray(receiver_rows, dtype=np.int64)
        n = rows.shape[0]
        channels = np.asarray(receiver_channels, dtype=np.int64)
        if channels.ndim == 0:
            channels = np.full(n, channels, dtype=np.int64)
        elif channels.shape != (n,):
            raise ValueError(f"V2V deliver: receiver_channels has shape {channels.shape}; expected ({n},)")
        return self.net.deliver(np.array([step]), table.data, self._base, np.zeros(n, np.int64), rows, channels)


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


@njit(nogil=True, inline="always")
def _mix(z):  # pragma: no cover - compiled
    """SplitMix64 finaliser: a well-spread 64-bit hash of z."""
    z = (z ^ (z >> _S30)) * _MIX1
    z = (z ^ (z >> _S27)) * _MIX2
    return z ^ (z >> _S31)


@njit(nogil=True, inline="always")
def _loss_uniform(seed, sent_step, message, receiver_row):  # pragma: no cover - compiled
    """Uniform [0, 1) fixed by (seed, send step, message slot, receiver row)."""
    z = _mix(seed + _GOLDEN)
    z = _mix(z ^ np.uint64(sent_step))
    z = _mix(z ^ np.uint64(message))
    z = _mix(z ^ np.uint64(receiver_row))
    return float(z >> _S11) * 1.1102230246251565e-16  # 2**-53


@njit(nogil=True, inline="always")
def _open_slot(queue, steps, e):  # pragma: no cover - compiled
    """Episode ``e``'s slot of its step (emptied if it held an older step)."""
    slot_step = queue.slot_step
    step = steps[e]
    slot = step % slot_step.shape[1]
    if slot_step[e, slot] != step:
        slot_step[e, slot] = step
        queue.count[e, slot] = 0
    return slot


@njit(nogil=True)
def _enqueue_agents(network, steps, episode, rows, channels, payloads, data, base):  # pragma: no cover - compiled
    """Write agents' messages into their episodes' slots; returns the index of the first bad
    message (row or channel out of range, non-finite payload) without writing anything, -2 when a
    slot overflows, else -1."""
    rule, queue = network.rule, network.queue
    capacity, bound = rule.capacity, rule.payload_bound
    count, q_row, q_kind, q_channel, q_pose, q_payload = (
        queue.count, queue.row, queue.kind, queue.channel, queue.pose, queue.payload
    )  # fmt: skip
    n, size = payloads.shape
    for i in range(n):
        if rows[i] < 0 or rows[i] >= capacity:
            return i
        if channels[i] < 0 or channels[i] >= rule.channels:
            return i
        for p in range(size):
            if not math.isfinite(payloads[i, p]):
                return i
    for i in range(n):
        e, r = episode[i], rows[i]
        slot = _open_slot(queue, steps, e)
        k = count[e, slot]
        if k >= capacity:
            return -2
        g = base[e] + r
        q_row[e, slot, k] = r
        q_kind[e, slot, k] = _AGENT
        q_channel[e, slot, k] = channels[i]
        q_pose[e, slot, k, 0], q_pose[e, slot, k, 1], q_pose[e, slot, k, 2] = data[_X, g], data[_Y, g], data[_H, g]
        for p in range(size):
            q_payload[e, slot, k, p] = min(max(payloads[i, p], -bound), bound)
        count[e, slot] = k + 1
    return -1


@njit(nogil=True)
def _enqueue_traffic(network, steps, episodes, alive, role, data, base):  # pragma: no cover - compiled
    """Write the state message of every live connected traffic row of ``episodes``; returns -1
    when a slot overflows, else 0."""
    rule, queue = network.rule, network.queue
    connected, columns, broadcasts = network.connected, network.traffic_columns, network.broadcasts
    count, q_row, q_kind, q_channel, q_pose, q_payload = (
        queue.count, queue.row, queue.kind, queue.channel, queue.pose, queue.payload
    )  # fmt: skip
    capacity, channel = rule.capacity, rule.traffic_channel
    size = q_payload.shape[3]
    n_fields = columns.shape[0]
    for q in range(episodes.shape[0]):
        e = episodes[q]
        slot = _open_slot(queue, steps, e)
        k = count[e, slot]
        for r in range(capacity):
            g = base[e] + r
            if not (connected[e, r] and alive[g] and broadcasts[role[g]]):
                continue
            if k >= capacity:
                return -1
            q_row[e, slot, k] = r
            q_kind[e, slot, k] = _TRAFFIC
            q_channel[e, slot, k] = channel
            q_pose[e, slot, k, 0], q_pose[e, slot, k, 1], q_pose[e, slot, k, 2] = data[_X, g], data[_Y, g], data[_H, g]
            for p in range(n_fields):
                v = data[columns[p], g]
                q_payload[e, slot, k, p] = min(max(v, -TRAFFIC_PAYLOAD_BOUND), TRAFFIC_PAYLOAD_BOUND)
            for p in range(n_fields, size):
                q_payload[e, slot, k, p] = 0.0
            k += 1
        count[e, slot] = k
    return 0


# The two steps of ``_deliver`` per receiver, inlined into it by numba.
@njit(nogil=True, inline="always")
def _heard(queue, e, slot, n_sent, sent, receiver, rule, seed, dist2, index):  # pragma: no cover - compiled
    """Which of the ``n_sent`` messages of episode ``e``'s slot (sent at step ``sent``) the receiver
    hears: not its own, on its channel (or broadcast), within range and not lost. Writes their
    squared distances and indices into ``dist2``/``index`` and returns how many."""
    q_row, q_channel, q_pose = queue.row[e, slot], queue.channel[e, slot], queue.pose[e, slot]
    r, channel, rx, ry = receiver.row, receiver.channel, receiver.x, receiver.y
    range2, loss = rule.range2, rule.loss
    m = 0
    for k in range(n_sent):
        if q_row[k] == r:
            continue
        ch = q_channel[k]
        if ch >= 0 and ch != channel:
            continue
        ddx, ddy = q_pose[k, 0] - rx, q_pose[k, 1] - ry
        d2 = ddx * ddx + ddy * ddy
        if d2 > range2:
            continue
        if loss > 0.0 and _loss_uniform(seed, sent, k, r) < loss:
            continue
        dist2[m] = d2
        index[m] = k
        m += 1
    return m


@njit(nogil=True, inline="always")
def _nearest_first(dist2, index, m, take):  # pragma: no cover - compiled
    """Partial selection sort of the first ``m`` entries: the ``take`` nearest (ties: sent first) first."""
    for j in range(take):
        best = j
        for q in range(j + 1, m):
            if dist2[q] < dist2[best] or (dist2[q] == dist2[best] and index[q] < index[best]):
                best = q
        dist2[j], dist2[best] = dist2[best], dist2[j]
        index[j], index[best] = index[best], index[j]


@njit(nogil=True)
def _deliver(network, steps, episode, receivers, r_channels, data, base):  # pragma: no cover - compiled
    """What each receiver (episode ``episode[i]``, row ``receivers[i]``, tuned to ``r_channels[i]``)
    gets: (-1, a ``Received``), or (the index of the first receiver whose row is out of range,
    nothing filled)."""
    rule, queue, seeds = network.rule, network.queue, network.seeds
    capacity, latency, limit = rule.capacity, rule.latency, rule.limit
    slot_step, count, q_row, q_kind, q_pose, q_payload = (
        queue.slot_step, queue.count, queue.row, queue.kind, queue.pose, queue.payload
    )  # fmt: skip
    n, width, size = receivers.shape[0], rule.max_messages, q_payload.shape[3]
    out = Received(
        sender_row=np.full((n, width), -1, dtype=np.int64), sender_kind=np.zeros((n, width), dtype=np.int8),
        pose=np.zeros((n, width, 3)), age=np.zeros((n, width), dtype=np.int32),
        payload=np.zeros((n, width, size), dtype=np.float32), mask=np.zeros((n, width), dtype=np.bool_),
        count=np.zeros(n, dtype=np.int64),
    )  # fmt: skip
    o_row, o_kind, o_pose, o_age, o_payload, o_mask, o_count = (
        out.sender_row, out.sender_kind, out.pose, out.age, out.payload, out.mask, out.count
    )  # fmt: skip
    for i in range(n):
        if receivers[i] < 0 or receivers[i] >= capacity:
            return i, out
    slots = slot_step.shape[1]
    dist2 = np.empty(capacity)
    index = np.empty(capacity, dtype=np.int64)
    for i in range(n):
        e, r = episode[i], receivers[i]
        sent = steps[e] - latency
        slot = sent % slots if sent >= 0 else 0
        # Nothing was sent at step ``sent`` (or the slot moved on): nothing to deliver.
        n_sent = count[e, slot] if sent >= 0 and slot_step[e, slot] == sent else 0
        g = base[e] + r
        rx, ry, rh = data[_X, g], data[_Y, g], data[_H, g]
        receiver = Receiver(row=r, channel=r_channels[i], x=rx, y=ry)
        m = _heard(queue, e, slot, n_sent, sent, receiver, rule, seeds[e], dist2, index)
        take = min(m, limit)
        _nearest_first(dist2, index, m, take)
        c, s = math.cos(rh), math.sin(rh)
        for j in range(take):
            k = index[j]
            ddx, ddy = q_pose[e, slot, k, 0] - rx, q_pose[e, slot, k, 1] - ry
            o_row[i, j] = q_row[e, slot, k]
            o_kind[i, j] = q_kind[e, slot, k]
            o_pose[i, j, 0] = c * ddx + s * ddy
            o_pose[i, j, 1] = -s * ddx + c * ddy
            o_pose[i, j, 2] = wrap_scalar(q_pose[e, slot, k, 2] - rh)
            o_age[i, j] = latency
            for p in range(size):
                o_payload[i, j, p] = q_payload[e, slot, k, p]
            o_mask[i, j] = True
        o_count[i] = take
    return -1, out
