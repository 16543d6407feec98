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
    UINT32_MAX,
    Bye,
    Error,
    Frame,
    Hello,
    Message,
    Pong,
    Pose,
    Presence,
    Welcome,
    seq_delta,
    seq_next,
)


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
    last_seq: int | None = None
    last_t: float = 0.0
    _sent_at: OrderedDict[int, float] = field(default_factory=OrderedDict)

    # --- outgoing ----------------------------------------------------------------------

    @staticmethod
    def hello(
        token: str,
        room: str,
        name: str,
        layout: str | None = None,
        rate_hz: float | None = None,
        watch: tuple[str, ...] = (),
    ) -> Hello:
        return Hello(token, room, name, layout, rate_hz, tuple(watch))

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

        Tracked slots: positions finite and within +-1000 m (OUT_OF_RANGE), orientations
        finite and not zero (NOT_NORMALISED), then normalised. Untracked slots are sent
        as origin + identity whatever they hold (NaN included).

        Raises:
            OutOfRangeError, NotNormalisedError: a tracked slot is unusable.
            OutOfOrderError, DuplicateError: an explicit ``seq`` is not newer.
            ValueError: wrong shapes, ``valid`` outside 0..15, or a time outside
                [0, 1e12] or before the last frame's.
        """
        pos = np.array(positions, dtype=np.float64)  # (4, 3), a copy
        quat = np.array(orientations, dtype=np.float64)  # (4, 4)
        if pos.shape != (4, 3) or quat.shape != (4, 4):
            raise ValueError(
                f"need positions (4, 3) and orientations (4, 4), got {pos.shape}, {quat.shape}"
            )
        if not 0 <= valid <= ALL_VALID:
            raise ValueError(f"valid must be in 0..15, not {valid}")
        for i in range(4):
            if not valid >> i & 1:
                pos[i], quat[i] = 0.0, (0.0, 0.0, 0.0, 1.0)
                continue
            if not (np.abs(pos[i]) <= MAX_COORD_M).all():  # NaN fails too
                raise OutOfRangeError(f"tracker {i} position {pos[i]} m", field=f"trackers[{i}]")
            n = math.sqrt(float(quat[i] @ quat[i]))
            if not (math.isfinite(n) and n > 1e-6):
                raise NotNormalisedError(
                    f"tracker {i} orientation {quat[i]}", field=f"trackers[{i}]"
                )
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
        t = now if t is None else float(t)
        if not (0.0 <= t <= MAX_TIME_S and t >= self.last_t):
            raise ValueError(f"frame time {t} s is outside [0, 1e12] or before the last one")
        return Frame(seq, t, pos, quat, valid)

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

    def connected(self) -> None:
        """A new connection: its server may be another process, with another clock."""
        self.clock.reset()

    def receive(self, msg: Message, now: float) -> tuple[Event | None, BaseException | None]:
        """What a server message means: ``(event for the application, end cause)``.

        The end cause is set when the message ends the session: a fatal ``error``
        (its typed exception) or a ``bye``.
        """
        if isinstance(msg, Pose):
            self.stats.poses += 1
            return msg, None
        if isinstance(msg, Pong):
            self.clock.add(msg.t0, msg.t1, msg.t2, now)
            return None, None
        if isinstance(msg, Presence):
            return msg, None
        if isinstance(msg, Welcome):
            self.welcome = msg
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
