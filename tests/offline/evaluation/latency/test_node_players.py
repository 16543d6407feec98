"""The TypeScript client processes of ``posecast bench latency --sdk typescript``
(offline.evaluation.latency.node_players): the walks Python writes for them are the
Python players' walks, their plans keep players.py's roles and phases, what they
return reads back as a :class:`WorkerResult`, and a real Node worker against a real
server streams and displays its room-mates' poses on the host's monotonic clock."""

from __future__ import annotations

import itertools
import random
import time
from pathlib import Path

import numpy as np
import posecast_client as pc
import pytest

from posecast.errors import WorkerError
from posecast.offline.evaluation.latency import node_players as npl
from posecast.offline.evaluation.latency.players import PlayerPlan, WorkerPlan
from posecast.testing.serve import ServeProcess

SECRET = "s" * 32
NODE_MISSING = npl.node_missing()


def test_the_walks_file_holds_each_players_walk_source_frames(tmp_path: Path) -> None:
    players = (PlayerPlan("pa", "r", 0, 3), PlayerPlan("pb", "r", 5, 4))
    path, at = npl.write_walks(players, tmp_path / "w.f64", seconds=10.0)
    data = np.fromfile(path, "<f8").reshape(-1, 29)
    assert at == {"pa": (0, 600), "pb": (600, 600)} and len(data) == 1200
    for p, offset in ((players[0], (0.0, 0.0, 0.0)), (players[1], (1.2, 0.0, 1.2))):
        source = pc.WalkSource(seconds=10.0, seed=p.seed, loop=True, offset_m=offset)
        first, n = at[p.player]
        for k, s in enumerate(itertools.islice(source.samples(), n)):
            row = data[first + k]
            np.testing.assert_array_equal(row[:12].reshape(4, 3), s.positions)
            np.testing.assert_array_equal(row[12:28].reshape(4, 4), s.orientations)
            assert row[28] == s.valid == 15


def test_the_plan_keeps_the_python_players_roles_phases_and_tokens(tmp_path: Path) -> None:
    players = (PlayerPlan("p0", "r0", 0, 0), PlayerPlan("p2", "r0", 2, 2),
               PlayerPlan("p4", "r1", 0, 4))  # fmt: skip
    plan = WorkerPlan("ws://127.0.0.1:1/", SECRET, players, 100.0, 103.0, 113.0)
    frames = {"p0": (0, 900), "p2": (900, 900), "p4": (1800, 900)}
    doc = npl.node_plan(plan, tmp_path / "w.f64", frames)
    assert [p["draws"] for p in doc["players"]] == [True, False, True]  # the first of each room
    for p, row in zip(players, doc["players"], strict=True):
        assert row["start_at"] == 100.0 + random.Random(p.seed).random() / 60.0
        assert (row["first"], row["frames"]) == frames[p.player]
        assert row["token"].count(".") == 2  # a JWT
    assert (doc["measure_from"], doc["stop_at"], doc["tail_s"]) == (103.0, 113.0, 1.5)
    everyone = npl.node_plan(
        WorkerPlan("u", SECRET, players, 0, 1, 2, draw_all=True), Path(), frames
    )
    assert all(p["draws"] for p in everyone["players"])


def test_a_workers_result_reads_back_and_its_clock_is_checked() -> None:
    data = {
        "started_at": 5.0, "captures": {"pa": [[0, 1.5], [1, 1.6]]},
        "displayed": [["pb", 3, 1.2, 1.3, 1.4]], "drawn": 1, "waiting": [["pb", 4, 1.5, 1.55]],
        "jumps_m": [0.01], "members": {"pa": "r"},
        "welcome": {"lookahead_frames": 0, "rate_hz": 60, "version": 2},
        "errors": {"OUT_OF_ORDER": 2}, "failures": [], "display_frames": 9,
        "display_frames_late": 1, "cpu_s": 0.25, "wall_s": 1.0,
    }  # fmt: skip
    r = npl.result_of(data)
    assert r.captures == {"pa": {0: 1.5, 1: 1.6}} and r.displayed == [("pb", 3, 1.2, 1.3, 1.4)]
    assert r.waiting == [("pb", 4, 1.5, 1.55)] and r.errors["OUT_OF_ORDER"] == 2
    assert (r.drawn, r.display_frames, r.display_frames_late, r.cpu_s) == (1, 9, 1, 0.25)
    npl.check_clock(5.0, 4.9, 0)
    for started in (4.8, 40.0):  # before its spawn, or far after: another clock
        with pytest.raises(WorkerError, match="CLOCK_MONOTONIC"):
            npl.check_clock(started, 4.9, 0)


@pytest.mark.skipif(NODE_MISSING is not None, reason=f"TypeScript players: {NODE_MISSING}")
@pytest.mark.timeout(120)
def test_a_node_worker_streams_and_displays_its_room_mates(tmp_path: Path) -> None:
    bundle = npl.build_worker(tmp_path)
    players = (PlayerPlan("pa", "room0", 0, 1), PlayerPlan("pb", "room0", 1, 2))
    walks = npl.write_walks(players, tmp_path / "w.f64", seconds=10.0)
    with ServeProcess(secret=SECRET, samples=4, lookahead=1) as server:
        server.wait_ready()
        start = time.monotonic() + 1.5
        plan = WorkerPlan(server.url, SECRET, players, start, start + 0.5, start + 2.0)
        with npl.node_workers(bundle, [plan], [walks], tmp_path) as results:
            (out,) = results(60.0)
    assert out.failures == [] and not out.errors
    assert out.members == {"pa": "room0", "pb": "room0"}
    assert out.welcome == {"lookahead_frames": 0, "rate_hz": 60, "version": 2}
    for p in ("pa", "pb"):
        assert len(out.captures[p]) > 10  # 2 s of frames at 60 Hz
        assert all(start <= t < start + 2.0 for t in out.captures[p].values())
    senders = {row[0] for row in out.displayed}
    assert senders == {"pa", "pb"}  # each shows the other (a player never shows itself)
    for sender, seq, t, received, shown in out.displayed:
        # One clock: a pose is made after its frame was captured, and shown after it came.
        assert seq in out.captures[sender] and out.captures[sender][seq] < t < received <= shown
    assert 0 < out.drawn < len(out.displayed)  # pa draws (the first of its room); pb does not
    assert all(row[0] == "pb" for row in out.displayed[: out.drawn])
    assert out.jumps_m and out.display_frames > 0 and out.wall_s > 0 and out.cpu_s > 0
