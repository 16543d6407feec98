"""The ``posecast`` command line (posecast.cli), called in-process through ``main``.

Every error a user can cause ends as ``posecast: error [CODE]: message`` and a
``hint:`` line on stderr, exit status 2, and no traceback: one test at least per
subcommand provokes one (``test_*_user_error`` and the tests around them).
"""

from __future__ import annotations

import json
import logging
import re
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from posecast.cli import main
from posecast.offline.dataset.store import read_manifest
from posecast.offline.motion.synthetic import walk_clip, write_fixture_bvh
from posecast.skeleton import JOINT_NAMES


def user_error(capsys: pytest.CaptureFixture[str], rc: int, code: str) -> str:
    """Assert a clean user error with ``code``; returns stderr."""
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "Traceback" not in err, err
    lines = err.splitlines()
    at = [i for i, ln in enumerate(lines) if ln.startswith(f"posecast: error [{code}]: ")]
    assert at, err
    assert lines[at[0] + 1].startswith("hint: ") and len(lines[at[0] + 1]) > 10, err
    return err


def _write(root: Path, rel: str, layout: str, seed: int) -> Path:
    path = root / rel
    path.parent.mkdir(parents=True, exist_ok=True)
    write_fixture_bvh(path, walk_clip(seconds=0.5, fps=120.0, seed=seed), layout)
    return path


@pytest.fixture
def bvh_dir(tmp_path: Path) -> Path:
    root = tmp_path / "bvh"
    _write(root, "mb/01/01_01.bvh.gz", "cmu_mb", 1)  # train
    _write(root, "daz/13/13_01.bvh", "cmu_daz", 2)  # val
    _write(root, "mb/05/05_01.bvh", "cmu_mb", 3)  # test
    return root


