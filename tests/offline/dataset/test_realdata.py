"""Checks on the real CMU clips in ../shared/data (skipped when the data is absent).

The data is never committed (see docs/data.md), so these run only on a machine that
has it next to the repository: ``<repo>/../shared/data/cmu_bvh``.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from posecast.geometry.rotations import quat2yaw, quat_apply, yaw2quat
from posecast.offline.dataset.frames import derive_frames
from posecast.offline.dataset.split import load_split_table, subject_of
from posecast.offline.motion.bvh import read_bvh
from posecast.offline.motion.retarget import retarget
from posecast.offline.motion.rig import detect_rig, load_rigs
from posecast.skeleton import TOES, Joint
from posecast.tracking.features import FEATURE_NAMES, TrackerSlot

REPO_ROOT = Path(__file__).resolve().parents[3]
DATA = REPO_ROOT.parent / "shared" / "data"
CMU_BVH = DATA / "cmu_bvh"

pytestmark = [
    pytest.mark.realdata,
    pytest.mark.skipif(not CMU_BVH.is_dir(), reason=f"CMU data not found at {CMU_BVH}"),
]

# One file per rig: a walk (MotionBuilder rig) and reaching / tiptoeing (Daz rig).
SAMPLES = [("mb/07/07_01.bvh.gz", "cmu_mb"), ("daz/13/13_10.bvh.gz", "cmu_daz")]


def _index_rows() -> list[dict[str, str]]:
    with (DATA / "index.csv").open(newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


@pytest.fixture(scope="module", params=SAMPLES, ids=[s[1] for s in SAMPLES])
def real_clip(request):
    rel, rig_name = request.param
    path = CMU_BVH / rel
    bvh = read_bvh(path)
    rig = detect_rig(bvh, load_rigs())
    assert rig.name == rig_name
    clip = retarget(bvh, rig, name=path.name.split(".")[0], subject=subject_of(path))
    row = next(r for r in _index_rows() if r["file"] == f"cmu_bvh/{rel}")
    return clip, row


def test_t_pose_dropped_and_resampled_to_60_fps(real_clip) -> None:
    clip, row = real_clip
    assert clip.fps == 60.0
    # index.csv counts the synthetic T-pose frame; the clip does not.
    motion_frames = int(row["frames"]) - 1
    assert abs(clip.n_frames - motion_frames * 60.0 / float(row["fps"])) <= 1.0


def test_plausible_anatomy(real_clip) -> None:
    clip, _ = real_clip
    _, pos = clip.fk()
    head_y = np.median(pos[:, Joint.HEAD, 1])
    assert 1.4 <= head_y <= 1.75
    pelvis_y = np.median(pos[:, Joint.PELVIS, 1])
    assert 0.8 <= pelvis_y <= 1.05
    for toe in TOES:
        # feet on the floor: each toe's low percentile is near the toe rest height
        assert -0.01 <= np.percentile(pos[:, toe, 1], 5) <= 0.08, toe.name
    assert np.percentile(pos[:, list(TOES), 1], 0.5) > -0.05  # nothing deep underground


def test_left_is_plus_x_in_the_character_frame(real_clip) -> None:
    clip, _ = real_clip
    frames = derive_frames(clip)
    feat = frames["features"]
    assert np.median(feat[:, FEATURE_NAMES.index("LEFT_HAND.px")]) > 0.05
    assert np.median(feat[:, FEATURE_NAMES.index("RIGHT_HAND.px")]) < -0.05
    # and the left foot at +X: the legs are not swapped either
    _, wp = clip.fk()
    waist_quat = frames["tracker_quat"][:, TrackerSlot.WAIST].astype(np.float64)
    inv_yaw = yaw2quat(-quat2yaw(waist_quat))
    for toe, sign in ((Joint.LEFT_TOE, 1.0), (Joint.RIGHT_TOE, -1.0)):
        local = quat_apply(inv_yaw, wp[:, toe] - wp[:, Joint.PELVIS])
        assert sign * np.median(local[:, 0]) > 0.03, toe.name
    contact = frames["contacts"].mean()
    assert 0.1 < contact < 0.95


def test_committed_split_covers_every_subject_in_the_index() -> None:
    rows = _index_rows()
    assert rows, "index.csv is empty"
    table = load_split_table()
    subjects = {str(int(r["subject"])) for r in rows}
    assert subjects <= set(table), f"not in split.json: {sorted(subjects - set(table))}"
    for r in rows:
        assert subject_of(r["file"]) == str(int(r["subject"])), r["file"]
    assert table["60"] == table["61"]
    # every split gets real clips
    assert {table[s] for s in subjects} == {"train", "val", "test"}
