"""``posecast data prepare`` as a library call (offline.dataset.prepare), and reading it back."""

from __future__ import annotations

import gzip
import json
import tempfile
from collections.abc import Callable
from pathlib import Path

import pytest

from posecast.errors import BvhError, DataError, RigError
from posecast.offline.dataset.prepare import (
    DATASET_FORMAT,
    DATASET_VERSION,
    find_bvh_files,
    prepare,
)
from posecast.offline.dataset.split import SPLITS, load_split_table, split_of
from posecast.offline.dataset.store import load_split, read_manifest
from posecast.offline.motion.rig import load_rigs
from posecast.offline.motion.synthetic import walk_clip, write_fixture_bvh

from .conftest import SOURCE_FPS, Fixture, write_fixture

TABLE = load_split_table()


def _expected_split(fx: Fixture) -> str:
    return split_of(fx.subject, TABLE)


# --- a good tree ------------------------------------------------------------------------


def test_every_split_gets_clips_from_the_fixture_tree(good_files) -> None:
    assert {_expected_split(fx) for fx in good_files} == set(SPLITS)


def test_manifest_statistics(prepared, good_files) -> None:
    out, report = prepared
    manifest = read_manifest(out)
    assert manifest["format"] == DATASET_FORMAT
    assert manifest["version"] == DATASET_VERSION
    assert manifest["fps"] == 60.0
    assert manifest["skipped"] == []
    assert report.skipped == []
    for split in SPLITS:
        mine = [fx for fx in good_files if _expected_split(fx) == split]
        stats = manifest["splits"][split]
        frames = sum(fx.frames_60 for fx in mine)
        assert stats["sequences"] == len(mine), split
        assert stats["frames"] == frames, split
        assert stats["hours"] == pytest.approx(frames / 60 / 3600, abs=5e-5)
        assert stats["subjects"] == sorted({fx.subject for fx in mine}, key=lambda s: (len(s), s))
        assert 0.0 <= stats["contact_ratio"] <= 1.0
        data = load_split(out, split)
        ratio = data.frames["contacts"].sum() / (2 * frames)
        assert stats["contact_ratio"] == pytest.approx(ratio, abs=1e-4)
        assert 0.0 < ratio < 1.0  # the walks have stance and swing phases


def test_manifest_lists_every_clip_with_its_source(prepared, good_files, bvh_tree) -> None:
    out, _ = prepared
    manifest = json.loads((out / "manifest.json").read_text("utf-8"))
    by_name = {c["name"]: (split, c) for split in SPLITS for c in manifest["clips"][split]}
    assert set(by_name) == {fx.name for fx in good_files}
    for fx in good_files:
        split, entry = by_name[fx.name]
        assert split == _expected_split(fx)
        assert entry["subject"] == fx.subject
        assert entry["rig"] == fx.layout
        assert entry["frames"] == fx.frames_60
        assert Path(entry["source"]) == bvh_tree / fx.rel


def test_report_table_has_one_row_per_split(prepared) -> None:
    _, report = prepared
    lines = report.table().splitlines()
    assert lines[0].split() == ["split", "hours", "seqs", "frames", "contact"]
    assert [ln.split()[0] for ln in lines[1:]] == list(SPLITS)
    assert report.seconds > 0


# --- bad input --------------------------------------------------------------------------

# Each maker writes one bad file into a folder and returns its path and what the error
# must say: the error class, the line (None where no line applies), the missing joints
# and a fragment of the message.
BadMaker = Callable[[Path], tuple[Path, type[DataError], int | None, tuple[str, ...], str]]


def _good_text(layout: str = "cmu_mb", seconds: float = 0.5) -> str:
    """The text of a valid fixture BVH (half a second of walking)."""
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "x.bvh"
        write_fixture_bvh(path, walk_clip(seconds=seconds, fps=SOURCE_FPS, seed=5), layout)
        return path.read_text("utf-8")