def test_data_prepare_prints_the_split_table(bvh_dir: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "prepared"
    assert main(["data", "prepare", "--bvh", str(bvh_dir), "--out", str(out)]) == 0
    stdout = capsys.readouterr().out.splitlines()
    assert stdout[0].split() == ["split", "hours", "seqs", "frames", "contact"]
    rows = {ln.split()[0]: ln.split() for ln in stdout[1:4]}
    assert set(rows) == {"train", "val", "test"}
    for row in rows.values():
        assert row[2] == "1"  # one sequence each
        assert row[3] == "30"  # 0.5 s at 60 fps
    assert stdout[-1].startswith(f"wrote {out}")
    assert read_manifest(out)["splits"]["val"]["subjects"] == ["13"]


def test_verbose_logs_every_file(bvh_dir: Path, tmp_path: Path, capsys) -> None:
    argv = ["data", "prepare", "--bvh", str(bvh_dir), "--out", str(tmp_path / "o"), "-v"]
    assert main(argv) == 0
    err = capsys.readouterr().err
    for name in ("01_01.bvh.gz", "13_01.bvh", "05_01.bvh"):
        assert name in err


def test_a_bad_file_fails_with_code_and_file_name(bvh_dir: Path, tmp_path: Path, capsys) -> None:
    bad = bvh_dir / "mb" / "05" / "05_02.bvh"
    bad.write_text("HIERARCHY\nROOT Hips\n{\n", "utf-8")
    out = tmp_path / "prepared"
    assert main(["data", "prepare", "--bvh", str(bvh_dir), "--out", str(out)]) == 2
    captured = capsys.readouterr()
    assert captured.err.startswith("posecast: error [BVH_INVALID]: ")
    assert f"{bad}:3:" in captured.err
    assert "Traceback" not in captured.err
    assert not (out / "manifest.json").exists()


def test_skip_bad_prepares_the_rest_and_lists_the_bad_file(
    bvh_dir: Path, tmp_path: Path, capsys
) -> None:
    bad = bvh_dir / "junk.bvh"
    bad.write_text("not motion\n", "utf-8")
    out = tmp_path / "prepared"
    argv = ["data", "prepare", "--bvh", str(bvh_dir), "--out", str(out), "--skip-bad"]
    assert main(argv) == 0
    stdout = capsys.readouterr().out
    assert "skipped 1 file(s):" in stdout
    assert str(bad) in stdout
    manifest = read_manifest(out)
    assert [s["file"] for s in manifest["skipped"]] == [str(bad)]
    assert sum(manifest["splits"][s]["sequences"] for s in ("train", "val", "test")) == 3


def test_an_unknown_rig_fails_until_its_map_is_added_with_rigs(tmp_path: Path, capsys) -> None:
    # A skeleton of posecast's shape whose left wrist has another name.
    root = tmp_path / "bvh"
    path = _write(root, "captures/alice/take1.bvh", "posecast", 4)
    path.write_text(path.read_text("utf-8").replace("LEFT_HAND", "L_Wrist"), "utf-8")
    argv = ["data", "prepare", "--bvh", str(root), "--out", str(tmp_path / "o")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("posecast: error [RIG_UNKNOWN]: ")
    assert str(path) in err
    assert "missing joints: LEFT_HAND" in err

    rigs = tmp_path / "rigs"
    rigs.mkdir()
    joints = {j: j for j in JOINT_NAMES}
    joints["LEFT_HAND"] = "L_Wrist"
    rig = {"name": "alice_rig", "unit_m": 1.0, "first_frame_is_tpose": False, "joints": joints}
    (rigs / "alice.json").write_text(json.dumps(rig), "utf-8")
    assert main([*argv, "--rigs", str(rigs)]) == 0
    manifest = read_manifest(tmp_path / "o")
    clips = [c for s in ("train", "val", "test") for c in manifest["clips"][s]]
    assert [(c["rig"], c["subject"]) for c in clips] == [("alice_rig", "alice")]


def test_a_bad_split_file_is_a_config_error(bvh_dir: Path, tmp_path: Path, capsys) -> None:
    split = tmp_path / "split.json"
    split.write_text(json.dumps({"subjects": {"1": "holdout"}}), "utf-8")
    argv = ["data", "prepare", "--bvh", str(bvh_dir), "--out", str(tmp_path / "o")]
    assert main([*argv, "--split-file", str(split)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("posecast: error [CONFIG_INVALID]: ")
    assert str(split) in err


def test_a_custom_split_file_moves_subjects(bvh_dir: Path, tmp_path: Path) -> None:
    split = tmp_path / "split.json"
    split.write_text(json.dumps({"subjects": {"1": "test", "5": "test", "13": "test"}}), "utf-8")
    out = tmp_path / "o"
    argv = ["data", "prepare", "--bvh", str(bvh_dir), "--out", str(out)]
    assert main([*argv, "--split-file", str(split)]) == 0
    splits = read_manifest(out)["splits"]
    assert (splits["train"]["sequences"], splits["test"]["sequences"]) == (0, 3)


def test_a_missing_bvh_directory_is_an_error(tmp_path: Path, capsys) -> None:
    argv = ["data", "prepare", "--bvh", str(tmp_path / "nope"), "--out", str(tmp_path / "o")]
    user_error(capsys, main(argv), "DATA_INVALID")


@pytest.mark.parametrize(
    ("extra", "code"),
    [
        (["--rig", "no_such_rig"], "RIG_UNKNOWN"),
        (["--rigs", "no_such_dir"], "CONFIG_INVALID"),
        (["--out", "__file__"], "CONFIG_INVALID"),
        (["--out", "__file__/prepared"], "CONFIG_INVALID"),  # was a NotADirectoryError
    ],
    ids=["unknown-rig", "missing-rigs-dir", "out-is-a-file", "out-under-a-file"],
)
def test_data_prepare_user_error(
    bvh_dir: Path, tmp_path: Path, capsys, extra: list[str], code: str
) -> None:
    afile = tmp_path / "afile"
    afile.write_text("x", "utf-8")
    extra = [a.replace("__file__", str(afile)) for a in extra]
    argv = ["data", "prepare", "--bvh", str(bvh_dir), "--out", str(tmp_path / "o"), *extra]
    user_error(capsys, main(argv), code)
    assert not (tmp_path / "o").exists()


def test_demo_runs_a_room(capsys) -> None:
    """make run: the server, two simulated headsets and a spectator on loopback."""
    assert main(["demo", "--port", "0", "--seconds", "5", "--samples", "8"]) == 0
    stdout = capsys.readouterr().out
    assert "posecast demo: server on ws://127.0.0.1:" in stdout
    rates = {
        m.group(1): float(m.group(2))
        for m in re.finditer(r"^(alice|bob):\s+([\d.]+) poses/s", stdout, flags=re.MULTILINE)
    }
    assert set(rates) == {"alice", "bob"}, stdout
    assert all(r > 20 for r in rates.values()), rates


def test_demo_stops_cleanly_on_sigterm() -> None:
    """`kill` or a process manager stops make run's demo as Ctrl-C does (it was killed
    by the signal, exit 143, the server never drained)."""
    import signal

    argv = [sys.executable, "-m", "posecast", "demo", "--port", "0", "--samples", "8"]
    with subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) as p:
        assert p.stdout is not None
        out = [p.stdout.readline() for _ in range(3)]  # server, viewer, the first rates
        assert out[1].startswith("viewer: "), out
        p.send_signal(signal.SIGTERM)
        rest, _ = p.communicate(timeout=30)
    assert p.returncode == 0, (out, rest)
    assert "Traceback" not in rest, rest


def test_token_mints_a_token_the_server_verifies(capsys, monkeypatch) -> None:
    import time

    from posecast.online.auth.tokens import verify

    monkeypatch.setenv("POSECAST_TOKEN_SECRET", "e" * 32)
    args = ["token", "--room", "R", "--player", "P", "--role", "backend", "--rooms", "A,B"]
    assert main([*args, "--ttl", "60"]) == 0
    claims = verify(b"e" * 32, capsys.readouterr().out.strip(), now=time.time())
    assert (claims.room, claims.player, claims.role, claims.rooms) == (
        "R",
        "P",
        "backend",
        ("A", "B"),
    )
    assert claims.exp - claims.iat == 60
    monkeypatch.delenv("POSECAST_TOKEN_SECRET")
    err = user_error(capsys, main(["token", "--room", "R", "--player", "P"]), "CONFIG_INVALID")
    assert "POSECAST_TOKEN_SECRET" in err


@pytest.mark.parametrize(
    "extra",
    [
        ["--ttl", "0"],
        ["--ttl", "-5"],
        ["--ttl", str(10**9)],
        ["--rooms", "A,B"],  # extra rooms are for backends
        ["--secret", "short"],
        ["--player", "a b"],  # not a wire id: every client's decoder would refuse it
        ["--player", "p" * 65],
        ["--room", "lob by"],
    ],
    ids=[
        "ttl-0",
        "ttl-negative",
        "ttl-too-long",
        "rooms-without-backend",
        "short-secret",
        "player-not-an-id",
        "player-too-long",
        "room-not-an-id",
    ],
)
def test_token_user_error(capsys, monkeypatch, extra: list[str]) -> None:
    monkeypatch.setenv("POSECAST_TOKEN_SECRET", "e" * 32)
    rc = main(["token", "--room", "R", "--player", "P", *extra])
    user_error(capsys, rc, "CONFIG_INVALID")


def test_the_entry_point_prints_no_traceback() -> None:
    """``python -m posecast`` (what the ``posecast`` script runs): exit 2, code and hint."""
    out = subprocess.run(
        [sys.executable, "-m", "posecast", "token", "--room", "R", "--player", "P"],
        input="",
        capture_output=True,
        text=True,
        timeout=60,
        env={"PATH": "/usr/bin:/bin"},
    )
    assert out.returncode == 2, out.stderr
    assert out.stderr.startswith("posecast: error [CONFIG_INVALID]: "), out.stderr
    assert "\nhint: " in out.stderr and "Traceback" not in out.stderr


def test_a_bug_keeps_its_traceback(monkeypatch) -> None:
    """Only PosecastError is turned into a message; anything else is a bug to see."""
    from posecast.cli import serve

    def broken(args: object) -> int:
        raise RuntimeError("a bug")

    monkeypatch.setattr(serve, "cmd_token", broken)
    with pytest.raises(RuntimeError, match="a bug"):
        main(["token", "--room", "R", "--player", "P"])


@pytest.mark.parametrize(
    ("network", "extra", "code"),
    [
        ("cvae", ["--steps", "0"], "CONFIG_INVALID"),
        ("cvae", ["--steps", "-3"], "CONFIG_INVALID"),
        ("cvae", ["--rot-weight", "-1"], "CONFIG_INVALID"),
        ("cvae", ["--rot-weight", "nan"], "CONFIG_INVALID"),
        ("cvae", ["--vel-weight", "-1"], "CONFIG_INVALID"),
        ("anomaly", ["--vel-weight", "1"], "CONFIG_INVALID"),
        ("cvae", ["--lower-weight", "0"], "CONFIG_INVALID"),
        ("anomaly", ["--lower-weight", "2"], "CONFIG_INVALID"),
        ("cvae", ["--threads", "0"], "CONFIG_INVALID"),
        ("cvae", ["--seed", "-1"], "CONFIG_INVALID"),
        ("cvae", ["--no-orientation"], "CONFIG_INVALID"),  # the 4-point layout has none
        ("ae", ["--layout", "hmd3"], "CONFIG_INVALID"),
        ("anomaly", ["--rot-weight", "10"], "CONFIG_INVALID"),
        ("anomaly", ["--hidden", "256"], "CONFIG_INVALID"),
        ("anomaly", ["--device", "auto"], "CONFIG_INVALID"),
        ("cvae", ["--hidden", "100"], "CONFIG_INVALID"),  # not a multiple of 64
        ("cvae", ["--hidden", "0"], "CONFIG_INVALID"),
        ("cvae", ["--window", "1"], "CONFIG_INVALID"),
        ("cvae", ["--batch", "0"], "CONFIG_INVALID"),
        ("cvae", ["--kl-weight", "-1"], "CONFIG_INVALID"),
        ("cvae", ["--budget-min", "inf"], "CONFIG_INVALID"),
        ("anomaly", ["--steps", "0"], "CONFIG_INVALID"),
        ("cvae", [], "DATASET_INVALID"),  # --data names no directory
        ("anomaly", [], "DATASET_INVALID"),
    ],
)
def test_train_user_error(
    tmp_path: Path, capsys, network: str, extra: list[str], code: str
) -> None:
    argv = ["train", network, "--data", str(tmp_path / "nope"), "--out", str(tmp_path / "run")]
    user_error(capsys, main([*argv, *extra]), code)
    assert not (tmp_path / "run").exists()


def test_train_on_a_directory_that_is_not_a_dataset(tmp_path: Path, capsys) -> None:
    argv = ["train", "cvae", "--data", str(tmp_path), "--out", str(tmp_path / "run")]
    err = user_error(capsys, main(argv), "DATASET_INVALID")
    assert "posecast data prepare" in err


def test_export_user_error(tmp_path: Path, capsys) -> None:
    out = str(tmp_path / "models")
    user_error(capsys, main(["export", "--out", out]), "CONFIG_INVALID")  # nothing to export
    missing = tmp_path / "nope.pt"
    err = user_error(capsys, main(["export", "--out", out, "--ae", str(missing)]), "MODEL_INVALID")
    assert str(missing) in err
    rc = main(["export", "--out", out, "--ae", __file__, "--data", str(tmp_path / "nope")])
    user_error(capsys, rc, "DATASET_INVALID")


@pytest.mark.parametrize(
    ("extra", "code"),
    [
        (["--variants", "foo"], "CONFIG_INVALID"),
        (["--variants", "cvae_ik,"], "CONFIG_INVALID"),
        (["--variants", "ae_ik", "--layout", "hmd3"], "CONFIG_INVALID"),
        (["--layout", "sites"], "CONFIG_INVALID"),
        (["--split", "holdout"], "CONFIG_INVALID"),
        (["--samples", "0"], "CONFIG_INVALID"),
        (["--samples", "100000000"], "CONFIG_INVALID"),
        (["--outlier-factor", "-1"], "CONFIG_INVALID"),
        (["--ik-max-drift", "-0.1"], "CONFIG_INVALID"),
        (["--ik-max-drift", "far"], "CONFIG_INVALID"),
        (["--ik-release-frames", "0"], "CONFIG_INVALID"),
        (["--wrist-elbow", "1.5"], "CONFIG_INVALID"),
        (["--wrist-elbow", "-0.1"], "CONFIG_INVALID"),
        (["--wrist-elbow", "nan"], "CONFIG_INVALID"),
        (["--backend", "cuda"], "CONFIG_INVALID"),
        (["--json", "/no/such/dir/eval.json"], "CONFIG_INVALID"),
        (["--models", "/no/such/models"], "MODEL_INVALID"),
        ([], "DATASET_INVALID"),  # --data names no directory
    ],
)
def test_eval_user_error(tmp_path: Path, capsys, extra: list[str], code: str) -> None:
    rc = main(["eval", "--data", str(tmp_path / "nope"), *extra])
    user_error(capsys, rc, code)


def test_eval_takes_every_engine_switch_of_the_server() -> None:
    """``posecast eval --no-*`` are the server's engine switches, mapped to EngineConfig
    by the one mapping (config.engine_settings): a switch added to the server without
    its eval flag fails here, not with an AttributeError in a run."""
    from posecast.cli import build_parser
    from posecast.online.config import ENGINE_SWITCHES

    args = build_parser().parse_args(["eval", "--data", "d"])
    assert all(getattr(args, name) is False for name in ENGINE_SWITCHES)


def test_data_clearance_prints_the_engines_table(bvh_dir: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "prepared"
    assert main(["data", "prepare", "--bvh", str(bvh_dir), "--out", str(out)]) == 0
    capsys.readouterr()
    assert main(["data", "clearance", "--data", str(out), "--percentile", "50"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[1].split() == ["speed_m_s", "toe_frames", "clearance_m"]
    assert lines[-2].startswith("SPEEDS_M_S = (0.125, ") and lines[-1].startswith("CLEARANCE_M")
    rows = [ln.split() for ln in lines[2:-2]]
    assert sum(int(r[1]) for r in rows) > 0  # the walk's toe-frames, binned
    heights = [float(r[2]) for r in rows]
    assert heights == sorted(heights) and heights[-1] > 0


@pytest.mark.parametrize(
    ("extra", "code"),
    [
        (["--split", "holdout"], "CONFIG_INVALID"),
        (["--percentile", "101"], "CONFIG_INVALID"),
        (["--percentile", "nan"], "CONFIG_INVALID"),
        ([], "DATASET_INVALID"),  # --data names no directory
    ],
)
def test_data_clearance_user_error(tmp_path: Path, capsys, extra: list[str], code: str) -> None:
    rc = main(["data", "clearance", "--data", str(tmp_path / "nope"), *extra])
    user_error(capsys, rc, code)


def test_data_wrists_prints_the_wrists_bend(bvh_dir: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "prepared"
    assert main(["data", "prepare", "--bvh", str(bvh_dir), "--out", str(out)]) == 0
    capsys.readouterr()
    assert main(["data", "wrists", "--data", str(out), "--split", "train"]) == 0
    lines = capsys.readouterr().out.splitlines()
    stats = {ln.split()[0]: float(ln.split()[1]) for ln in lines[1:]}
    assert list(stats) == ["hand_frames", "mean_deg", "median_deg", "p90_deg", "p99_deg"]
    assert stats["hand_frames"] > 0
    assert 0.0 <= stats["median_deg"] <= stats["p90_deg"] <= stats["p99_deg"] <= 180.0


@pytest.mark.parametrize(
    ("extra", "code"),
    [(["--split", "holdout"], "CONFIG_INVALID"), ([], "DATASET_INVALID")],
)
def test_data_wrists_user_error(tmp_path: Path, capsys, extra: list[str], code: str) -> None:
    rc = main(["data", "wrists", "--data", str(tmp_path / "nope"), *extra])
    user_error(capsys, rc, code)


def test_eval_of_a_directory_without_bvh_files(tmp_path: Path, capsys) -> None:
    user_error(capsys, main(["eval", "--bvh", str(tmp_path)]), "DATA_INVALID")


def test_eval_apps_user_error(bvh_dir: Path, tmp_path: Path, capsys) -> None:
    data = tmp_path / "prepared"
    user_error(capsys, main(["eval-apps", "--data", str(data)]), "DATASET_INVALID")
    user_error(capsys, main(["eval-apps", "--data", str(data), "--runs", "0"]), "CONFIG_INVALID")
    rc = main(["eval-apps", "--data", str(data), "--latent-scale", "0"])
    user_error(capsys, rc, "CONFIG_INVALID")
    rc = main(["eval-apps", "--data", str(data), "--samples", "1,x"])
    user_error(capsys, rc, "CONFIG_INVALID")
    rc = main(["eval-apps", "--data", str(data), "--samples", "10,100000000"])
    user_error(capsys, rc, "CONFIG_INVALID")
    rc = main(["eval-apps", "--data", str(data), "--backend", "cuda"])
    user_error(capsys, rc, "CONFIG_INVALID")
    assert main(["data", "prepare", "--bvh", str(bvh_dir), "--out", str(data)]) == 0
    capsys.readouterr()
    rc = main(["eval-apps", "--data", str(data), "--clip", "no_such_clip"])
    err = user_error(capsys, rc, "CONFIG_INVALID")
    assert "01_01" in err  # the hint names the clips there are


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


def test_an_unknown_backend_is_named_with_the_known_ones(capsys) -> None:
    err = user_error(capsys, main(["bench", "engine", "--backend", "cuda"]), "CONFIG_INVALID")
    assert "'cuda'" in err and "native, onnx, torch" in err.splitlines()[-1]


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


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["bench", "engine", "--players", "10,10"], "--players '10,10' names 10 twice"),
        (["bench", "engine", "--players", "1,10,1"], "--players '1,10,1' names 1 twice"),
        (["eval-apps", "--data", "d", "--samples", "4,4"], "--samples '4,4' names 4 twice"),
    ],
)
def test_a_count_listed_twice_is_refused(capsys, monkeypatch, argv: list[str], says: str) -> None:
    """``--players 10,10`` ran the same count twice and printed '10 (10 did not fit)'
    when one run fit and the other did not."""
    import posecast.offline.evaluation.engine_speed as speed

    monkeypatch.setattr(speed, "run_side_by_side", lambda *a: pytest.fail("it ran"))
    err = user_error(capsys, main(argv), "CONFIG_INVALID")
    assert f"posecast: error [CONFIG_INVALID]: {says}: each count once" in err, err


def test_serve_without_a_secret_is_a_config_error(capsys, monkeypatch) -> None:
    """No POSECAST_TOKEN_SECRET and no --dev: refused before any socket is opened."""
    import os

    for name in [k for k in os.environ if k.startswith("POSECAST_")]:
        monkeypatch.delenv(name)
    err = user_error(capsys, main(["serve", "--port", "0"]), "CONFIG_INVALID")
    assert "POSECAST_TOKEN_SECRET" in err and "--dev" in err.splitlines()[-1]


@pytest.mark.parametrize(
    ("argv", "env", "said"),
    [
        (["--tick-hz", "nan"], {}, "--tick-hz nan must be in [1, 240]"),
        ([], {"POSECAST_TICK_HZ": "nan"}, "POSECAST_TICK_HZ=nan must be in [1, 240]"),
        (
            ["--redis-timeout-s", "2"],
            {},
            "--redis-node-ttl-s 3 must be above timeout + max(heartbeat / 2 + timeout,"
            " heartbeat) = 4.5 s, with --redis-timeout-s 2 and --redis-heartbeat-s 1",
        ),
        (["--redis", "redis://h:port/0"], {}, "--redis is not a well-formed URL (not shown"),
    ],
)
def test_serve_names_a_bad_setting_as_the_user_gave_it(
    capsys, monkeypatch, argv: list[str], env: dict[str, str], said: str
) -> None:
    """``posecast serve --tick-hz nan`` said ``tick_hz must be in [1, 240]``."""
    import os

    for name in [k for k in os.environ if k.startswith("POSECAST_")]:
        monkeypatch.delenv(name)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    err = user_error(capsys, main(["serve", "--dev", *argv]), "CONFIG_INVALID")
    assert f"posecast: error [CONFIG_INVALID]: {said}" in err, err
    assert "tick_hz" not in err and "redis_" not in err, err


def test_serve_names_a_models_dir_from_the_environment(capsys, monkeypatch) -> None:
    import os

    for name in [k for k in os.environ if k.startswith("POSECAST_")]:
        monkeypatch.delenv(name)
    monkeypatch.setenv("POSECAST_MODELS_DIR", "/no/such/models")
    err = user_error(capsys, main(["serve", "--dev"]), "MODEL_INVALID")
    assert "leave out POSECAST_MODELS_DIR" in err.splitlines()[-1], err


@pytest.mark.parametrize(
    ("argv", "env", "named"),
    [
        (["--models-dir", "/no/such/a"], {}, "--models-dir"),
        (["--models", "/no/such/a"], {"POSECAST_MODELS_DIR": "/no/such/b"}, "--models-dir"),
        ([], {"POSECAST_MODELS_DIR": "/no/such/b"}, "POSECAST_MODELS_DIR"),
    ],
)
def test_serve_names_the_models_dir_as_the_config_names_it(
    capsys, monkeypatch, argv: list[str], env: dict[str, str], named: str
) -> None:
    """cmd_serve worked out the models directory's name from os.environ itself,
    beside the config's own naming: it asks config.setting_names now."""
    import os

    import posecast.online.config as config

    def names(*a: object) -> dict[str, str]:  # marked, to tell its name from another
        out = setting_names(*a)  # type: ignore[arg-type]
        return out | {"models_dir": f"<{out['models_dir']}>"}

    setting_names = config.setting_names
    monkeypatch.setattr(config, "setting_names", names)
    for name in [k for k in os.environ if k.startswith("POSECAST_")]:
        monkeypatch.delenv(name)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    err = user_error(capsys, main(["serve", "--dev", *argv]), "MODEL_INVALID")
    assert f"leave out <{named}> for the shipped models" in err.splitlines()[-1], err


@pytest.mark.parametrize(
    ("extra", "code"),
    [
        (["--port", "70000"], "CONFIG_INVALID"),
        (["--samples", "0"], "CONFIG_INVALID"),
        (["--samples", "100000000"], "CONFIG_INVALID"),  # was a MemoryError traceback
        (["--lookahead", "100000"], "CONFIG_INVALID"),  # was a MemoryError traceback
        (["--lookahead", "256"], "CONFIG_INVALID"),  # served, and every welcome refused
        (["--layouts", "hmd4"], "CONFIG_INVALID"),
        (["--backend", "cuda"], "CONFIG_INVALID"),
        (["--models-dir", "/no/such/models"], "MODEL_INVALID"),
    ],
)
def test_serve_user_error(capsys, monkeypatch, extra: list[str], code: str) -> None:
    import os

    for name in [k for k in os.environ if k.startswith("POSECAST_")]:
        monkeypatch.delenv(name)
    user_error(capsys, main(["serve", "--dev", *extra]), code)


@pytest.mark.parametrize(
    ("extra", "code"),
    [
        (["--samples", "0"], "CONFIG_INVALID"),
        (["--samples", "100000000"], "CONFIG_INVALID"),  # was a MemoryError traceback
        (["--seconds", "-1"], "CONFIG_INVALID"),
        (["--port", "-1"], "CONFIG_INVALID"),
        (["--bvh", "/no/such/file.bvh"], "BVH_INVALID"),
    ],
)
def test_demo_user_error(capsys, extra: list[str], code: str) -> None:
    user_error(capsys, main(["demo", *extra]), code)


def test_demo_on_a_port_in_use_is_a_config_error(capsys) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        rc = main(["demo", "--port", str(port), "--seconds", "1", "--samples", "8"])
    err = user_error(capsys, rc, "CONFIG_INVALID")
    assert f"127.0.0.1:{port}" in err


def test_train_device_auto_takes_cuda_only_where_torch_sees_one(monkeypatch) -> None:
    import torch

    from posecast.cli.train import train_device
    from posecast.errors import PosecastError

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert train_device("auto") == train_device("cpu") == "cpu"
    with pytest.raises(PosecastError, match="no CUDA device"):
        train_device("cuda")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert train_device("auto") == train_device("cuda") == "cuda"


@pytest.mark.parametrize(
    ("argv", "says", "hint"),
    [
        (["serve", "--port", "abc"], "invalid int value: 'abc'", "see `posecast serve --help`"),
        (
            ["data", "prepare", "--bvh", "x"],
            "required: --out",
            "see `posecast data prepare --help`",
        ),
        (
            ["eval", "--data", "d", "--samples"],
            "expected one argument",
            "see `posecast eval --help`",
        ),
        (
            ["token", "--room", "R", "--player", "P", "--ttl", "1e3"],
            "invalid int value: '1e3'",
            "see `posecast token --help`",
        ),
        (["train", "cvea"], "invalid choice: 'cvea'", "see `posecast train --help`"),
    ],
)
def test_a_command_line_mistake_is_a_config_error_naming_its_command(
    capsys, argv: list[str], says: str, hint: str
) -> None:
    """What argparse refuses (a malformed or missing value, a missing option) prints
    the CLI's own error, code and a hint naming the command's help, never a bare
    argparse message."""
    err = user_error(capsys, main(argv), "CONFIG_INVALID")
    assert says in err, err
    assert f"hint: {hint} for the options" in err, err


@pytest.mark.parametrize(
    ("argv", "says", "hint"),
    [
        # An unknown option with no command: it, not the missing command, is the mistake.
        (["--bogus"], "unknown option --bogus", "see `posecast --help` for the options"),
        (["-x"], "unknown option -x", "see `posecast --help` for the options"),
        (["data", "--bogus"], "unknown option --bogus", "see `posecast data --help`"),
        # ... nor is a required option it hides, perhaps by a typo of it.
        (
            ["token", "--room", "R", "--plyer", "P"],
            "unknown option --plyer",
            "did you mean --player? see `posecast token --help` for the options",
        ),
        (
            ["data", "clearance", "--bvh", "x"],  # was: "required: --data"
            "unknown option --bvh",
            "see `posecast data clearance --help` for the options",
        ),
        # After a command, by argparse's order already, now with the nearest option.
        (
            ["serve", "--no-such-flag"],
            "unknown option --no-such-flag",
            "see `posecast serve --help`",
        ),
        (
            ["serve", "--prot", "1"],
            "unknown option --prot",
            "did you mean --port? see `posecast serve --help` for the options",
        ),
        (["serve", "-p", "80"], "unknown option -p", "see `posecast serve --help` for the options"),
        (["--bogus", "serve"], "unknown option --bogus", "see `posecast serve --help`"),
        # An option typed before its command.
        (
            ["--port", "80", "serve"],
            "unknown option --port",
            "an option goes after its command: `posecast serve --port`",
        ),
        # A misspelt or missing command: named with the commands, not by argparse's dest.
        (
            ["srve"],
            "unknown command 'srve' for `posecast` (one of data, train,",
            "did you mean `posecast serve`? see `posecast --help` for the commands",
        ),
        (
            ["data", "prep", "--out", "x"],
            "unknown command 'prep' for `posecast data` (one of prepare, clearance, wrists)",
            "did you mean `posecast data prepare`? see `posecast data --help` for the commands",
        ),
        ([], "`posecast` needs a command: data, train,", "see `posecast --help` for the commands"),
        (
            ["data"],
            "`posecast data` needs a command: prepare, clearance, wrists",
            "see `posecast data --help` for the commands",
        ),
        (["serve", "80"], "unrecognized arguments: 80", "see `posecast serve --help`"),
    ],
)
def test_the_first_wrong_word_is_the_one_reported(
    capsys, argv: list[str], says: str, hint: str
) -> None:
    """argparse finds a missing command or option before it looks at the words it did
    not know: ``posecast --bogus`` said a command was missing. The CLI names the
    unknown option or command, in the order typed, with the nearest valid one."""
    err = user_error(capsys, main(argv), "CONFIG_INVALID")
    assert f"posecast: error [CONFIG_INVALID]: {says}" in err, err
    assert f"hint: {hint}" in err, err
    assert "did you mean" in hint or "did you mean" not in err, err


@pytest.mark.parametrize(
    ("argv", "says", "hint"),
    [
        (
            ["token", "--room", "R", "--player", "P", "--secret", "-SuperSecretValue123456"],
            "argument --secret: expected one argument",
            "a value that starts with '-' goes after '=' (--secret=VALUE)",
        ),
        (
            ["token", "--room", "R", "--player", "P", "--sec", "-SuperSecretValue123456"],
            "argument --secret: expected one argument",
            "(--secret=VALUE)",
        ),
        (
            ["token", "--room", "R", "--player", "P", "--secret", "-hSuperSecretValue123456"],
            "argument --secret: expected one argument",
            "(--secret=VALUE)",
        ),
        (
            ["token", "--room", "R", "--player", "-bob"],
            "argument --player: expected one argument",
            "(--player=VALUE)",
        ),
        (
            ["serve", "--redis", "-SuperSecretValue123456"],
            "argument --redis-url/--redis: expected one argument",
            "(--redis=VALUE)",
        ),
        (
            ["serve", "--re=redis://:SuperSecretValue123456@h/0"],
            "ambiguous option: --re=<hidden> could match",
            "see `posecast serve --help` for the options",
        ),
    ],
)
def test_a_value_that_starts_with_a_dash_is_not_an_unknown_option(
    capsys, argv: list[str], says: str, hint: str
) -> None:
    """The word after an option that takes a value is its value, not an option: the
    CLI called ``--secret -SuperSecret...`` an unknown option, and so printed the
    secret on stderr. argparse's own complaint is reported, with the ``--opt=VALUE``
    form that takes such a value, and a secret's value is never shown."""
    err = user_error(capsys, main(argv), "CONFIG_INVALID")
    assert f"posecast: error [CONFIG_INVALID]: {says}" in err, err
    assert "hint: " in err and hint in err.split("hint: ", 1)[1], err
    assert "SuperSecretValue123456" not in err and "unknown option" not in err, err


def test_a_value_that_starts_with_a_dash_goes_after_an_equals_sign(capsys) -> None:
    argv = ["token", "--room", "R", "--player", "P", "--secret=-SuperSecretValue123456"]
    assert main(argv) == 0
    assert capsys.readouterr().out.count(".") == 1


def test_an_unknown_option_with_no_command_prints_no_traceback() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "posecast", "--bogus"],
        input="",
        capture_output=True,
        text=True,
        timeout=60,
        env={"PATH": "/usr/bin:/bin"},
    )
    assert out.returncode == 2, out.stderr
    assert "posecast: error [CONFIG_INVALID]: unknown option --bogus\n" in out.stderr
    assert "\nhint: see `posecast --help`" in out.stderr and "Traceback" not in out.stderr


def test_help_describes_posecast_for_its_users(capsys) -> None:
    """``posecast --help`` showed the module docstring's developer note ("Configuration
    is parsed here, once, and passed down.")."""
    with pytest.raises(SystemExit) as exit_:
        main(["--help"])
    out = capsys.readouterr().out
    assert exit_.value.code == 0
    assert "Configuration is parsed" not in out
    assert "Full-body poses for VR players" in " ".join(out.split()), out
    assert "posecast serve --dev" in " ".join(out.split()), out


def test_bench_engine_help_shows_the_defaults(capsys) -> None:
    with pytest.raises(SystemExit):
        main(["bench", "engine", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    for default in ("1,10,50,100,200", "100", "120", "2", "10"):
        assert f"(default {default})" in out, (default, out)


def _serve_output(monkeypatch, capsys, argv: list[str], env: dict[str, str]) -> list[str]:
    """What ``posecast serve argv`` prints on stdout up to and once it listens (on 8765;
    the server itself is not run)."""
    import os

    import posecast.online.shell.app as app

    async def served(cfg, on_ready) -> None:
        on_ready(8765)

    monkeypatch.setattr(app, "serve_until_signal", served)
    for name in [k for k in os.environ if k.startswith("POSECAST_")]:
        monkeypatch.delenv(name)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    for name in ("posecast", "websockets"):  # serve configures them: give them back after
        logger = logging.getLogger(name)
        monkeypatch.setattr(logger, "handlers", list(logger.handlers))
        monkeypatch.setattr(logger, "propagate", logger.propagate)
        monkeypatch.setattr(logger, "level", logger.level)
    assert main(["serve", *argv]) == 0
    return capsys.readouterr().out.splitlines()


def test_serve_dev_prints_export_lines_to_paste_and_the_viewer(capsys, monkeypatch) -> None:
    """``serve --dev`` gave its invented secret as prose only: the README told users to
    copy it into ``export POSECAST_TOKEN_SECRET=<SECRET>`` by hand, and nothing said
    where the viewer was."""
    out = _serve_output(monkeypatch, capsys, ["--dev", "--host", "0.0.0.0"], {})
    secret = re.fullmatch(r"posecast: --dev: token secret for this run: (\S+)", out[0])
    assert secret, out
    # Tests and SDK helpers read the first two lines so: the secret, then the port.
    assert out[1] == "posecast: listening on ws://0.0.0.0:8765"
    assert out[2:] == [
        "posecast: --dev: viewer at http://127.0.0.1:8765/viewer/ (this machine only)",
        "posecast: --dev: for a client in another shell, paste:",
        f"export POSECAST_TOKEN_SECRET={secret.group(1)}",
        "export POSECAST_URL=ws://127.0.0.1:8765/",
    ]
    pasted = subprocess.run(
        ["bash", "-c", f'{out[4]}; {out[5]}; echo "$POSECAST_TOKEN_SECRET $POSECAST_URL"'],
        capture_output=True, text=True, check=True, timeout=30,
    )  # fmt: skip
    assert pasted.stdout == f"{secret.group(1)} ws://127.0.0.1:8765/\n"


def test_serve_dev_with_a_secret_set_prints_the_viewer_and_never_the_secret(
    capsys, monkeypatch
) -> None:
    out = _serve_output(monkeypatch, capsys, ["--dev"], {"POSECAST_TOKEN_SECRET": "k" * 32})
    assert out == [
        "posecast: listening on ws://127.0.0.1:8765",
        "posecast: --dev: viewer at http://127.0.0.1:8765/viewer/ (this machine only)",
    ]
    assert _serve_output(monkeypatch, capsys, [], {"POSECAST_TOKEN_SECRET": "k" * 32}) == [
        "posecast: listening on ws://127.0.0.1:8765"
    ]


def test_serve_writes_an_ipv6_host_in_brackets(capsys, monkeypatch) -> None:
    # It printed ws://:::8765, which no URL parser reads.
    out = _serve_output(monkeypatch, capsys, ["--host", "::"], {"POSECAST_TOKEN_SECRET": "k" * 32})
    assert out == ["posecast: listening on ws://[::]:8765"]


def test_serve_names_both_families_for_every_interface(capsys, monkeypatch) -> None:
    # --host "" (every IPv4 and IPv6 interface) printed ws://:8765, which names neither.
    out = _serve_output(monkeypatch, capsys, ["--host", ""], {"POSECAST_TOKEN_SECRET": "k" * 32})
    assert out == ["posecast: listening on ws://0.0.0.0:8765 and ws://[::]:8765"]


@pytest.mark.parametrize("host", ["::", "::1", "0.0.0.0", "127.0.0.1", "localhost"])
def test_serve_dev_prints_urls_that_reach_the_bound_server(host: str) -> None:
    """``--host ::`` printed 127.0.0.1, but asyncio binds ``::`` IPv6-only: nothing
    answered there. Each printed URL is dialled on a server bound as posecast binds
    (asyncio's create_server, which websockets' serve calls)."""
    import asyncio

    from posecast.cli.serve import dev_lines

    if ":" in host and not socket.has_ipv6:
        pytest.skip("no IPv6 here")

    async def dial() -> list[str]:
        try:
            server = await asyncio.start_server(lambda r, w: w.close(), host, 0)
        except OSError as exc:  # pragma: no cover - a machine without that address
            pytest.skip(f"cannot bind {host}: {exc}")
        port = server.sockets[0].getsockname()[1]
        lines = dev_lines(host, port, "s" * 32)
        try:
            for url in (lines[0].split()[4], lines[3].split("=", 1)[1]):
                address = url.split("//", 1)[1].rsplit(":", 1)[0].strip("[]")
                _, writer = await asyncio.open_connection(address, port)
                writer.close()
        finally:
            server.close()
        return lines

    lines = asyncio.run(dial())
    assert lines[0].endswith("/viewer/ (this machine only)"), lines
    if host.startswith(":"):
        assert "http://[::1]:" in lines[0] and lines[3].startswith(
            "export POSECAST_URL=ws://[::1]:"
        )


def test_serve_dev_on_an_address_that_is_not_loopback_says_there_is_no_viewer() -> None:
    """The viewer line said "(this machine only)" for ``--host 192.168.x.y`` too, but
    /viewer/token hands tokens to loopback peers only (shell.http): the page got 403."""
    from posecast.cli.serve import dev_lines

    assert dev_lines("192.0.2.7", 8765, "s" * 32) == [
        "posecast: --dev: no viewer here: its dev tokens need a loopback bind, and host"
        " 192.0.2.7 is not one (--host 127.0.0.1, the default, or 0.0.0.0 is)",
        "posecast: --dev: for a client in another shell, paste:",
        f"export POSECAST_TOKEN_SECRET={'s' * 32}",
        "export POSECAST_URL=ws://192.0.2.7:8765/",
    ]
    assert dev_lines("2001:db8::7", 8765, None)[0].startswith("posecast: --dev: no viewer here")


def test_serve_logs_each_posecast_variable_that_sets_nothing(capsys, monkeypatch) -> None:
    """POSECAST_REDIS (for POSECAST_REDIS_URL) used to leave a node silently embedded."""
    import posecast.online.shell.app as app

    async def served(cfg, on_ready) -> None:  # the server itself is not under test
        assert cfg.redis_url == ""

    monkeypatch.setattr(app, "serve_until_signal", served)
    monkeypatch.setenv("POSECAST_TOKEN_SECRET", "s" * 32)
    monkeypatch.setenv("POSECAST_REDIS", "redis://redis:6379/0")
    for name in ("posecast", "websockets"):  # serve configures them: give them back after
        logger = logging.getLogger(name)
        monkeypatch.setattr(logger, "handlers", list(logger.handlers))
        monkeypatch.setattr(logger, "propagate", logger.propagate)
        monkeypatch.setattr(logger, "level", logger.level)
    assert main(["serve", "--port", "0"]) == 0
    lines = [json.loads(ln) for ln in capsys.readouterr().err.splitlines() if ln.startswith("{")]
    (warning,) = [ln for ln in lines if ln["event"] == "unknown setting ignored"]
    assert warning["level"] == "WARNING" and warning["variable"] == "POSECAST_REDIS"
    assert warning["did_you_mean"] == "POSECAST_REDIS_URL"
