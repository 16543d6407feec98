"""The subject-wise split (posecast.offline.dataset.split)."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import pytest

from posecast.errors import ConfigError
from posecast.offline.dataset.split import (
    SPLITS,
    hashed_split,
    load_split_table,
    split_of,
    subject_of,
)
from posecast.offline.dataset.store import read_manifest

# The subjects in ../shared/data (see its README): CMU numbers of the BVH set, the
# CMU numbers new with the ASF/AMC set, and the HDM05 actor codes.
CMU_SUBJECTS = {"1", "3", "5", "6", "7", "8", "9", "10", "12", "13", "14", "60", "61", "94", "135"}
CMU_AMC_SUBJECTS = {"16", "17", "29", "35", "49", "91", "127", "131"}
HDM05_ACTORS = {"bd", "bk", "dg", "mm", "tr"}
# Minutes of motion of the new subjects (../shared/data/index_amc.csv)
NEW_MINUTES = {
    "16": 2.46, "17": 0.45, "29": 9.93, "35": 0.19, "49": 3.12, "91": 1.61, "127": 1.63,
    "131": 2.45, "bd": 1.84, "bk": 2.49, "dg": 1.88, "mm": 1.67, "tr": 1.98,
}  # fmt: skip


def test_committed_table_loads_and_lists_the_staged_subjects() -> None:
    table = load_split_table()
    assert set(table) == CMU_SUBJECTS | CMU_AMC_SUBJECTS | HDM05_ACTORS
    assert set(table.values()) == set(SPLITS)  # every split has subjects


def test_the_asf_amc_subjects_keep_the_test_split_clean() -> None:
    table = load_split_table()
    # 14 (BVH and ASF/AMC trials) stays in test, 135 in train; the new subjects go to
    # train and val only, about 85/15 by duration.
    assert table["14"] == "test" and table["135"] == "train"
    assert {table[s] for s in NEW_MINUTES} == {"train", "val"}
    val = sum(m for s, m in NEW_MINUTES.items() if table[s] == "val")
    assert val / sum(NEW_MINUTES.values()) == pytest.approx(0.15, abs=0.02)


def test_salsa_partners_share_a_split() -> None:
    table = load_split_table()
    assert table["60"] == table["61"]


def test_a_subject_is_in_exactly_one_split() -> None:
    # The table is a mapping, so this holds by construction; the file must not
    # sneak a duplicate key past json (which keeps the last one silently).
    from posecast.offline.dataset import split as split_module

    path = Path(split_module.__file__).with_name("split.json")
    pairs = json.loads(path.read_text("utf-8"), object_pairs_hook=lambda kv: kv)
    subjects = dict(pairs)["subjects"]
    keys = [k for k, _ in subjects]
    assert len(keys) == len(set(keys))


def test_every_clip_of_a_subject_lands_in_one_split(prepared, good_files) -> None:
    out, _ = prepared
    manifest = read_manifest(out)
    seen: dict[str, set[str]] = {}
    for split in SPLITS:
        for clip in manifest["clips"][split]:
            seen.setdefault(clip["subject"], set()).add(split)
    assert set(seen) == {fx.subject for fx in good_files}
    # subject 1 has clips on both rigs, in two folders
    assert sum(fx.subject == "1" for fx in good_files) >= 3
    table = load_split_table()
    for subject, splits in seen.items():
        assert splits == {split_of(subject, table)}, subject
    # and the per-split subject lists in the statistics never overlap
    listed = [s for split in SPLITS for s in manifest["splits"][split]["subjects"]]
    assert len(listed) == len(set(listed))


def test_table_subjects_take_their_listed_split_others_the_hash() -> None:
    table = {"1": "test"}
    assert split_of("1", table) == "test"
    assert split_of("2", table) == hashed_split("2")


def test_hashed_split_is_stable() -> None:
    # Pinned values: changing the hash would silently move users' subjects between
    # splits and leak test subjects into training.
    assert hashed_split("alice") == "val"
    assert hashed_split("11") == "test"
    assert hashed_split("frank") == "test"
    assert hashed_split("bob") == "train"
    assert [hashed_split("alice") for _ in range(3)] == ["val"] * 3


def test_hashed_split_is_about_80_10_10() -> None:
    counts = Counter(hashed_split(f"subject-{i}") for i in range(5000))
    assert set(counts) == set(SPLITS)
    assert counts["train"] / 5000 == pytest.approx(0.8, abs=0.03)
    assert counts["val"] / 5000 == pytest.approx(0.1, abs=0.02)
    assert counts["test"] / 5000 == pytest.approx(0.1, abs=0.02)


@pytest.mark.parametrize(
    ("path", "subject"),
    [
        ("x/05_02.bvh.gz", "5"),
        ("cmu_bvh/daz/135/135_03.bvh.gz", "135"),
        ("01_01.bvh", "1"),
        ("captures/alice/take1.bvh", "alice"),
        ("captures/bob/05_02_retake.bvh", "bob"),
        ("cmu_amc/135/135_02.amc.gz", "135"),
        ("hdm05_amc/bd/HDM_bd_squat1Reps_001_120.amc.gz", "bd"),
        ("elsewhere/HDM_mm_sneak2StepsLStart_002_120.amc", "mm"),
    ],
)
def test_subject_of(path: str, subject: str) -> None:
    assert subject_of(path) == subject


def test_a_custom_table_is_read_and_checked(tmp_path: Path) -> None:
    good = tmp_path / "split.json"
    good.write_text(json.dumps({"subjects": {"alice": "test", "7": "train"}}), "utf-8")
    assert load_split_table(good) == {"alice": "test", "7": "train"}


@pytest.mark.parametrize(
    ("content", "why"),
    [
        (json.dumps({"subjects": {"alice": "holdout"}}), "unknown split names"),
        (json.dumps({"people": {}}), "not a split table"),
        (json.dumps({"subjects": ["alice"]}), "not a split table"),
        ("{not json", "not a split table"),
    ],
)
def test_a_bad_custom_table_is_a_config_error(tmp_path: Path, content: str, why: str) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text(content, "utf-8")
    with pytest.raises(ConfigError, match=why) as info:
        load_split_table(bad)
    assert str(bad) in str(info.value)


def test_a_missing_custom_table_is_a_config_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot read split table"):
        load_split_table(tmp_path / "absent.json")
