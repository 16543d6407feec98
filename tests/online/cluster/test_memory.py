"""Several hubs on one in-memory broker (posecast.online.cluster.memory), without
sockets: rooms across nodes, one batch per room per tick, takeovers, capacity, burned
tokens. The Redis backend runs the same hub code against a real ``redis-server`` in
``tests/system/scaleout/``."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from posecast.online.cluster.memory import MemoryBroker, MemoryBus
from posecast.online.core.hub import Hub
from posecast.online.metrics import Metrics
from posecast.online.protocol import decode, encode
from posecast.online.protocol.messages import (
    Bye,
    Error,
    Hello,
    Message,
    Pose,
    Presence,
    Welcome,
)
from posecast.online.shell.ticker import TickOutput
from posecast.testing.poses import of_message
from tests.online.conftest import make_cfg, token, walk_frame


class Node:
    """One hub on a shared broker, with a manual clock."""

    def __init__(self, broker: MemoryBroker, name: str, **cfg: Any) -> None:
        self.now = time.time()
        self.bus = MemoryBus(broker, name, clock=lambda: self.now)
        self.hub = Hub(make_cfg(**cfg), Metrics(), bus=self.bus)

    def join(self, player: str, room: str = "r1") -> int:
        conn = self.hub.connect("10.0.0.1", self.now)
        tok = token(room=room, player=player)
        self.hub.receive(conn, encode(Hello(1, tok, room, player.upper())), self.now)
        return conn

    def inbox(self, conn: int) -> list[Message]:
        box = self.hub.outbox(conn)
        assert box is not None
        out = [decode(d) for d in box.take()]
        box.sent(self.now)
        return out

    def tick(self, *players: str, seq: int = 0) -> None:
        self.hub.deliver(TickOutput([of_message(make_pose(p, seq)) for p in players]), self.now)


def make_pose(player: str, seq: int) -> Pose:
    f = walk_frame(seq)
    import numpy as np

    return Pose(player, seq, 1.0, np.zeros((19, 3)), np.tile(f.quat[:1], (19, 1)))


def test_two_nodes_share_a_room_and_other_rooms_see_nothing() -> None:
    broker = MemoryBroker()
    a, b = Node(broker, "A"), Node(broker, "B")
    pa = a.join("pa")
    (welcome,) = a.inbox(pa)
    assert isinstance(welcome, Welcome)
    pb, other = b.join("pb"), b.join("pc", room="r2")
    welcome_b, *rest = b.inbox(pb)  # welcome: this node's view; then pa, from the snapshot
    assert isinstance(welcome_b, Welcome) and rest == [Presence("join", "r1", "pa", "PA")]
    assert a.inbox(pa) == [Presence("join", "r1", "pb", "PB")]  # the bus's join announcement
    b.inbox(other)

    a.tick("pa", seq=1)
    b.tick("pb", "pc", seq=1)
    assert {m.player for m in b.inbox(pb) if isinstance(m, Pose)} == {"pa", "pb"}  # own too
    assert {m.player for m in a.inbox(pa) if isinstance(m, Pose)} == {"pa", "pb"}
    assert all(m.player == "pc" for m in b.inbox(other) if isinstance(m, Pose))
    assert b.hub.metrics.value("posecast_remote_players") == 1

    a.hub.disconnect(pa, a.now)
    assert b.inbox(pb) == [Presence("leave", "r1", "pa", "PA")]
    assert broker.members["r1"] == {"pb": ("B", "PB")}


def test_one_batched_message_per_room_per_tick() -> None:
    broker = MemoryBroker()
    a, b = Node(broker, "A"), Node(broker, "B")
    for p in ("p1", "p2", "p3"):
        a.join(p)
    a.join("q1", room="r2")
    b.join("watcher-of-r1")
    before = broker.messages
    a.tick("p1", "p2", "p3", "q1")
    assert broker.messages - before == 1  # r1 only: nobody else is in r2


def test_the_same_player_joining_another_node_replaces_the_first() -> None:
    broker = MemoryBroker()
    a, b = Node(broker, "A"), Node(broker, "B")
    first, mate = a.join("p"), a.join("mate")
    a.inbox(first)
    a.inbox(mate)
    b.join("p")
    errors = [m for m in a.inbox(first) if isinstance(m, Error)]
    assert [e.code for e in errors] == ["REPLACED"]
    assert a.inbox(mate)[-1] == Presence("join", "r1", "p", "P")  # now it plays on B
    assert broker.members["r1"]["p"] == ("B", "P")


def test_room_capacity_counts_players_on_every_node() -> None:
    broker = MemoryBroker()
    a, b = Node(broker, "A", max_players_per_room=2), Node(broker, "B", max_players_per_room=2)
    a.join("p1")
    b.join("p2")
    late = a.join("p3")
    errors = [m for m in a.inbox(late) if isinstance(m, Error)]
    assert [e.code for e in errors] == ["ROOM_FULL"]


def test_losing_the_bus_announces_remote_players_as_leaving() -> None:
    broker = MemoryBroker()
    a, b = Node(broker, "A"), Node(broker, "B")
    pa = a.join("pa")
    b.join("pb")
    a.inbox(pa)
    a.hub.sink.remote_lost(a.now)
    assert a.inbox(pa) == [Presence("leave", "r1", "pb", "PB")]


def test_a_token_burned_on_one_node_is_refused_on_the_others() -> None:
    broker = MemoryBroker()
    a, b = Node(broker, "A"), Node(broker, "B")
    b.join("someone")  # b's bus is subscribed somewhere, so it hears the burn
    tok = token(room="r1", player="p")
    conn = a.hub.connect("10.0.0.1", a.now)
    a.hub.receive(conn, encode(Hello(1, tok, "r1", "P")), a.now)
    a.hub.receive(conn, encode(Bye("done")), a.now)
    again = b.hub.connect("10.0.0.1", b.now)
    b.hub.receive(again, encode(Hello(1, tok, "r1", "P")), b.now)
    errors = [m for m in b.inbox(again) if isinstance(m, Error)]
    assert [e.code for e in errors] == ["UNAUTHENTICATED"]


def test_a_v2_client_gets_a_remote_players_poses_as_records() -> None:
    """A v2 client on node B: the player on node A is announced with an avatar id and
    skeleton (the snapshot's presence), and its v1 poses from the bus reach the client
    as v2 records, decoded once on B, within the v1 pose's own rounding."""
    from posecast.online.protocol import records
    from posecast.online.protocol.messages import Poses

    broker = MemoryBroker()
    a, b = Node(broker, "A"), Node(broker, "B")
    pa = a.join("pa")
    a.inbox(pa)
    conn = b.hub.connect("10.0.0.1", b.now, 2)
    tok = token(room="r1", player="pv")
    b.hub.receive(conn, encode(Hello(2, tok, "r1", "PV")), b.now)
    box = b.hub.outbox(conn)
    assert box is not None
    got = [decode(d, version=2) for d in box.take(b.now)]
    joins = [m for m in got if isinstance(m, Presence) and m.player == "pa"]
    assert joins and joins[0].avatar_id is not None and joins[0].skeleton is not None
    refs: dict[int, records.Recon | None] = {joins[0].avatar_id: None}
    for seq in range(1, 4):
        a.tick("pa", seq=seq)
        b.tick(seq=seq)  # B's own tick (no local poses): its v2 clients' pose clock
        msgs = [decode(d, version=2) for d in box.take(b.now)]
        poses = [m for m in msgs if isinstance(m, Poses)]
        assert len(poses) == 1, msgs
        (rec,) = records.decode_records(poses[0].data, refs)
        assert rec.recon.seq == seq and rec.keyframe == (seq == 1)
        want = decode(encode(make_pose("pa", seq)))
        assert isinstance(want, Pose) and want.rotations is not None
        world = records.items2world(rec.recon.items)
        assert np.abs(np.abs(np.einsum("ij,ij->i", world, want.rotations)) - 1).max() < 1e-4


def test_a_remote_players_calibration_reaches_v2_clients_as_its_skeleton() -> None:
    """The bus carries each pose's calibration scale: B sends its v2 client the
    skeleton before the records, so FK gives the remote positions."""
    from posecast.online.protocol import records
    from posecast.online.protocol.messages import Poses, Skeleton

    broker = MemoryBroker()
    a, b = Node(broker, "A"), Node(broker, "B")
    a.inbox(a.join("pa"))
    conn = b.hub.connect("10.0.0.1", b.now, 2)
    b.hub.receive(conn, encode(Hello(2, token(room="r1", player="pv"), "r1", "PV")), b.now)
    box = b.hub.outbox(conn)
    assert box is not None
    (join,) = [m for m in map(lambda d: decode(d, version=2), box.take(b.now))
               if isinstance(m, Presence) and m.player == "pa"]  # fmt: skip
    assert join.avatar_id is not None
    refs: dict[int, records.Recon | None] = {join.avatar_id: None}
    bones = records.bytes2skeleton(join.skeleton or b"")
    short = records.skeleton_offsets(1.25)  # a short user: every bone / 1.25
    q = np.tile([0.0, 0.0, 0.0, 1.0], (19, 1))
    pos = np.zeros((19, 3))
    pos[0] = (1.0, 0.8, 2.0)
    for j in range(1, 19):
        pos[j] = pos[records.PARENTS[j]] + short[j - 1]
    a.hub.deliver(TickOutput([of_message(Pose("pa", 5, 1.0, pos, q), scale=1.25)]), a.now)
    msgs = [decode(d, version=2) for d in box.take(b.now)]
    kinds = [m.TYPE for m in msgs]
    assert kinds == ["skeleton", "poses"], kinds  # the skeleton first
    skel = msgs[0]
    assert isinstance(skel, Skeleton) and skel.player == "pa"
    bones = records.bytes2skeleton(skel.skeleton)
    assert np.abs(bones - short).max() < 5e-4
    poses = msgs[1]
    assert isinstance(poses, Poses)
    (rec,) = records.decode_records(poses.data, refs)
    assert np.abs(rec.recon.positions(bones) - pos).max() < 0.002


def test_a_node_forgets_the_avatars_of_a_room_it_stops_watching() -> None:
    """B watches r1 only while a client of its own is there; each time the last one
    leaves, the remote players it knew of there give back their avatar ids (200 rounds of
    a v2 client coming and going beside a player of A held 200 avatar ids before)."""
    broker = MemoryBroker()
    a, b = Node(broker, "A"), Node(broker, "B")
    for i in range(50):
        pa = a.join(f"pa{i}")
        a.inbox(pa)
        conn = b.hub.connect("10.0.0.1", b.now, 2)
        b.hub.receive(conn, encode(Hello(2, token(room="r1", player="pv"), "r1", "PV")), b.now)
        box = b.hub.outbox(conn)
        assert box is not None
        box.take(b.now)
        b.hub.disconnect(conn, b.now)  # B's last client in r1 leaves: B stops watching it
        a.hub.disconnect(pa, a.now)
    assert b.hub.remote.total == 0
    assert len(b.hub.router.avatars) == 0  # every avatar id given back (50 held before)