def _corrupt_value(folder: Path):
    lines = _good_text().splitlines(keepends=True)
    motion_line = next(i for i, ln in enumerate(lines) if ln.startswith("Frame Time")) + 5
    parts = lines[motion_line].split()
    parts[7] = "1.2.3"
    lines[motion_line] = " ".join(parts) + "\n"
    path = folder / "03_01.bvh"
    path.write_text("".join(lines), "utf-8")
    return path, BvhError, motion_line + 1, (), "non-numeric"


def _corrupt_gzip(folder: Path):
    path = folder / "03_02.bvh.gz"
    path.write_bytes(b"\x1f\x8b" + bytes(range(256)) * 4)
    return path, BvhError, None, (), "corrupt gzip"


def _truncated(folder: Path):
    lines = _good_text().splitlines(keepends=True)
    kept = lines[: len(lines) - 20]
    path = folder / "03_03.bvh"
    path.write_text("".join(kept), "utf-8")
    return path, BvhError, len(kept), (), "truncated: header says"


def _truncated_mid_row(folder: Path):
    text = _good_text()
    path = folder / "03_04.bvh"
    cut = text[: len(text) - 40]
    path.write_text(cut, "utf-8")
    return path, BvhError, len(cut.splitlines()), (), "values, found"


def _truncated_hierarchy(folder: Path):
    lines = _good_text().splitlines(keepends=True)[:30]
    path = folder / "03_05.bvh"
    path.write_text("".join(lines), "utf-8")
    return path, BvhError, 30, (), "no MOTION section"


