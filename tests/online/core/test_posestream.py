"""v2 pose streams without sockets: records prepared against each client's own
reference stay decodable under latest-wins superseding, keyframes come when due, and
one encoding serves every client that shares a reference."""

from __future__ import annotations

import numpy as np

from posecast.geometry.rotations import quat_conj, quat_mul
from posecast.online.core.outbox import Outbox
from posecast.online.core.posestream import KEYFRAME_EVERY_S, Avatars, PoseStream, prepare
from posecast.online.protocol import decode, records
from posecast.online.protocol.messages import Poses
from posecast.online.protocol.records import PoseState


def _walk(n: int, seed: int = 0, player: str = "a") -> list[PoseState]:
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(19, 3))
    out = []
    for k in range(n):
        items = records.rotvec2quat(axes * 0.3 * np.sin(k / 9.0 + np.arange(19))[:, None])
        pos = np.zeros((19, 3))
        pos[0] = (0.02 * k, 0.95, 0.0)
        out.append(PoseState.from_engine(player, k, k / 60, pos, records.items2world(items)))
    return out


class Client:
    """A v2 client's side: decodes what the writer sends, against its own references."""

    def __init__(self) -> None:
        self.refs: dict[int, records.Recon | None] = {0: None}
        self.got: list[records.Record] = []

    def read(self, box: Outbox, now: float) -> None:
        for data in box.take(now):
            msg = decode(data, version=2)
            assert isinstance(msg, Poses)
            self.got += records.decode_records(msg.data, self.refs)


def _put(boxes: list[Outbox], state: PoseState, now: float) -> None:
    streams = [b.stream for b in boxes]
    slots = prepare([(s, state) for s in streams if s is not None], now)
    for box, slot in zip(boxes, slots, strict=True):
        assert slot is not None
        box.put_pose(state.player, slot, now)


def test_superseded_records_stay_decodable_and_close() -> None:
    fast, slow = Outbox(8, PoseStream()), Outbox(8, PoseStream())
    for box in (fast, slow):
        assert box.stream is not None
        box.stream.announce("a", 0)
    cf, cs = Client(), Client()
    poses = _walk(90)
    for k, state in enumerate(poses):
        now = k / 60
        _put([fast, slow], state, now)
        cf.read(fast, now)
        if k % 7 == 0:  # the slow one reads every 7th tick: the rest is superseded
            cs.read(slow, now)
    assert [r.recon.seq for r in cf.got] == list(range(90))
    assert len(cs.got) == 13 and not all(r.keyframe for r in cs.got)
    for client in (cf, cs):
        for rec in client.got:
            truth = poses[rec.recon.seq]
            world = records.items2world(rec.recon.items)
            err = records.quat2rotvec(quat_mul(quat_conj(world), truth.world))
            assert np.degrees(np.linalg.norm(err, axis=-1)).max() < 0.11
            assert rec.recon.root == truth.root
    keys = [r.recon.seq for r in cf.got if r.keyframe]
    assert keys == [0, round(KEYFRAME_EVERY_S * 60)]  # the first, then one a second


def test_clients_in_step_share_one_encoding_and_resync_gives_keyframes() -> None:
    boxes = [Outbox(8, PoseStream()) for _ in range(3)]
    for box in boxes:
        assert box.stream is not None
        box.stream.announce("a", 0)
    clients = [Client() for _ in boxes]
    poses = _walk(6)
    for k, state in enumerate(poses):
        _put(boxes, state, k / 60)
        if k == 3:
            assert boxes[1].stream is not None
            boxes[1].stream.request_resync()
        sent = [b.take(k / 60) for b in boxes]
        for c, data in zip(clients, sent, strict=True):
            msg = decode(data[0], version=2)
            assert isinstance(msg, Poses)
            c.got += records.decode_records(msg.data, c.refs)
        if k < 3:
            assert sent[0] == sent[1] == sent[2]  # one shared encoding, the same bytes
        assert len(state._deltas) <= (1 if k <= 3 else 2)  # once per distinct reference
    assert [r.keyframe for r in clients[0].got] == [True] + [False] * 5
    assert [r.keyframe for r in clients[1].got] == [True, False, False, True, False, False]


def test_after_a_resync_a_paused_avatar_resumes_with_a_keyframe() -> None:
    """The client dropped every reference: an avatar with no pose in the next tick
    (its frames paused) must not resume with a delta the client cannot apply."""
    box = Outbox(8, PoseStream())
    assert box.stream is not None
    box.stream.announce("a", 0)
    box.stream.announce("b", 1)
    a, b = _walk(8), _walk(8, seed=1, player="b")
    client = Client()
    client.refs[1] = None
    for k in range(3):
        _put([box], a[k], k / 60)
        _put([box], b[k], k / 60)
        client.read(box, k / 60)
    box.stream.request_resync()
    client.refs = {0: None, 1: None}  # what a client that asked for it holds
    for k in range(3, 8):
        _put([box], a[k], k / 60)
        if k >= 6:  # b was paused for three ticks
            _put([box], b[k], k / 60)
        client.read(box, k / 60)
    got = [(r.avatar_id, r.keyframe) for r in client.got[6:]]
    assert got == [(0, True), (0, False), (0, False), (0, False), (1, True), (0, False),
                   (1, False)]  # fmt: skip


