"""The pure client session: frame checks, seq and time rules, what server messages mean."""

from __future__ import annotations

import random

import numpy as np
import pytest

from posecast_client.errors import (
    ConnectionLostError,
    DuplicateError,
    KickedError,
    NotNormalisedError,
    OutOfOrderError,
    OutOfRangeError,
    ServerShutdownError,
)
from posecast_client.protocol import Bye, Error, Pong, Pose, Presence
from posecast_client.session import ClientSession, backoff_delay, is_retryable

POS = np.array([[0.0, 1.6, 0.0], [0.3, 1.0, 0.1], [-0.3, 1.0, 0.1], [0.0, 1.0, 0.0]])
QUAT = np.tile([0.0, 0.0, 0.0, 1.0], (4, 1))


def test_seq_counts_from_seq0_and_continues_across_dropped_frames() -> None:
    s = ClientSession(seq0=2**32 - 2)
    f = s.frame(POS, QUAT, now=1.0)
    s.sent(f, 1.0)
    g = s.frame(POS, QUAT, now=1.1)
    s.dropped(g)  # no connection: the seq is used up all the same
    h = s.frame(POS, QUAT, now=1.2)
    assert (f.seq, g.seq, h.seq) == (2**32 - 2, 2**32 - 1, 0)
    assert (s.stats.frames_sent, s.stats.frames_dropped) == (1, 1)
    assert s.sent_at(f.seq) == 1.0 and s.sent_at(g.seq) is None


def test_explicit_seq_must_be_newer() -> None:
    s = ClientSession()
    s.sent(s.frame(POS, QUAT, now=1.0, seq=10), 1.0)
    with pytest.raises(DuplicateError):
        s.frame(POS, QUAT, now=1.1, seq=10)
    with pytest.raises(OutOfOrderError):
        s.frame(POS, QUAT, now=1.1, seq=9)
    assert s.frame(POS, QUAT, now=1.1, seq=15).seq == 15  # gaps are fine
    with pytest.raises(ValueError):
        s.frame(POS, QUAT, now=1.1, seq=-1)


def test_time_must_not_go_backwards() -> None:
    s = ClientSession()
    s.sent(s.frame(POS, QUAT, now=5.0), 5.0)
    with pytest.raises(ValueError):
        s.frame(POS, QUAT, now=6.0, t=4.0)


def test_a_frame_without_time_after_one_stamped_ahead_takes_that_time() -> None:
    # A stamp ahead of the clock (a WebXR frame's predicted display time) must not get
    # the next unstamped frame refused as going back: it takes the last frame's time.
    s = ClientSession()
    s.sent(s.frame(POS, QUAT, now=5.0, t=5.02), 5.0)
    assert s.frame(POS, QUAT, now=5.01).t == 5.02
    assert s.frame(POS, QUAT, now=5.03).t == 5.03


def test_tracked_slots_are_checked_and_normalised_untracked_ones_ignored() -> None:
    s = ClientSession()
    quat = QUAT * 3.0
    pos = POS.copy()
    pos[3] = np.nan  # the waist is lost
    f = s.frame(pos, quat, now=1.0, valid=0b0111)
    np.testing.assert_allclose(np.linalg.norm(f.orientations, axis=1), 1.0)
    assert f.positions[3].tolist() == [0.0, 0.0, 0.0]
    with pytest.raises(OutOfRangeError) as info:
        s.frame(pos, QUAT, now=1.0)
    assert info.value.field == "trackers[3]"
    with pytest.raises(NotNormalisedError):
        s.frame(POS, np.zeros((4, 4)), now=1.0)
    with pytest.raises(ValueError):
        s.frame(POS[:3], QUAT, now=1.0)
    with pytest.raises(ValueError):
        s.frame(POS, QUAT, now=1.0, valid=16)


