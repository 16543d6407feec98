"""Routing (posecast.online.core.routing): poses and presence to the room's audience."""

from __future__ import annotations

from posecast.online.core.tick import TickOutput
from posecast.testing.poses import pose_out
from tests.online.core.harness import Harness


def test_poses_reach_the_room_audience_only() -> None:
    h = Harness()
    a, b, c = h.join("a"), h.join("b"), h.join("c", room="r2")
    spec = h.join("s", role="spectator")
    for conn in (a, b, c, spec):
        h.inbox(conn)
    h.hub.deliver(TickOutput([pose_out("a", 1), pose_out("c", 1)]), h.now)
    a2, c2 = pose_out("a", 2), pose_out("c", 2)
    h.hub.deliver(TickOutput([a2, c2]), h.now)  # nobody read
    raw = {conn: h.hub.outbox(conn).take() for conn in (a, b, c, spec)}  # type: ignore[union-attr]
    assert raw == {a: [a2.v1()], b: [a2.v1()], c: [c2.v1()], spec: [a2.v1()]}
    assert h.hub.metrics.value("posecast_poses_superseded_total") == 4


def test_reach_limited_poses_are_counted() -> None:
    h = Harness()
    h.inbox(h.join("a"))
    h.hub.deliver(TickOutput([pose_out("a", 1, reach_limited=True)], reach_limited=1), h.now)
    h.hub.deliver(TickOutput([pose_out("a", 2)]), h.now)
    assert h.hub.metrics.value("posecast_reach_limited_total") == 1