def test_pose_rate_takes_every_kth_tick_and_unknown_avatars_wait() -> None:
    s = PoseStream()
    s.set_rate(20.0)
    assert [t for t in range(12) if s.accepts(t)] == [0, 3, 6, 9]
    state = _walk(1)[0]
    assert prepare([(s, state)], 0.0) == [None]  # not announced: nothing for it yet
    avatars = Avatars()
    assert [avatars.avatar_id(p) for p in ("a", "b", "c")] == [0, 1, 2]
    avatars.release("b")
    assert avatars.avatar_id("d") == 1  # the smallest free avatar id
    assert avatars.rescale("a", 1.0) is None
    tall = avatars.rescale("a", 0.8)
    assert tall is not None and avatars.skeleton("a") == tall
    assert np.allclose(records.bytes2skeleton(tall), records.skeleton_offsets(0.8), atol=1e-4)


def test_clients_that_joined_apart_fall_into_step_at_the_shared_keyframe_tick() -> None:
    avatars = Avatars()
    early, late = Outbox(8, PoseStream()), Outbox(8, PoseStream())
    assert early.stream is not None and late.stream is not None
    early.stream.announce("a", avatars.avatar_id("a"))
    poses = _walk(130)
    for tick, state in enumerate(poses, start=1):
        if tick == 11:
            late.stream.announce("a", avatars.avatar_id("a"))  # joins 10 ticks later
        now = tick / 60
        keyed = frozenset({"a"}) if avatars.keyframe_tick("a", tick) else frozenset()
        streams = [b.stream for b in (early, late) if b.stream and "a" in b.stream.known]
        slots = prepare([(s, state) for s in streams], now, keyed)
        for box, slot in zip((early, late), slots, strict=False):
            assert slot is not None
            box.put_pose("a", slot, now)
        for box in (early, late):
            box.take(now)
        if 11 <= tick < 60:
            assert early.stream.refs["a"] is not late.stream.refs["a"]  # apart: two encodings
        if tick >= 60:
            assert early.stream.refs["a"] is late.stream.refs["a"]  # one shared keyframe on
    assert early.stream.keyframes == 3 and late.stream.keyframes == 3  # 1 (or 11), 60, 120


def test_records_past_one_message_go_out_in_several_within_the_limit() -> None:
    """A backend watching 160 avatars gets their first (keyframe) records in more than
    one ``poses`` message, each within a server message's 16384 bytes (one message of
    21 kB before, which the client's own decoder refused), cut between records: every
    avatar's record arrives, and decodes."""
    from posecast.online.protocol.messages import MAX_SERVER_MESSAGE_BYTES_V2

    box = Outbox(8, PoseStream())
    stream = box.stream
    assert stream is not None
    client = Client()
    rng = np.random.default_rng(1)
    for avatar_id in range(160):
        stream.announce(f"p{avatar_id}", avatar_id)
        client.refs[avatar_id] = None
    for seq in (1, 2):
        for avatar_id in range(160):
            items = records.rotvec2quat(rng.normal(size=(19, 3)) * 0.5)
            pos = np.zeros((19, 3))
            pos[0] = (0.1 * avatar_id, 0.95, 0.0)
            world = records.items2world(items)
            state = PoseState.from_engine(f"p{avatar_id}", seq, seq / 60, pos, world)
            (slot,) = prepare([(stream, state)], seq / 60)
            assert slot is not None
            box.put_pose(state.player, slot, seq / 60)
        if seq == 1:
            data = box.take(seq / 60)
            box.sent(seq / 60)
            assert len(data) >= 2, [len(d) for d in data]
            assert max(len(d) for d in data) <= MAX_SERVER_MESSAGE_BYTES_V2
            for d in data:
                msg = decode(d, version=2)
                assert isinstance(msg, Poses)
                client.got += records.decode_records(msg.data, client.refs)
        else:
            client.read(box, seq / 60)
    assert [r.recon.seq for r in client.got] == [1] * 160 + [2] * 160


def test_a_record_that_waited_since_an_earlier_tick_keeps_that_ticks_time() -> None:
    """A client one tick behind: avatar a has no pose at tick 1, b has; a's record from
    tick 0 goes out in a message with tick 0's t, not under tick 1's (records have no
    time of their own, and an interpolating client would show a's pose 16.7 ms late)."""
    box = Outbox(8, PoseStream())
    assert box.stream is not None
    box.stream.announce("a", 0)
    box.stream.announce("b", 1)
    refs: dict[int, records.Recon | None] = {0: None, 1: None}
    a, b = _walk(1, player="a"), _walk(2, seed=1, player="b")
    _put([box], a[0], 0.0)
    _put([box], b[0], 0.0)
    _put([box], b[1], 1 / 60)  # the writer was still busy: b's slot is superseded, a's waits
    got = []
    for data in box.take(1 / 60):
        msg = decode(data, version=2)
        assert isinstance(msg, Poses)
        got += [(msg.t, r.avatar_id, r.recon.seq) for r in records.decode_records(msg.data, refs)]
    assert got == [(0.0, 0, 0), (1 / 60, 1, 1)]
