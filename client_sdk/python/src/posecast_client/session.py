"""The client's protocol state (pure): messages in, events and decisions out.

One :class:`ClientSession` lives as long as the :class:`~posecast_client.client.Client`,
across reconnects. It builds ``hello`` and checked ``frame`` messages, keeps ``seq``
increasing (never restarting on a new connection, so a pose's ``seq`` always names
one frame this client sent), remembers when recent frames were sent (for latency),
feeds ``pong`` into the clock, and sorts what the server sends into events for the
application and the reason a connection ended. No sockets, no clocks: the caller
passes ``now``.
"""

from __future__ import annotations

import math
import random
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from posecast_client.clock import ClockSync
from posecast_client.errors import (
    ConnectionLostError,
    DuplicateError,
    NotNormalisedError,
    OutOfOrderError,
    OutOfRangeError,
    PosecastClientError,
    ProtocolError,
    ServerShutdownError,
)
from posecast_client.protocol import (
    ALL_VALID,
    MAX_COORD_M,
    MAX_TIME_S,
    PROTOCOL_VERSION,
    UINT32_MAX,
    Bye,
    Error,
    Frame,
    Hello,
    Message,
    Pong,
    Pose,
    Poses,
    Presence,
    Skeleton,
    Welcome,
    seq_delta,
    seq_next,
)
from posecast_client.records import (
    ROOT_UNIT_M,
    AvatarState,
    decode_records,
    fk,
    items2world,
    skeleton2offsets,
)
from posecast_client.sites import TrackerSet

RESYNC_GAP_S = 0.25  # at most one automatic resync this often (as the TypeScript SDK)


@dataclass(frozen=True, slots=True)
class Reconnecting:
    """Event: the connection was lost; the client tries again after ``delay_s``.

    A :class:`~posecast_client.protocol.Welcome` event follows once it rejoined.
    """

    attempt: int  # 1 for the first try after a loss
    delay_s: float
    cause: BaseException


Event = Pose | Presence | Error | Welcome | Reconnecting


@dataclass
class Stats:
    """Counters of one client (all connections together)."""

    frames_sent: int = 0
    frames_dropped: int = 0  # send_frame while reconnecting: frames supersede, none queue
    poses: int = 0
    errors: int = 0  # non-fatal error messages
    reconnects: int = 0  # successful rejoins
    events_dropped: int = 0  # the application did not read events fast enough
    bad_messages: int = 0  # server messages this codec refused (logged, skipped)
    bad_records: int = 0  # v2 poses messages whose records could not be applied
    pose_messages: int = 0  # messages that carried poses (v1 pose, v2 poses)
    pose_bytes: int = 0  # their WebSocket payload bytes, all together


def backoff_delay(attempt: int, initial_s: float, max_s: float, rng: random.Random) -> float:
    """Exponential back-off with jitter: about ``initial_s * 2**(attempt-1)``, capped.

    The delay is drawn from the upper half of the step (``[d/2, d]``) so that many
    clients cut off by one server restart do not all come back in the same instant.
    """
    d = min(max_s, initial_s * 2.0 ** max(0, attempt - 1))
    return d * (0.5 + 0.5 * rng.random())


def is_retryable(cause: BaseException) -> bool:
    """Whether a session that ended with ``cause`` is worth reconnecting for."""
    if isinstance(cause, PosecastClientError):
        return bool(getattr(cause, "retryable", False))
    return isinstance(cause, OSError | TimeoutError)  # the transport's own failures


@dataclass
class AvatarTable:
    """v2: who each avatar id is, its bone offsets ``(19, 3)``, and the state records apply to."""

    players: dict[int, str] = field(default_factory=dict)
    offsets: dict[int, np.ndarray] = field(default_factory=dict)
    states: dict[int, AvatarState | None] = field(default_factory=dict)

    def clear(self) -> None:
        self.players.clear()
        self.offsets.clear()
        self.states.clear()

    def announce(self, player: str, avatar_id: int, skeleton: bytes) -> None:
        for h, p in list(self.players.items()):
            if p == player and h != avatar_id:  # the player moved to another avatar id
                self.forget(h)
        if self.players.get(avatar_id) != player:
            self.states[avatar_id] = None  # a new avatar on this id: wait for a keyframe
        self.players[avatar_id] = player
        self.offsets[avatar_id] = skeleton2offsets(skeleton)

    def drop_states(self) -> None:
        """Drop every reference: each avatar's next record must be a keyframe."""
        for avatar_id in self.states:
            self.states[avatar_id] = None

    def forget(self, avatar_id: int) -> None:
        self.players.pop(avatar_id, None)
        self.offsets.pop(avatar_id, None)
        self.states.pop(avatar_id, None)

    def forget_player(self, player: str) -> None:
        for h, p in list(self.players.items()):
            if p == player:
                self.forget(h)

    def poses(self, msg: Poses) -> list[Pose]:
        """The records of ``msg`` as poses. Raises BadFieldError for a bad record; the
        caller then drops every reference (:meth:`drop_states`): some of the message's
        records were not applied, so the server's references and these differ."""
        recs = decode_records(msg.data, self.states)
        if not recs:
            return []
        items = np.stack([r.state.items for r in recs])  # (R, 19, 4)
        world = items2world(items)
        roots = np.array([r.state.root for r in recs], dtype=np.float64) * ROOT_UNIT_M
        positions = fk(world, roots, np.stack([self.offsets[r.avatar_id] for r in recs]))
        return [
            Pose(
                player=self.players[rec.avatar_id],
                seq=rec.state.seq,
                t=msg.t,
                positions=positions[i],
                rotations=world[i],
                local_rotations=items[i],
                keyframe=rec.keyframe,
                reach_limited=rec.reach_limited,
            )
            for i, rec in enumerate(recs)
        ]


