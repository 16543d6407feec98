"""Shown poses for tests without an engine (posecast.testing.poses): a rest body made as
the engine thread makes its poses, a v1 message turned back into one, and a pose the
wire cannot carry refused."""

from __future__ import annotations

import numpy as np
import pytest

from posecast.online.protocol import decode
from posecast.online.protocol.messages import Pose
from posecast.skeleton import reference_offsets
from posecast.testing.poses import IDENTITY, REST, of_message, pose_out


def test_the_default_pose_is_the_rest_body_with_identity_rotations() -> None:
    np.testing.assert_allclose(REST[0], reference_offsets()[0])
    np.testing.assert_allclose(np.diff(REST, axis=0), reference_offsets()[1:])
    out = pose_out("p1", seq=5, t=2.5, scale=1.25, reach_limited=True)
    assert (out.player, out.seq, out.t) == ("p1", 5, 2.5)
    assert out.state.scale == 1.25 and out.state.reach_limited
    msg = decode(out.v1())
    assert isinstance(msg, Pose) and (msg.player, msg.seq, msg.t) == ("p1", 5, 2.5)
    np.testing.assert_allclose(msg.positions, REST, atol=0.6e-3)  # the wire's 1 mm
    assert msg.rotations is not None
    np.testing.assert_allclose(msg.rotations, IDENTITY, atol=1e-4)


def test_a_v1_message_becomes_the_pose_it_carries() -> None:
    rot = np.tile([0.0, np.sin(0.2), 0.0, np.cos(0.2)], (19, 1))
    src = pose_out("p2", seq=9, t=1.0, positions=REST + np.array([0.5, 0.0, -1.0]), rotations=rot)
    msg = decode(src.v1())
    assert isinstance(msg, Pose)
    again = of_message(msg, scale=0.9)
    assert again.v1() == src.v1()  # the same quantities: the same bytes
    assert again.state.scale == 0.9


def test_a_pose_beyond_the_wire_is_refused() -> None:
    far = REST.copy()
    far[7, 0] += 40.0  # 40 m from the pelvis: beyond v1's int16 millimetres
    with pytest.raises(ValueError, match="cannot carry p3's pose"):
        pose_out("p3", positions=far)
