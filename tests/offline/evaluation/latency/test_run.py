"""``posecast bench latency``'s run (offline.evaluation.latency.run): players dealt into
rooms and client processes, and a phase's report from what the client processes and
the server measured (a whole run is ``tests/cli/test_bench_latency.py``'s)."""

from __future__ import annotations

import time
from collections import Counter

import pytest

from posecast.offline.evaluation.latency.players import WorkerResult
from posecast.offline.evaluation.latency.run import (
    START_S,
    LatencyConfig,
    ratio,
    report_of,
    worker_plans,
)


def test_players_are_dealt_into_rooms_in_order_and_over_processes_round_robin() -> None:
    cfg = LatencyConfig(players=5, room_size=2, procs=2, warmup_s=3.0, seconds=10.0)
    before = time.monotonic()
    plans = worker_plans(cfg, "ws://x/", "secret", "p")
    assert [[p.player for p in w.players] for w in plans] == [["p0", "p2", "p4"], ["p1", "p3"]]
    rooms = {p.player: (p.room, p.slot, p.seed) for w in plans for p in w.players}
    assert rooms["p0"] == ("proom0", 0, 0) and rooms["p1"] == ("proom0", 1, 1)
    assert rooms["p3"] == ("proom1", 1, 3) and rooms["p4"] == ("proom2", 0, 4)
    w = plans[0]
    assert all((x.start_at, x.measure_from, x.stop_at) == (w.start_at, w.measure_from, w.stop_at)
               for x in plans)  # fmt: skip
    assert w.start_at >= before + START_S
    assert (w.measure_from - w.start_at, w.stop_at - w.measure_from) == pytest.approx((3.0, 10.0))
    assert len(worker_plans(LatencyConfig(players=1, procs=4), "u", "s", "q")) == 1  # never idle


def test_a_phases_report_counts_what_was_expected_shown_and_missed() -> None:
    """Two players in one room, frames 2..11 of each captured in the window: each
    expects the other's ten poses (20); 18 of them were displayed, one received and
    never shown, one lost (what was captured outside the window counts nowhere)."""
    window = (10.0, 11.0)

    def cap(s: int) -> float:
        return 10.0 + (s - 2) / 60  # frames 0 and 1 before the window

    a, b = WorkerResult(), WorkerResult()
    a.captures = {"pa": {s: cap(s) for s in range(12)}}
    b.captures = {"pb": {s: cap(s) for s in range(12)}}
    a.members, b.members = {"pa": "r"}, {"pb": "r"}
    for res, sender in ((a, "pb"), (b, "pa")):
        res.welcome = {"lookahead_frames": 2, "rate_hz": 60.0, "version": 2}
        res.display_frames, res.display_frames_late, res.cpu_s, res.wall_s = 90, 9, 0.5, 1.0
        res.jumps_m = [0.01, 0.02]
        res.displayed = [(sender, s, cap(s) + 0.01, cap(s) + 0.02, cap(s) + 0.05)
                         for s in [0, *range(2, 11)]]  # fmt: skip
    a.waiting = [("pb", 11, 10.2, 10.21), ("pb", 1, 9.99, 10.0)]  # received, never shown
    a.errors = Counter({"BAD_FIELD": 1})
    m0 = {"posecast_tick_seconds_count": 100.0, "posecast_tick_seconds_sum": 1.0}
    m1 = {"posecast_tick_seconds_count": 160.0, "posecast_tick_seconds_sum": 1.3,
          "posecast_tick_overruns_total": 2.0}  # fmt: skip
    r = report_of([a, b], m0, m1, 0.75, window)
    assert r["poses_expected"] == 20 and r["poses_displayed"] == 18
    assert r["delivery"] == 0.9 and r["poses_received_not_displayed"] == 1
    assert r["capture_to_display_ms_p50"] == pytest.approx(50.0, abs=0.01)
    assert r["components_ms"]["client_buffer"]["mean"] == pytest.approx(30.0, abs=0.01)
    assert r["tick_ms_mean"] == 5.0 and r["tick_overruns"] == 2.0
    assert (r["lookahead_frames"], r["rate_hz"], r["protocol"]) == (2, 60.0, 2)
    assert r["max_joint_jump_cm"] == 2.0 and r["display_frames"] == 180
    assert r["display_frames_late_share"] == 0.1 and r["clients_cpu_cores"] == 1.0
    assert r["server_cpu_cores"] == 0.75 and r["errors"] == {"BAD_FIELD": 1}
    assert r["drawn_capture_to_display_ms"]["poses"] == 0  # no player drew
    a.drawn = len(a.displayed)  # a drew all its 10 rows: the 9 of the window count (not frame 0)
    assert report_of([a, b], m0, m1, 0.75, window)["drawn_capture_to_display_ms"]["poses"] == 9
    assert r["failures"] == []


def test_ratios_against_the_clean_phase() -> None:
    assert ratio(30.0, 20.0) == 1.5
    assert ratio(None, 20.0) is None and ratio(3.0, None) is None and ratio(3.0, 0.0) is None
