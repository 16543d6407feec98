"""One client process of ``posecast bench latency`` (offline.evaluation.latency.players):
its players join a real server, stream their walks, and each displays its room-mates'
poses, never its own; what it returns is plain, picklable data."""

from __future__ import annotations

import pickle
import time

import pytest

from posecast.offline.evaluation.latency.players import PlayerPlan, WorkerPlan, run_worker
from posecast.testing.serve import ServeProcess

SECRET = "s" * 32


@pytest.mark.timeout(120)
def test_a_worker_streams_and_displays_its_room_mates() -> None:
    with ServeProcess(secret=SECRET, samples=4, lookahead=1) as server:
        server.wait_ready()
        players = (PlayerPlan("pa", "room0", 0, 1), PlayerPlan("pb", "room0", 1, 2))
        start = time.monotonic() + 1.5
        plan = WorkerPlan(server.url, SECRET, players, start, start + 0.5, start + 2.0)
        out = run_worker(plan)
    assert out.failures == [] and not out.errors
    assert out.members == {"pa": "room0", "pb": "room0"}
    assert out.welcome["version"] == 2  # posecast.v2, the SDK's newest
    assert out.welcome["lookahead_frames"] == 0  # no delayed emission: no delay
    for p in ("pa", "pb"):
        assert len(out.captures[p]) > 10  # 2 s of frames at 60 Hz
        assert all(start <= t < start + 2.0 for t in out.captures[p].values())
    senders = {row[0] for row in out.displayed}
    assert senders == {"pa", "pb"}  # each shows the other (a player never shows itself)
    for sender, seq, _, received, shown in out.displayed:
        assert seq in out.captures[sender] and shown >= received
    assert out.display_frames > 0 and out.wall_s > 0
    assert pickle.loads(pickle.dumps(out)).displayed == out.displayed