@dataclass
class ClientSession:
    """Seq, time and clock bookkeeping of one client, and what server messages mean.

    Args:
        seq0: the first frame's ``seq`` (0).
        remember_frames: how many recent frames' send times are kept (for latency).
    """

    seq0: int = 0
    remember_frames: int = 1024
    clock: ClockSync = field(default_factory=ClockSync)
    stats: Stats = field(default_factory=Stats)
    welcome: Welcome | None = None
    version: int = PROTOCOL_VERSION  # of the current connection
    avatars: AvatarTable = field(default_factory=AvatarTable)
    want_resync: bool = False  # a record could not be applied: ask for keyframes
    _resync_at: float = -1e18  # when the last one was asked for
    last_seq: int | None = None
    last_t: float = 0.0
    # The player's tracker set (frames carry its rows as ``sites``), None: 4 slots.
    tracker_set: TrackerSet | None = None
    _sent_at: OrderedDict[int, float] = field(default_factory=OrderedDict)

    # --- outgoing ----------------------------------------------------------------------

    def hello(
        self,
        token: str,
        room: str,
        name: str,
        layout: str | None = None,
        rate_hz: float | None = None,
        watch: tuple[str, ...] = (),
        pose_rate_hz: float | None = None,
    ) -> Hello:
        """The ``hello`` for this connection's version (v1 drops ``pose_rate_hz``)."""
        rate = pose_rate_hz if self.version >= 2 else None
        return Hello(token, room, name, layout, rate_hz, tuple(watch), self.version, rate)

    def frame(
        self,
        positions: ArrayLike,
        orientations: ArrayLike,
        *,
        now: float,
        valid: int = ALL_VALID,
        seq: int | None = None,
        t: float | None = None,
    ) -> Frame:
        """A checked frame, with the next ``seq`` and time ``now`` unless given.

        Rows: the four tracker slots, or (after joining with a tracker set) one per site
        of :attr:`tracker_set`, sent as ``sites``. Tracked rows: values finite and within
        +-1000 (OUT_OF_RANGE), orientations finite and not zero (NOT_NORMALISED), then
        normalised. Untracked rows are sent as origin + identity whatever they hold (NaN
        included).

        Raises:
            OutOfRangeError, NotNormalisedError: a tracked row is unusable.
            OutOfOrderError, DuplicateError: an explicit ``seq`` is not newer.
            ValueError: wrong shapes, ``valid`` beyond the rows, or a time outside
                [0, 1e12] or before the last frame's.
        """
        ts = self.tracker_set
        rows, full = (4, ALL_VALID) if ts is None else (len(ts), ts.all_valid)
        key = "trackers" if ts is None else "sites"
        pos = np.array(positions, dtype=np.float64)  # (rows, 3), a copy
        quat = np.array(orientations, dtype=np.float64)  # (rows, 4)
        if pos.shape != (rows, 3) or quat.shape != (rows, 4):
            raise ValueError(
                f"need positions ({rows}, 3) and orientations ({rows}, 4), got "
                f"{pos.shape}, {quat.shape}"
            )
        if not 0 <= valid <= full:
            raise ValueError(f"valid must be in 0..{full}, not {valid}")
        for i in range(rows):
            if not valid >> i & 1:
                pos[i], quat[i] = 0.0, (0.0, 0.0, 0.0, 1.0)
                continue
            if not (np.abs(pos[i]) <= MAX_COORD_M).all():  # NaN fails too
                raise OutOfRangeError(f"{key}[{i}] value {pos[i]}", field=f"{key}[{i}]")
            n = math.sqrt(float(quat[i] @ quat[i]))
            if not (math.isfinite(n) and n > 1e-6):
                raise NotNormalisedError(f"{key}[{i}] orientation {quat[i]}", field=f"{key}[{i}]")
            quat[i] /= n
        if seq is None:
            seq = self.seq0 if self.last_seq is None else seq_next(self.last_seq)
        elif not 0 <= seq <= UINT32_MAX:
            raise ValueError(f"seq {seq} is not a uint32")
        elif self.last_seq is not None:
            d = seq_delta(seq, self.last_seq)
            if d == 0:
                raise DuplicateError(f"seq {seq} was already sent", field="seq", ref_seq=seq)
            if d < 0:
                raise OutOfOrderError(f"seq {seq} after {self.last_seq}", field="seq", ref_seq=seq)
        # No time given: now, or the last frame's if that is later (a stamp ahead of
        # the clock, like a WebXR frame's predicted display time, must not make the
        # next unstamped frame refused as going back).
        t = max(now, self.last_t) if t is None else float(t)
        if not (0.0 <= t <= MAX_TIME_S and t >= self.last_t):
            raise ValueError(f"frame time {t} s is outside [0, 1e12] or before the last one")
        return Frame(seq, t, pos, quat, valid, sites=ts is not None)

    def sent(self, frame: Frame, now: float) -> None:
        """``frame`` left at client time ``now``: its seq and time are taken."""
        self.last_seq, self.last_t = frame.seq, frame.t
        self.stats.frames_sent += 1
        self._sent_at[frame.seq] = now
        while len(self._sent_at) > self.remember_frames:
            self._sent_at.popitem(last=False)

    def dropped(self, frame: Frame) -> None:
        """``frame`` could not be sent (no connection); its seq is used up all the same,
        so that seqs stay increasing across the gap."""
        self.last_seq, self.last_t = frame.seq, frame.t
        self.stats.frames_dropped += 1

    def sent_at(self, seq: int) -> float | None:
        """Client time the frame ``seq`` was sent (recent frames only)."""
        return self._sent_at.get(seq)

    # --- incoming ----------------------------------------------------------------------

    def connected(self, version: int = PROTOCOL_VERSION) -> None:
        """A new connection (of protocol ``version``): its server may be another
        process, with another clock and other avatar ids."""
        self.clock.reset()
        self.version = version
        self.avatars.clear()
        self.want_resync = False
        self._resync_at = -1e18

    def receive_all(
        self, msg: Message, now: float, size: int = 0
    ) -> tuple[list[Event], BaseException | None]:
        """:meth:`receive` for any message: a v2 ``poses`` gives one event per record.
        ``size``: the message's payload bytes (counted for ``Stats.pose_bytes``)."""
        if isinstance(msg, Poses):
            self.stats.pose_messages += 1
            self.stats.pose_bytes += size
            try:
                poses = self.avatars.poses(msg)
            except ProtocolError:
                # Skipped records moved the server's references on: no delta after them
                # can be trusted until the resync's keyframes (as the other SDKs do).
                self.avatars.drop_states()
                self.stats.bad_records += 1
                if now - self._resync_at >= RESYNC_GAP_S:  # the server rate-limits them
                    self._resync_at = now
                    self.want_resync = True
                return [], None
            self.stats.poses += len(poses)
            return list(poses), None
        if isinstance(msg, Pose):
            self.stats.pose_messages += 1
            self.stats.pose_bytes += size
        event, end = self.receive(msg, now)
        return ([] if event is None else [event]), end

    def receive(self, msg: Message, now: float) -> tuple[Event | None, BaseException | None]:
        """What a server message means: ``(event for the application, end cause)``.

        The end cause is set when the message ends the session: a fatal ``error``
        (its typed exception) or a ``bye``. (A v2 ``poses`` needs :meth:`receive_all`.)
        """
        if isinstance(msg, Pose):
            self.stats.poses += 1
            return msg, None
        if isinstance(msg, Skeleton):
            # An avatar id not known yet (or now another player's) is announced by it, as
            # the TypeScript and C# SDKs do; the same player keeps its reference.
            self.avatars.announce(msg.player, msg.avatar_id, msg.skeleton)
            return None, None
        if isinstance(msg, Pong):
            self.clock.add(msg.t0, msg.t1, msg.t2, now)
            return None, None
        if isinstance(msg, Presence):
            if msg.event == "join" and msg.avatar_id is not None and msg.skeleton is not None:
                self.avatars.announce(msg.player, msg.avatar_id, msg.skeleton)
            elif msg.event == "leave":
                self.avatars.forget_player(msg.player)
            return msg, None
        if isinstance(msg, Welcome):
            self.welcome = msg
            for m in msg.members:
                if m.avatar_id is not None and m.skeleton is not None:
                    self.avatars.announce(m.player, m.avatar_id, m.skeleton)
            return msg, None
        if isinstance(msg, Error):
            if msg.fatal:
                return None, msg.exception()
            self.stats.errors += 1
            return msg, None
        if isinstance(msg, Bye):
            if msg.reason == ServerShutdownError.code:
                return None, ServerShutdownError("the server is shutting down")
            return None, ConnectionLostError(f"the server said bye ({msg.reason or 'no reason'})")
        return None, None  # client-only types from a confused server: ignore


def classify_join_reply(msg: Message) -> Welcome | ProtocolError | None:
    """During a join: the welcome, the error refusing the hello, or ``None`` (keep reading)."""
    if isinstance(msg, Welcome):
        return msg
    if isinstance(msg, Error):
        return msg.exception()
    return None