def _truncated_gzip(folder: Path):
    data = gzip.compress(_good_text().encode("utf-8"), mtime=0)
    path = folder / "03_06.bvh.gz"
    path.write_bytes(data[: len(data) // 2])
    return path, BvhError, None, (), "corrupt gzip"


def _not_bvh(folder: Path):
    path = folder / "notes.bvh"
    path.write_text("these are my notes, not motion\n", "utf-8")
    return path, BvhError, 1, (), "not a BVH file"


def _binary(folder: Path):
    path = folder / "image.bvh"
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(200))
    return path, BvhError, 1, (), "not a BVH file"


def _empty(folder: Path):
    path = folder / "empty.bvh"
    path.write_bytes(b"")
    return path, BvhError, 1, (), "not a BVH file"


def _tpose_only(folder: Path):
    # A CMU file whose only frame is the synthetic T-pose: no motion left.
    lines = _good_text().splitlines(keepends=True)
    at = next(i for i, ln in enumerate(lines) if ln.startswith("Frames:"))
    lines[at] = "Frames: 1\n"
    path = folder / "03_07.bvh"
    path.write_text("".join(lines[: at + 3]), "utf-8")  # Frames, Frame Time, the T-pose row
    return path, BvhError, None, (), "fewer than 2 frames"


def _unknown_rig(folder: Path):
    # The posecast layout with one joint renamed: closest rig is posecast, one joint short.
    text = _good_text("posecast").replace("LEFT_HAND", "L_Wrist")
    path = folder / "03_08.bvh"
    path.write_text(text, "utf-8")
    return path, RigError, None, ("LEFT_HAND",), "matches no known rig"


BAD_MAKERS: dict[str, BadMaker] = {
    "corrupt value": _corrupt_value,
    "corrupt gzip": _corrupt_gzip,
    "truncated": _truncated,
    "truncated mid-row": _truncated_mid_row,
    "truncated hierarchy": _truncated_hierarchy,
    "truncated gzip": _truncated_gzip,
    "not bvh": _not_bvh,
    "binary": _binary,
    "empty": _empty,
    "T-pose only": _tpose_only,
    "unknown rig": _unknown_rig,
}

GOOD_FOR_BAD = (
    Fixture("mb/01/01_01.bvh.gz", "cmu_mb", 0.5, 1, "1"),
    Fixture("daz/05/05_01.bvh", "cmu_daz", 0.5, 2, "5"),
)


def _tree_with_bad(root: Path, makers: list[BadMaker]) -> tuple[list[Path], list[tuple]]:
    good = [write_fixture(root, fx) for fx in GOOD_FOR_BAD]
    bad_dir = root / "incoming"
    bad_dir.mkdir()
    return good, [maker(bad_dir) for maker in makers]


@pytest.mark.parametrize("kind", list(BAD_MAKERS))
def test_bad_file_raises_a_data_error_naming_file_and_line(tmp_path: Path, kind: str) -> None:
    _, [(path, cls, line, missing, why)] = _tree_with_bad(tmp_path / "bvh", [BAD_MAKERS[kind]])
    with pytest.raises(DataError) as info:
        prepare(tmp_path / "bvh", tmp_path / "out", load_rigs())
    exc = info.value
    assert type(exc) is cls
    assert exc.file == str(path)
    assert str(path) in str(exc)
    assert why in str(exc)
    if cls is BvhError:
        assert exc.line == line
        if line is not None:
            assert f"{path}:{line}:" in str(exc)
    else:
        assert exc.missing_joints == missing
        assert all(j in str(exc) for j in missing)
    assert not (tmp_path / "out" / "manifest.json").exists()


def test_skip_bad_lists_every_bad_file_and_keeps_the_good_ones(tmp_path: Path) -> None:
    root = tmp_path / "bvh"
    good, bad = _tree_with_bad(root, list(BAD_MAKERS.values()))
    report = prepare(root, tmp_path / "out", load_rigs(), skip_bad=True)
    bad_paths = sorted(str(b[0]) for b in bad)
    assert sorted(f for f, _ in report.skipped) == bad_paths
    for f, why in report.skipped:
        assert why.startswith(f)  # the message names the file
    manifest = read_manifest(tmp_path / "out")
    assert sorted(s["file"] for s in manifest["skipped"]) == bad_paths
    sources = sorted(c["source"] for s in SPLITS for c in manifest["clips"][s])
    assert sources == sorted(str(p) for p in good)
    sequences = sum(manifest["splits"][s]["sequences"] for s in SPLITS)
    # Nothing silently dropped: every file found is either prepared or listed as skipped.
    assert sequences + len(report.skipped) == len(find_bvh_files(root)) == len(good) + len(bad)
    assert f"skipped {len(bad)} file(s):" in report.table()


def test_non_bvh_names_are_not_picked_up(tmp_path: Path) -> None:
    root = tmp_path / "bvh"
    good, _ = _tree_with_bad(root, [])
    (root / "README.txt").write_text("hello", "utf-8")
    (root / "01_09.bvh.bak").write_text("old", "utf-8")
    assert find_bvh_files(root) == sorted(good)


def test_an_empty_or_missing_directory_is_an_error(tmp_path: Path) -> None:
    with pytest.raises(DataError, match=r"no \.bvh"):
        prepare(tmp_path, tmp_path / "out", load_rigs())
    with pytest.raises(DataError, match="no such directory"):
        prepare(tmp_path / "absent", tmp_path / "out", load_rigs())


def test_forcing_the_wrong_rig_names_the_missing_joints(tmp_path: Path) -> None:
    root = tmp_path / "bvh"
    _tree_with_bad(root, [])
    with pytest.raises(RigError) as info:
        prepare(root, tmp_path / "out", load_rigs(), rig_name="cmu_daz")
    # The Daz file passes; the MotionBuilder one lacks the Daz joint names.
    assert info.value.file == str(root / "mb/01/01_01.bvh.gz")
    assert {"hip", "lHand", "rFoot"} <= set(info.value.missing_joints)
    with pytest.raises(RigError, match="unknown rig 'nope'"):
        prepare(root, tmp_path / "out", load_rigs(), rig_name="nope")
