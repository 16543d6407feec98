"""``posecast data prepare|clearance|wrists`` (posecast.cli.data)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from posecast.cli import main
from posecast.offline.dataset.store import read_manifest
from posecast.skeleton import JOINT_NAMES
from tests.cli.conftest import user_error, write_bvh


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
    path = write_bvh(root, "captures/alice/take1.bvh", "posecast", 4)
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
