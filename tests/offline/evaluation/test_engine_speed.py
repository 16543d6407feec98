"""``posecast bench engine`` (posecast.offline.evaluation.engine_speed) runs both models, briefly.

The figures themselves come from running the benchmark (docs/engine.md); this only
checks that a tiny run measures what it says it does."""

from __future__ import annotations

import math
from typing import Any

import pytest

from posecast.offline.evaluation import engine_speed
from posecast.offline.evaluation.engine_speed import (
    FRAME_BUDGET_MS,
    BenchResult,
    bench,
    fits_frame,
    max_realtime_players,
    realtime_summary,
    run_side_by_side,
)


def run(player_counts: list[int], backend: str = "native", **kw: Any) -> dict[str, Any]:
    """One backend's report."""
    return run_side_by_side([backend], player_counts, **kw)[0]


def test_a_mixed_run_splits_players_between_the_models() -> None:
    r = bench(4, samples=4, ticks=3, warmup=1, threads=1, hmd3_share=0.5)
    assert (r.players, r.hmd3_players, r.samples) == (4, 2, 4)
    assert 0 < r.tick_p50_ms <= r.tick_p99_ms and math.isfinite(r.gflops)


def test_the_report_has_a_both_models_section_only_when_asked() -> None:
    one = run([2], samples=4, threads=1, ticks=3, naive_players=1, hmd3_share=0.0)
    assert "both_models" not in one and one["players"] == [2]
    two = run([2], samples=4, threads=1, ticks=3, naive_players=1, hmd3_share=0.5)
    both = two["both_models"]
    assert both["hmd3_players"] == [1] and len(both["tick_p99_ms"]) == 1


def test_the_report_names_the_backend_that_ran() -> None:
    r = run([1, 2], samples=2, threads=1, ticks=2, naive_players=1, backend="onnx")
    assert (r["backend"], r["backend_asked"]) == ("onnx", "onnx")
    default = run([1], samples=2, threads=1, ticks=2, naive_players=1)
    assert default["backend_asked"] == "native" and default["backend"] in ("native", "onnx")


def test_mixed_tracker_sets_run_beside_the_single_layout() -> None:
    r = run([3, 6], samples=4, threads=1, ticks=3, naive_players=1, hmd3_share=0.0, sets=True)
    sets = r["mixed_sets"]
    assert sets["sets"] == ["3p", "4p", "6p", "8p", "3p+2i", "3p+4i"]
    assert len(sets["tick_p50_ms"]) == len(sets["p50_ratio"]) == 2
    assert all(t > 0 for t in sets["tick_p50_ms"]) and all(x > 0 for x in sets["p50_ratio"])
    assert "mixed_sets" not in run([2], samples=4, threads=1, ticks=3, naive_players=1)


def test_every_tested_count_fitting_says_the_limit_is_higher() -> None:
    """``--players 1,4`` with both under the budget printed ``4``, as if 4 were the most."""
    assert realtime_summary([1, 4], [3.0, 9.0]) == ">= 4 (every tested count fit)"


def test_no_tested_count_fitting_names_the_smallest() -> None:
    """None fitting printed ``0``: no count was measured at 0."""
    text = realtime_summary([10, 1], [40.0, 20.31])  # unsorted, as --players may be
    assert text == "none of the tested counts fit (the smallest, 1, took p99 20.3 ms)"


def test_the_limit_lies_between_the_largest_fit_and_the_next_count() -> None:
    assert realtime_summary([1, 10, 25, 50], [1.0, 6.0, 15.0, 30.0]) == "25 (50 did not fit)"
    # the budget itself does not fit (p99 < 16.7 ms)
    assert realtime_summary([1, 2], [1.0, FRAME_BUDGET_MS]) == "1 (2 did not fit)"
    # a count below the largest fit that did not: said, not hidden
    noisy = realtime_summary([1, 10, 25, 50], [1.0, 17.0, 15.0, 30.0])
    assert noisy == "25 (50 did not fit); 10 did not fit either, a noisy run"


_JUST_UNDER = math.nextafter(FRAME_BUDGET_MS, 0.0)


@pytest.mark.parametrize(
    ("players", "p99"),
    [
        ([1, 4], [3.0, 9.0]),
        ([1, 2], [_JUST_UNDER, FRAME_BUDGET_MS]),
        ([10, 1], [40.0, 20.31]),
        ([1, 10, 25, 50], [1.0, 17.0, 15.0, 30.0]),
        ([5], [FRAME_BUDGET_MS]),
    ],
)
def test_the_summary_and_the_report_judge_by_one_rule(players: list[int], p99: list[float]) -> None:
    """realtime_summary (c4ca31e) kept its own copy of the fit rule beside
    BenchResult.realtime() and the report's max_realtime_players: one rule, fits_frame,
    now gives all three, so the printed count and the JSON's cannot part."""
    results = [
        BenchResult(p, 4, 0, "onnx", t, t, 1.0, 1.0) for p, t in zip(players, p99, strict=True)
    ]
    fitting = [r.players for r in results if r.realtime()]
    assert fitting == [p for p, t in zip(players, p99, strict=True) if fits_frame(t)]
    best = max_realtime_players(players, p99)
    assert best == max(fitting, default=0)
    assert (
        engine_speed.report("onnx", "onnx", results, [], {}, 4, 1, 0.0)["max_realtime_players"]
        == best
    )
    text = realtime_summary(players, p99)
    assert text.isascii(), text  # printed: stdout may not be UTF-8
    if best:
        assert text.removeprefix(">= ").startswith(f"{best} ("), text
    else:
        assert text.startswith("none of the tested counts fit"), text
