"""The in-memory bus backend: one broker object plays Redis's part inside a process.

``posecast serve`` without ``--redis`` gives its bus a broker of its own (one embedded
node); tests hand several hubs one broker to run many nodes in one process.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from posecast.online.cluster.bus import Bus, BusMessage, decode_message, deliver, encode_message
from posecast.online.protocol.pose_out import PoseOut


@dataclass
class MemoryBroker:
    """Redis's role, in process: member lists and per-room subscriptions."""

    members: dict[str, dict[str, tuple[str, str]]] = field(default_factory=dict)
    subscribers: dict[str, list[MemoryBus]] = field(default_factory=dict)
    burned: dict[str, int] = field(default_factory=dict)  # token id -> expiry
    messages: int = 0  # published, for tests


class MemoryBus(Bus):
    """In-process backend. Delivery is synchronous: a publish reaches every other
    subscribed node before it returns (deterministic tests, no event loop needed)."""

    def __init__(
        self, broker: MemoryBroker | None = None, node: str = "local", *, clock: Callable[[], float]
    ) -> None:
        super().__init__(node)
        self.broker = broker or MemoryBroker()
        self.clock = clock

    def watch(self, room: str) -> None:
        self.broker.subscribers.setdefault(room, []).append(self)
        if self.sink is not None:
            now = self.clock()
            live = {p: v for p, v in self.broker.members.get(room, {}).items() if v[0] != self.node}
            self.sink.remote_snapshot(room, live, now, now)
            self.after()

    def unwatch(self, room: str) -> None:
        subs = self.broker.subscribers.get(room, [])
        if self in subs:
            subs.remove(self)

    def joined(self, room: str, player: str, name: str) -> None:
        self.broker.members.setdefault(room, {})[player] = (self.node, name)
        self._send(room, BusMessage("join", self.node, player, name))

    def left(self, room: str, player: str) -> None:
        members = self.broker.members.get(room, {})
        if members.get(player, ("",))[0] == self.node:
            del members[player]
        self._send(room, BusMessage("leave", self.node, player))

    def publish(self, room: str, poses: list[PoseOut], events: list[bytes]) -> None:
        if len(self.broker.subscribers.get(room, ())) > 1:  # someone besides this node
            self._send(
                room, BusMessage("tick", self.node, poses=tuple(poses), events=tuple(events))
            )

    def burned(self, jti: str, exp: int) -> None:
        self.broker.burned[jti] = exp
        for bus in {b for subs in self.broker.subscribers.values() for b in subs} - {self}:
            if bus.sink is not None:
                bus.sink.remote_burn(jti, exp, bus.clock())

    def _send(self, room: str, m: BusMessage) -> None:
        data = encode_message(m)
        self.broker.messages += 1
        for bus in list(self.broker.subscribers.get(room, ())):
            decoded = decode_message(data)
            if bus is not self and bus.sink is not None and decoded is not None:
                deliver(bus.sink, room, decoded, bus.clock())
                bus.after()
