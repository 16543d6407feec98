"""``posecast bench engine`` (posecast.cli.bench)."""

from __future__ import annotations

import sys

import pytest

from posecast.cli import main
from tests.cli.conftest import user_error


@pytest.mark.parametrize(
    "extra",
    [
        ["--players", "1,x"],
        ["--players", "0"],
        ["--samples", "0"],
        ["--samples", "100000000"],  # was a MemoryError traceback
        ["--ticks", "0"],
        ["--hmd3-share", "1.5"],
        ["--backend", "cuda"],
        ["--backend", "onnx,onnx"],
        ["--backend", "native,"],
        ["--json", "/no/such/dir/bench.json"],
        ["--threads", "65"],  # the engine's pool takes 1 to 64
    ],
)
def test_bench_engine_user_error(capsys, extra: list[str]) -> None:
    user_error(capsys, main(["bench", "engine", *extra]), "CONFIG_INVALID")


def test_bench_engine_runs_each_backend_asked_for(capsys) -> None:
    pytest.importorskip("torch")
    argv = ["bench", "engine", "--players", "1", "--samples", "2", "--ticks", "2"]
    argv += ["--naive-players", "1", "--hmd3-share", "0", "--threads", "1"]
    assert main([*argv, "--backend", "onnx,torch"]) == 0
    headers = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("backend ")]
    assert headers == ["backend onnx", "backend torch"]


def _bench_report(p99: list[float]) -> dict[str, object]:
    """A ``bench engine`` report for players 1 and 4 with these p99 ticks (no engine)."""
    n = len(p99)
    section = {"backend": "onnx", "tick_p50_ms": p99, "tick_p99_ms": p99}
    return {
        "backend": "onnx", "backend_asked": "onnx", "native_isa": None, "players": [1, 4],
        "samples": 100, "tick_p50_ms": p99, "tick_p99_ms": p99, "gflops": [1.0] * n,
        "rss_mb_per_player": [1.0] * n, "naive_loop": {}, "max_realtime_players": 0,
        "both_models": section | {"hmd3_share": 0.5, "hmd3_players": [0, 2],
                                  "rss_mb_per_player": [1.0] * n},
        "mixed_sets": section | {"sets": ["3p"], "p50_ratio": [1.0] * n,
                                 "rss_mb_per_player": [1.0] * n},
    }  # fmt: skip


@pytest.mark.parametrize(
    ("p99", "said"),
    [
        ([2.0, 8.0], ">= 4 (every tested count fit)"),
        ([20.0, 80.0], "none of the tested counts fit (the smallest, 1, took p99 20.0 ms)"),
        ([2.0, 80.0], "1 (4 did not fit)"),
    ],
)
def test_bench_engine_says_how_many_players_fit(capsys, monkeypatch, p99, said) -> None:
    """``--players 1,4`` all fitting printed ``4`` as the most, none fitting ``0``."""
    import posecast.offline.evaluation.engine_speed as speed

    monkeypatch.setattr(speed, "run_side_by_side", lambda *a: [_bench_report(p99)])
    assert main(["bench", "engine", "--players", "1,4", "--backend", "onnx"]) == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("max players")]
    assert lines == [
        f"max players at 60 Hz (p99 < 16.7 ms), N=100: {said}",
        f"max players at 60 Hz, both models: {said}",
        f"max players at 60 Hz, mixed sets: {said}",
    ]


def test_bench_engine_prints_to_a_stdout_that_is_not_utf8(capsys, monkeypatch) -> None:
    """'≥ 4 (every tested count fit)' was the CLI's only non-ASCII output: on an ASCII
    stdout (LANG=C, a pipe on some systems) print raised UnicodeEncodeError."""
    import io

    import posecast.offline.evaluation.engine_speed as speed

    monkeypatch.setattr(speed, "run_side_by_side", lambda *a: [_bench_report([2.0, 8.0])])
    out = io.BytesIO()
    monkeypatch.setattr(sys, "stdout", io.TextIOWrapper(out, encoding="ascii", errors="strict"))
    assert main(["bench", "engine", "--players", "1,4", "--backend", "onnx"]) == 0
    sys.stdout.flush()
    assert b"max players at 60 Hz, mixed sets: >= 4 (every tested count fit)" in out.getvalue()


def test_bench_engine_help_shows_the_defaults(capsys) -> None:
    with pytest.raises(SystemExit):
        main(["bench", "engine", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    for default in ("1,10,50,100,200", "100", "120", "2", "10"):
        assert f"(default {default})" in out, (default, out)
