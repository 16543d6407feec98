"""Protocol v2 pose streams (pure): avatar ids, skeletons, and each client's references.

A v2 client gets one ``poses`` message per tick (more only where the records would
pass 16384 bytes) holding a record per avatar, each a
keyframe or a delta against the last record of that avatar **this client was sent**
(``docs/broadcast.md``, "v2: deltas under latest-wins"). Two objects keep that true:

* :class:`Avatars`, one per node: each player's small integer avatar id (the
  smallest free one, so records name avatars in one LEB128 byte) and its skeleton
  (the bone offsets at the scale the engine last used for it);
* :class:`PoseStream`, one per v2 connection: which avatars this client has been
  told about (an avatar id is announced by ``welcome``, ``presence`` join or
  ``skeleton``, all reliable and sent before any pose in the same batch), its pose
  rate, and per avatar the :class:`~posecast.online.protocol.records.Recon` it holds.

Keyframes come on a schedule shared by every client: each avatar has its keyframe
tick once every 60 ticks (staggered over the avatars by avatar id, on ticks that every
pose rate takes), so clients that joined at different times fall back into step at
the next one and share encodings again; a client's own keyframes (its first, a
``resync``, a delta that does not fit) come on top, and one that missed the shared
tick (a superseded slot) gets its own after 1.1 s at the latest.

The router prepares each record when it puts a pose into the client's latest-wins
slot, against the reference the client has *now*; the reference only moves when the
writer takes the slot (:meth:`PoseStream.message`), and taking consumes the slot, so
a record never meets a reference other than the one it was made against. A slot that
is superseded before the writer took it is replaced by a record against the same,
still current, reference. Clients whose references are the same object (every
client that got the same records) share one encoding: it is cached on the pose.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from posecast.online.protocol.codec import encode
from posecast.online.protocol.messages import (
    MAX_SERVER_MESSAGE_BYTES_V2,
    POSE_RATES_HZ,
    Member,
    Poses,
    Presence,
    Skeleton,
)
from posecast.online.protocol.records import (
    PoseState,
    Recon,
    encode_many,
    skeleton2bytes,
    skeleton_offsets,
    write_leb128,
)

# The most record bytes one poses message carries: a server message's 16384 bytes
# (proto/README.md, Limits) less the map around the bin (type, t, the bin header).
MAX_POSES_DATA_BYTES = MAX_SERVER_MESSAGE_BYTES_V2 - 64
KEYFRAME_EVERY_TICKS = 60  # every avatar's keyframe tick comes once in this many ticks
KEYFRAME_EVERY_S = 1.1  # and no client goes longer than this without one (a safety net)
_TICK_HZ = 60.0


@dataclass
class Avatars:
    """Node-wide: every known player's avatar id and skeleton (local and remote ones)."""

    _avatar_ids: dict[str, int] = field(default_factory=dict)
    _free: list[int] = field(default_factory=list)
    _next: int = 0
    _scale: dict[str, float] = field(default_factory=dict)
    _skeleton: dict[str, bytes] = field(default_factory=dict)
    _default: bytes = field(default_factory=lambda: skeleton2bytes(skeleton_offsets(1.0)))

    def __len__(self) -> int:
        """How many players hold an avatar id now."""
        return len(self._avatar_ids)

    def avatar_id(self, player: str) -> int:
        """``player``'s avatar id, assigned on first use (the smallest free one)."""
        h = self._avatar_ids.get(player)
        if h is None:
            if self._free:
                self._free.sort()
                h = self._free.pop(0)
            else:
                h, self._next = self._next, self._next + 1
            self._avatar_ids[player] = h
        return h

    def release(self, player: str) -> None:
        """``player`` is gone from this node: its avatar id may be given to another."""
        h = self._avatar_ids.pop(player, None)
        if h is not None:
            self._free.append(h)
        self._scale.pop(player, None)
        self._skeleton.pop(player, None)

    def skeleton(self, player: str) -> bytes:
        return self._skeleton.get(player, self._default)

    def scale_of(self, player: str) -> float:
        return self._scale.get(player, 1.0)

    def rescale(self, player: str, scale: float) -> bytes | None:
        """The engine used ``scale`` for ``player``: its new skeleton if that changed it."""
        if self._scale.get(player, 1.0) == scale:
            return None
        self._scale[player] = scale
        self._skeleton[player] = skeleton2bytes(skeleton_offsets(scale))
        return self._skeleton[player]

    def member(self, m: Member) -> Member:
        """``m`` with its v2 fields."""
        return Member(m.player, m.name, self.avatar_id(m.player), self.skeleton(m.player))

    def presence(self, p: Presence) -> Presence:
        """A v2 presence: a join carries the avatar id and the skeleton."""
        if p.event != "join":
            return p
        return Presence(p.event, p.room, p.player, p.name, self.avatar_id(p.player),
                        self.skeleton(p.player))  # fmt: skip

    def skeleton_message(self, player: str) -> Skeleton:
        return Skeleton(player, self.avatar_id(player), self.skeleton(player))

    def keyframe_tick(self, player: str, tick: int) -> bool:
        """Whether ``tick`` is ``player``'s shared keyframe tick: once every 60 ticks,
        at a phase that is a multiple of 12, so every pose rate (each k-th tick, k =
        1, 2, 3, 4) takes it."""
        return tick % KEYFRAME_EVERY_TICKS == (12 * self.avatar_id(player)) % KEYFRAME_EVERY_TICKS


@dataclass
class Slot:
    """What waits in a v2 client's latest-wins slot: the pose and its prepared record."""

    state: PoseState
    body: bytes  # the record after its avatar id
    recon: Recon  # what the client holds once it got the record
    keyframe: bool


