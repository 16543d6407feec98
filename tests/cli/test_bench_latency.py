"""``posecast bench latency`` (posecast.cli.bench_latency): a real ``posecast serve``,
SDK players in client processes (Python, or the TypeScript SDK in Node), the clean and
the lossy phase. The figures are not checked against any bound (timing is the
benchmark's to report, not a unit test's): the report's structure, and that each
phase's components add up to its total."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from posecast.cli import main
from posecast.offline.evaluation.latency import node_players
from posecast.offline.evaluation.latency.budget import COMPONENTS
from tests.cli.conftest import user_error

NODE_MISSING = node_players.node_missing()


@pytest.mark.parametrize(
    "extra",
    [
        ["--players", "1"],
        ["--room-size", "1"],
        ["--seconds", "0"],
        ["--display-hz", "nan"],
        ["--procs", "0"],
        ["--samples", "0"],
        ["--frame-queue", "0"],
        ["--lookahead", "-1"],
        ["--lookahead", "256"],
        ["--drop", "1"],
        ["--jitter-ms", "-5"],
        ["--down-jitter-ms", "inf"],
        ["--json", "/no/such/dir/latency.json"],
        ["--sdk", "csharp"],
    ],
)
def test_bench_latency_user_error(capsys, extra: list[str]) -> None:
    user_error(capsys, main(["bench", "latency", *extra]), "CONFIG_INVALID")


def test_bench_latency_typescript_without_node_modules_says_npm_ci(
    capsys, monkeypatch, tmp_path: Path
) -> None:
    (tmp_path / "bench").mkdir()
    (tmp_path / "bench" / "latency-worker.ts").touch()  # a checkout, never installed
    monkeypatch.setattr(node_players, "TS_SDK", tmp_path)
    err = user_error(capsys, main(["bench", "latency", "--sdk", "typescript"]), "CONFIG_INVALID")
    assert "node_modules" in err and "hint: cd client_sdk/typescript && npm ci" in err


def test_bench_latency_typescript_without_node(capsys, monkeypatch) -> None:
    monkeypatch.setattr(node_players.shutil, "which", lambda name: None)
    err = user_error(capsys, main(["bench", "latency", "--sdk", "typescript"]), "CONFIG_INVALID")
    assert "no `node`" in err


def _check_phase(phase: dict[str, Any]) -> None:
    assert phase["protocol"] == 2
    assert phase["failures"] == []
    assert 0 < phase["poses_displayed"] <= phase["poses_expected"]
    parts = phase["components_ms"]
    assert set(parts) == set(COMPONENTS)
    for stats in parts.values():
        assert stats["p50"] <= stats["p99"] <= stats["max"]
    assert phase["capture_to_display_ms_p50"] <= phase["capture_to_display_ms_p99"]
    look = phase["lookahead_frames"] / phase["rate_hz"] * 1000.0
    assert parts["lookahead"]["p50"] == parts["lookahead"]["p99"] == pytest.approx(look, abs=0.01)
    # Every pose's parts add up to its total, so do the means (each rounded to 0.01 ms).
    total = sum(stats["mean"] for stats in parts.values())
    assert total == pytest.approx(phase["capture_to_display_ms_mean"], abs=0.05)
    assert parts["client_buffer"]["p50"] >= 0.0  # displayed after it arrived
    assert phase["display_frames"] > 0
    assert 0.0 <= phase["queue_held_share"] <= 1.0
    drawn = phase["drawn_capture_to_display_ms"]  # the drawing players' poses, a part
    assert 0 < drawn["poses"] <= phase["poses_displayed"]
    # Jumps are read on the window's display frames: on a machine so busy that no pose
    # reached a screen before the window closed (all shown in the tail), there are none.
    jump = phase["max_joint_jump_cm"]
    assert jump is None or 0.0 <= phase["p99_joint_jump_cm"] <= jump


@pytest.mark.timeout(180)
@pytest.mark.parametrize(
    "sdk",
    [
        "python",
        pytest.param(
            "typescript",
            marks=pytest.mark.skipif(
                NODE_MISSING is not None, reason=f"TypeScript players: {NODE_MISSING}"
            ),
        ),
    ],
)
def test_bench_latency_reports_the_budget_clean_and_lossy(capsys, tmp_path: Path, sdk: str) -> None:
    out = tmp_path / "latency.json"
    argv = ["bench", "latency", "--players", "3", "--room-size", "3", "--seconds", "2"]
    argv += ["--warmup", "1", "--samples", "8", "--lookahead", "3", "--delayed-emission", "--lossy"]
    argv += ["--down-jitter-ms", "20", "--sdk", sdk]
    assert main([*argv, "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "capture to display" in printed and "client buffer" in printed
    report = json.loads(out.read_text())
    assert report["config"]["players"] == 3 and report["lookahead_frames"] == 3
    assert report["config"]["sdk"] == sdk
    _check_phase(report)
    lossy = report["lossy"]
    _check_phase(lossy)
    assert lossy["relay"]["frames_dropped"] > 0  # the relay did lose frames
    assert lossy["relay"]["frames_in"] > lossy["relay"]["frames_dropped"]
    assert lossy["p99_vs_clean"] > 0 and lossy["max_joint_jump_vs_clean"] > 0
