"""``posecast data prepare`` with ASF/AMC sources: alone, mixed with BVH, HDM05 opt-in.

The files are the hand-made CMU-named skeleton and walk of
``tests/offline/motion/acclaim_fixtures.py``; nothing from ../shared is needed.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from posecast.cli import main
from posecast.errors import AcclaimError, DataError
from posecast.offline.dataset.prepare import (
    HDM05_CITATION,
    HDM05_LICENCE,
    amc_frame_rate,
    find_amc_files,
    find_asf_for,
    prepare,
)
from posecast.offline.dataset.split import SPLITS, load_split_table, split_of
from posecast.offline.dataset.store import load_split, read_manifest
from posecast.offline.motion.rig import load_rigs
from posecast.offline.motion.synthetic import walk_clip, write_fixture_bvh

from ..motion.acclaim_fixtures import cmu_like_amc, cmu_like_asf, write_text

TABLE = load_split_table()

# (folder, skeleton file, take file, seconds, subject): subjects from the committed
# table in train (16, bd) and val (49), and one it does not list (77, hashed).
CMU_TAKES = (
    ("16", "16.asf", "16_01.amc", 1.0, "16"),
    ("16", "16.asf", "16_02.amc.gz", 0.75, "16"),
    ("49", "49.asx.gz", "49_03.amc.gz", 1.25, "49"),
    ("77", "77.asf.gz", "77_01.amc", 0.5, "77"),
)
HDM_TAKES = (("bd", "HDM_bd.asf", "HDM_bd_walk1Reps_001_120.amc", 1.0, "bd"),)


def _frames_60(seconds: float) -> int:
    n = round(seconds * 120)
    return (n - 1) // 2 + 1  # no T-pose frame in an AMC; 120 -> 60 fps


def _write_takes(root: Path, takes, seed: int = 0) -> list[Path]:
    out = []
    for i, (folder, skel, take, seconds, _) in enumerate(takes):
        d = root / folder
        gz = skel.endswith(".gz")
        if not (d / skel).exists():
            write_text(d / skel, cmu_like_asf(), crlf=True, gz=gz)
        amc = cmu_like_amc(seconds=seconds, seed=seed + i)
        out.append(write_text(d / take, amc, crlf=i % 2 == 1, gz=take.endswith(".gz")))
    return out


@pytest.fixture
def amc_tree(tmp_path: Path) -> Path:
    root = tmp_path / "amc"
    _write_takes(root, CMU_TAKES)
    return root


@pytest.fixture
def hdm_tree(tmp_path: Path) -> Path:
    root = tmp_path / "hdm05"
    _write_takes(root, HDM_TAKES, seed=10)
    return root


@pytest.fixture
def bvh_tree(tmp_path: Path) -> Path:
    root = tmp_path / "bvh"
    path = root / "mb" / "01" / "01_01.bvh.gz"
    path.parent.mkdir(parents=True)
    write_fixture_bvh(path, walk_clip(seconds=1.0, fps=120.0, seed=3), "cmu_mb")
    return root


def _clips(manifest: dict) -> dict[str, tuple[str, dict]]:
    return {c["name"]: (split, c) for split in SPLITS for c in manifest["clips"][split]}


def test_an_amc_tree_prepares_into_a_dataset(amc_tree: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    report = prepare(None, out, load_rigs(), amc_roots=[amc_tree])
    manifest = read_manifest(out)
    assert report.skipped == [] and manifest["skipped"] == []
    clips = _clips(manifest)
    assert set(clips) == {Path(t[2]).name.split(".")[0] for t in CMU_TAKES}
    for folder, skel, take, seconds, subject in CMU_TAKES:
        split, entry = clips[take.split(".")[0]]
        assert entry["subject"] == subject
        assert split == split_of(subject, TABLE)
        assert entry["rig"] == "cmu_asf"
        assert entry["format"] == "amc" and entry["source_kind"] == "amc"
        assert entry["source"] == str(amc_tree / folder / take)
        assert entry["skeleton"] == str(amc_tree / folder / skel)
        assert entry["frames"] == _frames_60(seconds)
    assert manifest["sources"] == [
        {"kind": "amc", "root": str(amc_tree), "files": len(CMU_TAKES), "clips": len(CMU_TAKES)}
    ]
    assert manifest["hdm05"] is False
    for split in SPLITS:
        data = load_split(out, split)
        assert data.n_clips == len(manifest["clips"][split])
        np.testing.assert_array_equal(np.diff(data.clip_start), [c["frames"] for c in data.clips])
        assert np.isfinite(data.frames["positions"]).all()
    assert "sources: amc" in report.table()


def test_bvh_and_amc_mix_and_hdm05_is_recorded(
    bvh_tree: Path, amc_tree: Path, hdm_tree: Path, tmp_path: Path
) -> None:
    out = tmp_path / "out"
    prepare(bvh_tree, out, load_rigs(), amc_roots=[amc_tree], hdm05_roots=[hdm_tree])
    manifest = read_manifest(out)
    clips = _clips(manifest)
    assert clips["01_01"][1]["format"] == "bvh" and clips["01_01"][1]["rig"] == "cmu_mb"
    hdm_split, hdm = clips["HDM_bd_walk1Reps_001_120"]
    assert (hdm["subject"], hdm_split, hdm["source_kind"]) == ("bd", "train", "hdm05")
    assert manifest["hdm05"] is True
    kinds = [(s["kind"], s["root"], s["files"], s["clips"]) for s in manifest["sources"]]
    assert kinds == [
        ("bvh", str(bvh_tree), 1, 1),
        ("amc", str(amc_tree), len(CMU_TAKES), len(CMU_TAKES)),
        ("hdm05", str(hdm_tree), 1, 1),
    ]
    hdm_source = manifest["sources"][2]
    assert hdm_source["licence"] == HDM05_LICENCE and "CC BY-SA 3.0" in HDM05_LICENCE
    assert hdm_source["citation"] == HDM05_CITATION and "CG-2007-2" in HDM05_CITATION
    total = sum(manifest["splits"][s]["sequences"] for s in SPLITS)
    assert total == 1 + len(CMU_TAKES) + 1


def test_hdm05_is_read_only_through_its_own_source(hdm_tree: Path, tmp_path: Path) -> None:
    with pytest.raises(DataError, match="HDM05") as info:
        prepare(None, tmp_path / "out", load_rigs(), amc_roots=[hdm_tree])
    assert any("--hdm05" in n for n in getattr(info.value, "__notes__", []))
    assert not (tmp_path / "out").exists()


def test_find_asf_for_picks_the_subjects_skeleton(tmp_path: Path) -> None:
    d = tmp_path / "mixed"
    for name in ("13.asf", "135.asf.gz", "HDM_bd.asx", "notes.txt"):
        write_text(d / name, "x")
    assert find_asf_for(d / "135_02.amc.gz") == d / "135.asf.gz"
    assert find_asf_for(d / "13_01.amc") == d / "13.asf"
    assert find_asf_for(d / "HDM_bd_squat1Reps_001_120.amc") == d / "HDM_bd.asx"
    with pytest.raises(AcclaimError, match=r"expected 7\.asf") as info:
        find_asf_for(d / "7_01.amc")
    assert info.value.file == str(d / "7_01.amc")
    lone = tmp_path / "lone"
    write_text(lone / "skeleton.asf", "x")
    assert find_asf_for(lone / "take1.amc") == lone / "skeleton.asf"
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(AcclaimError, match="no skeleton"):
        find_asf_for(empty / "01_01.amc")


def test_amc_frame_rate_and_file_discovery(amc_tree: Path, tmp_path: Path) -> None:
    assert amc_frame_rate("HDM_bd_squat1Reps_001_120.amc.gz") == 120.0
    assert amc_frame_rate("x/HDM_mm_sneak_002_60.amc") == 60.0
    assert amc_frame_rate("16_01.amc") == 120.0
    assert amc_frame_rate("16_01.amc", default=60.0) == 60.0
    (amc_tree / "16" / "16_01.amc.bak").write_text("old", "utf-8")
    assert [p.name for p in find_amc_files(amc_tree)] == [
        "16_01.amc",
        "16_02.amc.gz",
        "49_03.amc.gz",
        "77_01.amc",
    ]
    out = tmp_path / "out60"
    prepare(None, out, load_rigs(), amc_roots=[amc_tree / "77"], amc_fps=60.0)
    (entry,) = [c for s in SPLITS for c in read_manifest(out)["clips"][s]]
    assert entry["frames"] == 60  # 0.5 s written at 120 fps, read as 60 fps: 1 s


def test_bad_amc_files_fail_or_are_skipped(amc_tree: Path, tmp_path: Path) -> None:
    orphan = write_text(amc_tree / "orphans" / "55_01.amc", cmu_like_amc(0.5))
    lines = cmu_like_amc(0.5).splitlines()
    lines[10] = "lfemur 1 2"
    broken = write_text(amc_tree / "16" / "16_09.amc", "\n".join(lines) + "\n")
    with pytest.raises(AcclaimError) as info:
        prepare(None, tmp_path / "out", load_rigs(), amc_roots=[amc_tree])
    assert info.value.file == str(broken)
    assert f"{broken}:11: " in str(info.value)
    report = prepare(None, tmp_path / "out", load_rigs(), amc_roots=[amc_tree], skip_bad=True)
    assert sorted(f for f, _ in report.skipped) == sorted([str(broken), str(orphan)])
    assert "no skeleton" in dict(report.skipped)[str(orphan)]
    manifest = read_manifest(tmp_path / "out")
    assert sum(manifest["splits"][s]["sequences"] for s in SPLITS) == len(CMU_TAKES)


def test_an_empty_or_missing_amc_directory_is_an_error(tmp_path: Path) -> None:
    with pytest.raises(DataError, match=r"no \.amc"):
        prepare(None, tmp_path / "out", load_rigs(), amc_roots=[tmp_path])
    with pytest.raises(DataError, match="no such directory"):
        prepare(None, tmp_path / "out", load_rigs(), amc_roots=[tmp_path / "absent"])
    with pytest.raises(DataError, match="no source"):
        prepare(None, tmp_path / "out", load_rigs())


# --- the command line -------------------------------------------------------------------


def _user_error(capsys: pytest.CaptureFixture[str], rc: int, code: str) -> str:
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "Traceback" not in err
    lines = err.splitlines()
    assert lines[0].startswith(f"posecast: error [{code}]: "), err
    assert lines[1].startswith("hint: ") and len(lines[1]) > 10, err
    return err


def test_cli_takes_any_mix(
    bvh_tree: Path, amc_tree: Path, hdm_tree: Path, tmp_path: Path, capsys
) -> None:
    out = tmp_path / "o"
    argv = ["data", "prepare", "--bvh", str(bvh_tree), "--amc", str(amc_tree / "16")]
    argv += ["--amc", str(amc_tree / "49"), "--hdm05", str(hdm_tree), "--out", str(out)]
    assert main(argv) == 0
    stdout = capsys.readouterr().out.splitlines()
    assert stdout[0].split() == ["split", "hours", "seqs", "frames", "contact"]
    assert any(ln.startswith("sources: bvh") and "hdm05" in ln for ln in stdout)
    manifest = json.loads((out / "manifest.json").read_text("utf-8"))
    assert [s["kind"] for s in manifest["sources"]] == ["bvh", "amc", "amc", "hdm05"]
    assert manifest["hdm05"] is True


def test_cli_errors(amc_tree: Path, hdm_tree: Path, tmp_path: Path, capsys) -> None:
    out = str(tmp_path / "o")
    _user_error(capsys, main(["data", "prepare", "--out", out]), "CONFIG_INVALID")
    argv = ["data", "prepare", "--amc", str(amc_tree), "--out", out, "--amc-fps", "0"]
    _user_error(capsys, main(argv), "CONFIG_INVALID")
    bad = write_text(amc_tree / "16" / "16_05.amc", "1\nroot 1 2\n")
    err = _user_error(
        capsys, main(["data", "prepare", "--amc", str(amc_tree), "--out", out]), "ACCLAIM_INVALID"
    )
    assert f"{bad}:2: " in err and ".asf" in err.splitlines()[1]
    err = _user_error(
        capsys, main(["data", "prepare", "--amc", str(hdm_tree), "--out", out]), "DATA_INVALID"
    )
    assert "--hdm05" in err.splitlines()[1]
    err = _user_error(
        capsys,
        main(["data", "prepare", "--amc", str(tmp_path / "nope"), "--out", out]),
        "DATA_INVALID",
    )
    assert "--amc" in err.splitlines()[1]
    assert not Path(out).exists()
