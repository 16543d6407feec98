"""The ``posecast`` command line (posecast.cli), called in-process through ``main``."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from posecast.cli import main
from posecast.dataset.store import read_manifest
from posecast.motion.synthetic import walk_clip, write_fixture_bvh
from posecast.skeleton import JOINT_NAMES


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
    assert main(argv) == 2
    assert "[DATA_INVALID]" in capsys.readouterr().err


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


def test_token_mints_a_token_the_server_verifies(capsys, monkeypatch) -> None:
    import time

    from posecast.auth.tokens import verify

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
    assert main(["token", "--room", "R", "--player", "P"]) == 2
