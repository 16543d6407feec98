"""One shown pose on its way out (posecast.online.protocol.pose_out): quantised once
in the engine thread, the v1 message and the v2 state from it, the bus row and back."""

from __future__ import annotations

import numpy as np

from posecast.errors import ProtocolError
from posecast.online.protocol import encode
from posecast.online.protocol.messages import Pose
from posecast.online.protocol.pose_out import PoseOut
from posecast.online.protocol.records import PoseState


def test_a_ticks_poses_encode_in_one_pass_as_one_at_a_time(rng: np.random.Generator) -> None:
    """PoseOut.batch (the engine thread's) gives the bytes encode(Pose) writes, float32
    engine output included, the v2 state PoseState.batch gives, and refuses what either
    refuses, pose by pose."""
    e = 10
    pos = (rng.normal(size=(e, 19, 3)) * 0.5 + [0, 1, 0]).astype(np.float32)
    pos += rng.uniform(-900, 900, size=(e, 1, 3)).astype(np.float32)  # anywhere in the world
    q = rng.normal(size=(e, 19, 4))
    rot = (q / np.linalg.norm(q, axis=-1, keepdims=True)).astype(np.float32)
    pos[2, 7, 0] = pos[2, 0, 0] + 32.768  # a joint beyond int16 millimetres
    pos[4, 3, 1] = np.nan
    rot[6, 5] = 2.0  # far from unit length
    pos[8, :, 2] += 1000.0  # the pelvis beyond +-1000 m: v2's root cannot carry it
    players, seqs = [f"p-{i}" for i in range(e)], [2**32 - 1 - i for i in range(e)]
    scales, limited = [1.0 + i / 100 for i in range(e)], [i % 2 == 0 for i in range(e)]
    states = PoseState.batch(players, seqs, 12.25, pos, rot, scales, limited)
    got, refused = PoseOut.batch(states, pos, rot)
    by_player = {p.player: p for p in got}
    kept = []
    for i in range(e):
        one = Pose(players[i], seqs[i], 12.25, pos[i].astype(np.float64), rot[i].astype(np.float64))
        try:
            want: bytes | None = encode(one)
        except ProtocolError:
            want = None
        if want is None or states[i] is None:
            assert players[i] not in by_player, i
            continue
        kept.append(i)
        p, st = by_player[players[i]], states[i]
        assert st is not None and p.v1() == want, i
        assert p.state.root == st.root and p.state.scale == scales[i]
        assert p.state.reach_limited == limited[i]
        assert np.array_equal(p.state.items, st.items)
    assert (
        refused == 4 and len(got) == e - 4 and [p.player for p in got] == [players[i] for i in kept]
    )
    assert 8 not in kept  # encode alone would have taken it (the v1 root is a float)


def test_a_pose_restamped_for_another_clock_encodes_anew() -> None:
    """``at(t)``: a remote pose's time moved onto this node's clock; its v1 bytes and
    v2 encodings are made for that time, not taken from the original's caches."""
    from posecast.testing.poses import pose_out

    p = pose_out("m", 3, 5.0e6)
    first = p.v1()
    p.state.keyframe()
    moved = p.at(42.5)
    assert moved.t == 42.5 and moved.state.t == 42.5 and p.t == 5.0e6
    assert moved.v1() != first and moved.v1() == pose_out("m", 3, 42.5).v1()
    assert moved.state.keyframe()[0] == pose_out("m", 3, 42.5).state.keyframe()[0]