@dataclass
class PoseStream:
    """One v2 connection's view: announced avatars, pose rate, references."""

    pose_rate_hz: float = 60.0
    resync: bool = False  # the next poses: keyframes, also of deltas already prepared
    known: dict[str, int] = field(default_factory=dict)  # player -> avatar id announced
    refs: dict[str, Recon] = field(default_factory=dict)  # what the client holds
    last_key: dict[str, float] = field(default_factory=dict)  # when each keyframe went
    records: int = 0
    keyframes: int = 0
    every: int = 1  # ticks between this client's poses: 60 / pose_rate_hz
    ahead: int = 0  # the forecast this client asked for, in ticks (0: none)
    ahead_ms: float = 0.0  # the same in milliseconds: ``ahead`` ticks of the server's

    def set_rate(self, rate_hz: float) -> None:
        assert rate_hz in POSE_RATES_HZ
        self.pose_rate_hz = rate_hz
        self.every = round(_TICK_HZ / rate_hz)

    def set_forecast(self, ms: float, tick_hz: float) -> None:
        """Poses predicted ``ms`` (0-100) ahead from now on, to the nearest whole tick."""
        self.ahead = round(ms * tick_hz / 1000.0)
        self.ahead_ms = self.ahead * 1000.0 / tick_hz

    def request_resync(self) -> None:
        """The client dropped its references: every avatar's next record is a keyframe,
        in the next poses for those posing now and whenever a paused one resumes."""
        self.resync = True
        self.refs.clear()

    def accepts(self, tick: int) -> bool:
        """Whether tick number ``tick`` is one of this client's (every k-th tick)."""
        return tick % self.every == 0

    def announce(self, player: str, avatar_id: int) -> None:
        if self.known.get(player) != avatar_id:
            self.refs.pop(player, None)  # a new avatar on this avatar id: keyframe first
        self.known[player] = avatar_id

    def forget(self, player: str) -> None:
        self.known.pop(player, None)
        self.refs.pop(player, None)
        self.last_key.pop(player, None)

    def needs_keyframe(self, player: str, now: float) -> bool:
        ref = self.refs.get(player)
        return (
            ref is None or self.resync or now - self.last_key.get(player, -1e18) >= KEYFRAME_EVERY_S
        )

    def messages(self, slots: list[tuple[str, Slot]], now: float) -> list[bytes]:
        """The ``poses`` messages of what the writer took (one per tick the records are
        from, oldest first: a record has no time of its own, so a slot that waited
        since an earlier tick must not go out under a later tick's ``t``; and more
        where the records overflow a message's 16384 bytes, cut between records, all
        with their tick's time); the references move on."""
        parts: list[tuple[float, bytes]] = []
        for player, slot in slots:
            avatar_id = self.known.get(player)
            if avatar_id is None:
                continue  # left (or its avatar id moved) since the pose was queued
            body, recon, key = slot.body, slot.recon, slot.keyframe
            if self.resync and not key:
                (body, recon), key = slot.state.keyframe(), True
            parts.append((slot.state.t, write_leb128(avatar_id) + body))
            self.refs[player] = recon
            if key:
                self.last_key[player] = now
                self.keyframes += 1
            self.records += 1
        self.resync = False
        out: list[bytes] = []
        batch: list[bytes] = []
        size = 0
        t = 0.0
        for part_t, part in sorted(parts, key=lambda p: p[0]):  # stable within a tick
            if batch and (part_t != t or size + len(part) > MAX_POSES_DATA_BYTES):
                out.append(encode(Poses(t, b"".join(batch))))
                batch, size = [], 0
            batch.append(part)
            size += len(part)
            t = part_t
        if batch:
            out.append(encode(Poses(t, b"".join(batch))))
        return out


def prepare(
    requests: list[tuple[PoseStream, PoseState]], now: float, keyed: frozenset[str] = frozenset()
) -> list[Slot | None]:
    """Each client's record of each pose, against that client's current reference:
    keyframes where due (``keyed``: the players whose shared keyframe tick this is),
    every delta of the tick in one batched encoding, once per distinct (pose,
    reference) pair, and one :class:`Slot` per pair shared by the clients that have
    it; ``None`` for an avatar the client was not told about."""
    out: list[Slot | None] = [None] * len(requests)
    keyframes: dict[int, Slot] = {}  # id(state) -> its keyframe slot
    groups: dict[tuple[int, int], list[int]] = {}  # (id(state), id(ref)) -> requests
    pairs: list[tuple[PoseState, Recon]] = []
    for i, (stream, state) in enumerate(requests):
        player = state.player
        if player not in stream.known:
            continue
        ref = stream.refs.get(player)
        if (
            ref is None
            or player in keyed
            or stream.resync
            or now - stream.last_key.get(player, -1e18) >= KEYFRAME_EVERY_S
        ):
            slot = keyframes.get(id(state))
            if slot is None:
                body, recon = state.keyframe()
                slot = keyframes[id(state)] = Slot(state, body, recon, True)
            out[i] = slot
            continue
        key = (id(state), id(ref))
        group = groups.get(key)
        if group is None:
            groups[key] = [i]
            pairs.append((state, ref))
        else:
            group.append(i)
    for (state, _), got, members in zip(pairs, encode_many(pairs), groups.values(), strict=True):
        if got is None:  # does not fit a delta
            slot = keyframes.get(id(state))
            if slot is None:
                body, recon = state.keyframe()
                slot = keyframes[id(state)] = Slot(state, body, recon, True)
        else:
            slot = Slot(state, got[0], got[1], False)
        for i in members:
            out[i] = slot
    return out
