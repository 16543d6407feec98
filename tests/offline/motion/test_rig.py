"""Rig maps: the built-in rigs, detection, missing joints, bad JSON, user rigs."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from posecast.errors import RigError
from posecast.offline.motion.bvh import read_bvh, write_bvh
from posecast.offline.motion.clip import CanonicalClip
from posecast.offline.motion.retarget import retarget
from posecast.offline.motion.rig import (
    SourceRef,
    builtin_rigs,
    detect_rig,
    load_rig_file,
    load_rigs,
    rig_from_dict,
)
from posecast.offline.motion.synthetic import walk_clip
from posecast.skeleton import JOINT_NAMES, PARENTS, Joint, reference_offsets

LAYOUTS = ("cmu_daz", "cmu_mb", "posecast")
# The built-in rigs: the BVH layouts above and the ASF/AMC one (see test_acclaim.py).
BUILTIN = (*LAYOUTS, "cmu_asf")


@pytest.fixture
def short_walk() -> CanonicalClip:
    return walk_clip(seconds=0.5, fps=60.0, seed=3)


def posecast_rig_dict() -> dict[str, object]:
    """The built-in ``posecast`` rig as plain JSON data, to be spoiled by a test."""
    return {
        "name": "posecast",
        "unit_m": 1.0,
        "joints": {name: name for name in JOINT_NAMES},
    }


def test_builtin_rigs_load() -> None:
    rigs = {r.name: r for r in builtin_rigs()}
    assert sorted(rigs) == sorted(BUILTIN)
    for rig in rigs.values():
        assert set(rig.joints) == set(Joint)
        assert rig.unit_m > 0
        assert rig.description
    assert rigs["cmu_mb"].first_frame_is_tpose and rigs["cmu_daz"].first_frame_is_tpose
    assert not rigs["posecast"].first_frame_is_tpose
    assert not rigs["posecast"].align_floor
    assert rigs["cmu_daz"].unit_m == pytest.approx(0.01)
    assert rigs["cmu_daz"].joints[Joint.LEFT_TOE] == SourceRef("lFoot", end_site=True)
    assert rigs["cmu_mb"].joints[Joint.LEFT_TOE] == SourceRef("LeftToeBase")


def test_source_ref_parse() -> None:
    assert SourceRef.parse("rFoot.end") == SourceRef("rFoot", True)
    assert SourceRef.parse("Hips") == SourceRef("Hips", False)


@pytest.mark.parametrize("layout", LAYOUTS)
def test_detect_rig_picks_the_layout(
    fixture_bvh: Callable[..., Path], short_walk: CanonicalClip, layout: str
) -> None:
    bvh = read_bvh(fixture_bvh(short_walk, layout))
    rigs = load_rigs()
    rig = detect_rig(bvh, rigs)
    assert rig.name == layout
    assert rig.missing_joints(bvh) == []
    assert detect_rig(bvh, rigs, name=layout) is rig


def test_missing_joint_is_named(
    fixture_bvh: Callable[..., Path], short_walk: CanonicalClip, tmp_path: Path
) -> None:
    text = fixture_bvh(short_walk, "posecast").read_text()
    path = tmp_path / "renamed_hand.bvh"
    path.write_text(text.replace("JOINT LEFT_HAND", "JOINT LEFT_PAW"))
    bvh = read_bvh(path)
    with pytest.raises(RigError, match="closest is 'posecast'") as info:
        detect_rig(bvh, load_rigs())
    assert info.value.missing_joints == ("LEFT_HAND",)
    assert info.value.file == str(path)
    assert "missing joints: LEFT_HAND" in str(info.value)
    with pytest.raises(RigError) as named:
        detect_rig(bvh, load_rigs(), name="posecast")
    assert named.value.missing_joints == ("LEFT_HAND",)


def test_missing_end_site_is_named(
    fixture_bvh: Callable[..., Path], short_walk: CanonicalClip
) -> None:
    """cmu_daz puts the toe at the foot's End Site: a foot without one does not fit."""
    bvh = read_bvh(fixture_bvh(short_walk, "cmu_daz"))
    foot = bvh.index("lFoot")
    joints = list(bvh.joints)
    joints[foot] = dataclasses.replace(joints[foot], end_site=None)
    bvh = dataclasses.replace(bvh, joints=tuple(joints))
    with pytest.raises(RigError) as info:
        detect_rig(bvh, load_rigs(), name="cmu_daz")
    assert info.value.missing_joints == ("lFoot.end",)