def test_what_server_messages_mean() -> None:
    s = ClientSession()
    pose = Pose("p", 1, 1.0, np.zeros((19, 3)))
    assert s.receive(pose, 1.0) == (pose, None) and s.stats.poses == 1
    presence = Presence("join", "r", "p", "P")
    assert s.receive(presence, 1.0) == (presence, None)
    soft = Error("RATE_LIMITED", "slow down", False)
    assert s.receive(soft, 1.0) == (soft, None)
    event, end = s.receive(Error("KICKED", "out", True), 1.0)
    assert event is None and isinstance(end, KickedError) and not is_retryable(end)
    _, end = s.receive(Bye("SERVER_SHUTDOWN"), 1.0)
    assert isinstance(end, ServerShutdownError) and is_retryable(end)
    _, end = s.receive(Bye(), 1.0)
    assert isinstance(end, ConnectionLostError) and is_retryable(end)
    assert s.receive(Pong(1.0, 11.0, 11.0), 1.002) == (None, None)
    assert s.clock.offset_s == pytest.approx(9.999)


def test_a_skeleton_announces_its_avatar_id_and_keeps_the_same_players_reference() -> None:
    import json
    from pathlib import Path

    from posecast_client.codec import decode
    from posecast_client.protocol import Poses, Skeleton

    cases = json.loads((Path(__file__).parents[3] / "proto/vectors/poses.json").read_text())
    c = next(c for c in cases if c.get("name") == "poses_stream_two_avatars")
    s = ClientSession()
    s.connected(2)
    # No presence for these avatars reached this client: their skeletons announce them.
    for a in c["avatars"]:
        s.receive(Skeleton(a["player"], a["handle"], bytes.fromhex(a["skeleton"]["$bin"])), 0.0)
    first, second = (decode(bytes.fromhex(h), version=2) for h in c["messages"][:2])
    assert isinstance(first, Poses) and isinstance(second, Poses)
    keyed, _ = s.receive_all(first, 0.0)
    assert {p.player for p in keyed} == {a["player"] for a in c["avatars"]}
    assert s.stats.bad_records == 0
    # A calibration of the same player later: its reference stays, deltas go on.
    a = c["avatars"][0]
    s.receive(Skeleton(a["player"], a["handle"], bytes.fromhex(a["skeleton"]["$bin"])), 0.5)
    deltas, _ = s.receive_all(second, 0.5)
    assert deltas and s.stats.bad_records == 0 and not s.want_resync


def test_backoff_doubles_with_jitter_up_to_the_cap() -> None:
    rng = random.Random(1)
    for attempt in range(1, 12):
        nominal = min(8.0, 0.25 * 2 ** (attempt - 1))
        d = backoff_delay(attempt, 0.25, 8.0, rng)
        assert nominal / 2 <= d <= nominal
    assert is_retryable(OSError()) and is_retryable(TimeoutError())
    assert not is_retryable(ValueError())


def test_a_bad_record_drops_every_reference_and_asks_for_a_resync_now_and_then() -> None:
    """The records a bad one made the client skip moved the server's references on: a
    later delta is refused until keyframes come, never decoded into a wrong pose."""
    import json
    from pathlib import Path

    from posecast_client.codec import decode
    from posecast_client.protocol import Poses

    cases = json.loads((Path(__file__).parents[3] / "proto/vectors/poses.json").read_text())
    c = next(c for c in cases if c.get("name") == "poses_stream_two_avatars")
    s = ClientSession()
    s.connected(2)
    for a in c["avatars"]:
        s.avatars.announce(a["player"], a["handle"], bytes.fromhex(a["skeleton"]["$bin"]))
    msgs = [decode(bytes.fromhex(h), version=2) for h in c["messages"]]
    assert all(isinstance(m, Poses) for m in msgs)
    first, second = msgs[0], msgs[1]
    assert isinstance(first, Poses) and isinstance(second, Poses)
    good, _ = s.receive_all(first, 0.0)
    assert len(good) >= 2 and not s.want_resync
    bad, _ = s.receive_all(Poses(first.t, first.data + b"\x7f\x01"), 1.0)  # avatar id 127
    assert bad == [] and s.want_resync and s.stats.bad_records == 1
    s.want_resync = False  # the client sent it
    refused, _ = s.receive_all(second, 1.1)  # deltas: no reference to apply them to
    assert refused == [] and s.stats.bad_records == 2
    assert not s.want_resync  # 0.1 s after the last request
    s.receive_all(second, 1.3)
    assert s.want_resync
    keyed, _ = s.receive_all(first, 1.4)  # the resync's keyframes
    assert [p.seq for p in keyed] == [p.seq for p in good]