def test_unknown_rig_name_and_no_rigs(
    fixture_bvh: Callable[..., Path], short_walk: CanonicalClip
) -> None:
    bvh = read_bvh(fixture_bvh(short_walk))
    with pytest.raises(RigError, match="unknown rig 'mixamo'"):
        detect_rig(bvh, load_rigs(), name="mixamo")
    with pytest.raises(RigError, match="no rigs"):
        detect_rig(bvh, [])


def spoil_unknown_joint(d: dict) -> None:
    d["joints"]["TAIL"] = "Tail"


def spoil_missing_joint(d: dict) -> None:
    del d["joints"]["HEAD"]


def spoil_zero_unit(d: dict) -> None:
    d["unit_m"] = 0.0


def spoil_negative_unit(d: dict) -> None:
    d["unit_m"] = -0.01


def spoil_text_unit(d: dict) -> None:
    d["unit_m"] = "centimetres"


def spoil_no_name(d: dict) -> None:
    del d["name"]


def spoil_joint_list(d: dict) -> None:
    d["joints"] = list(d["joints"])


@pytest.mark.parametrize(
    ("spoil", "message"),
    [
        (spoil_unknown_joint, "unknown canonical joints ['TAIL']"),
        (spoil_missing_joint, "must map every canonical joint"),
        (spoil_zero_unit, "'unit_m' must be positive"),
        (spoil_negative_unit, "'unit_m' must be positive"),
        (spoil_text_unit, "lacks a valid field"),
        (spoil_no_name, "lacks a valid field"),
        (spoil_joint_list, "'joints' must be an object"),
    ],
)
def test_bad_rig_json(tmp_path: Path, spoil: Callable[[dict], None], message: str) -> None:
    data = posecast_rig_dict()
    rig_from_dict(data, "ok.json")  # unspoilt, it loads
    spoil(data)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(RigError) as info:
        load_rig_file(path)
    assert message in str(info.value)
    assert info.value.file == str(path)


def test_missing_canonical_joint_is_listed() -> None:
    data = posecast_rig_dict()
    spoil_missing_joint(data)
    with pytest.raises(RigError) as info:
        rig_from_dict(data, "rig.json")
    assert info.value.missing_joints == ("HEAD",)


@pytest.mark.parametrize(("text", "message"), [("{not json", "cannot read"), ("[]", "object")])
def test_unreadable_rig_file(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "rig.json"
    path.write_text(text)
    with pytest.raises(RigError, match=message):
        load_rig_file(path)


def renamed(name: str) -> str:
    """A naming scheme no built-in rig knows: ``LEFT_UPPER_ARM`` -> ``BoneLeftUpperArm``."""
    return "Bone" + name.title().replace("_", "")


def test_user_rig_is_config_not_code(tmp_path: Path) -> None:
    """A new skeleton needs one JSON file; its BVH then detects and retargets."""
    rig_dir = tmp_path / "rigs"
    rig_dir.mkdir()
    rig_json = {
        "name": "renamed",
        "description": "the canonical skeleton under other names, in centimetres",
        "unit_m": 0.01,
        "first_frame_is_tpose": False,
        "align_floor": False,
        "joints": {name: renamed(name) for name in JOINT_NAMES},
    }
    (rig_dir / "renamed.json").write_text(json.dumps(rig_json))
    clip = walk_clip(seconds=1.0, fps=60.0, seed=4)
    path = tmp_path / "renamed.bvh"
    write_bvh(
        path,
        names=[renamed(n) for n in JOINT_NAMES],
        parents=PARENTS,
        offsets=reference_offsets(),
        root_pos=clip.root_pos,
        local_quat=clip.local_quat,
        frame_time_s=1.0 / clip.fps,
        scale=100.0,
    )
    bvh = read_bvh(path)
    with pytest.raises(RigError):
        detect_rig(bvh, load_rigs())
    rigs = load_rigs([rig_dir])
    assert sorted(r.name for r in rigs) == sorted((*BUILTIN, "renamed"))
    rig = detect_rig(bvh, rigs)
    assert rig.name == "renamed"
    out = retarget(bvh, rig, name="r", subject="s", fps=60.0)
    assert out.rig == "renamed"
    assert out.n_frames == clip.n_frames
    np.testing.assert_allclose(out.fk()[1], clip.fk()[1], atol=1e-3)


def test_user_rig_replaces_a_builtin_of_the_same_name(tmp_path: Path) -> None:
    data = posecast_rig_dict()
    data["unit_m"] = 0.001
    (tmp_path / "mm.json").write_text(json.dumps(data))
    rigs = {r.name: r for r in load_rigs([tmp_path])}
    assert len(rigs) == len(BUILTIN)
    assert rigs["posecast"].unit_m == pytest.approx(0.001)
