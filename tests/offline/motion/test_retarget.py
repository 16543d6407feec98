"""Retargeting: every rig layout of the same walk comes back as that walk, at 60 fps."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from posecast.errors import BvhError
from posecast.geometry.fk import fk_mat
from posecast.geometry.rotations import aa2quat, normalize
from posecast.offline.motion.bvh import read_bvh, write_bvh
from posecast.offline.motion.clip import CanonicalClip
from posecast.offline.motion.resample import resample
from posecast.offline.motion.retarget import TARGET_FPS, align_floor, retarget
from posecast.offline.motion.rig import detect_rig, load_rigs
from posecast.offline.motion.synthetic import walk_clip
from posecast.skeleton import (
    JOINT_NAMES,
    PARENTS,
    REST_TOE_HEIGHT_M,
    TOES,
    Joint,
    reference_offsets,
)

LAYOUTS = ("posecast", "cmu_mb", "cmu_daz")
MM = 1e-3


@pytest.fixture
def walk120() -> CanonicalClip:
    """The walk as mocap is recorded, at 120 fps."""
    return walk_clip(seconds=2.0, fps=120.0, seed=1)


def through_file(
    fixture_bvh: Callable[..., Path], clip: CanonicalClip, layout: str, **kwargs: float
) -> CanonicalClip:
    """Write ``clip`` in ``layout``, read it back, detect its rig and retarget it."""
    bvh = read_bvh(fixture_bvh(clip, layout, gz=layout == "cmu_daz"))
    rig = detect_rig(bvh, load_rigs())
    assert rig.name == layout
    return retarget(bvh, rig, name="walk", subject="s01", **kwargs)


@pytest.mark.parametrize("layout", LAYOUTS)
def test_retarget_recovers_the_walk(
    fixture_bvh: Callable[..., Path], walk120: CanonicalClip, layout: str
) -> None:
    out = through_file(fixture_bvh, walk120, layout)
    want = resample(walk120, TARGET_FPS)
    assert out.fps == TARGET_FPS == 60.0
    assert (out.name, out.subject, out.rig) == ("walk", "s01", layout)
    assert out.n_frames == want.n_frames
    np.testing.assert_allclose(np.linalg.norm(out.local_quat, axis=-1), 1.0, atol=1e-12)
    np.testing.assert_allclose(out.fk()[1], want.fk()[1], atol=1 * MM)


@pytest.mark.parametrize("layout", LAYOUTS)
def test_tpose_frame_is_dropped(
    fixture_bvh: Callable[..., Path], walk120: CanonicalClip, layout: str
) -> None:
    """CMU files start with a T-pose frame; retargeting at the file's own rate drops
    exactly that frame and keeps every other one as it is."""
    bvh = read_bvh(fixture_bvh(walk120, layout))
    tpose = layout != "posecast"
    assert bvh.n_frames == walk120.n_frames + tpose
    out = retarget(bvh, detect_rig(bvh, load_rigs()), name="w", subject="s", fps=120.0)
    assert out.fps == 120.0
    assert out.n_frames == walk120.n_frames
    np.testing.assert_allclose(out.fk()[1], walk120.fk()[1], atol=1 * MM)


@pytest.mark.parametrize("layout", LAYOUTS)
def test_last_frame_survives_frame_time_rounding(
    fixture_bvh: Callable[..., Path], layout: str
) -> None:
    """241 frames at 120 fps last exactly 2 s: 121 frames at 60 fps, the last one
    included, although the file's frame time (0.00833333) is not exactly 1/120."""
    clip = walk_clip(seconds=241 / 120, fps=120.0, seed=2)
    assert clip.n_frames == 241
    out = through_file(fixture_bvh, clip, layout)
    want = resample(clip, 60.0)
    assert out.n_frames == want.n_frames == 121
    np.testing.assert_allclose(out.fk()[1], want.fk()[1], atol=1 * MM)


def test_root_path_scales_to_the_canonical_legs(tmp_path: Path) -> None:
    """A performer 10 % taller walks 10 % further; on canonical legs the stride fits."""
    clip = walk_clip(seconds=1.0, fps=60.0, seed=5)
    path = tmp_path / "tall.bvh"
    write_bvh(
        path,
        names=JOINT_NAMES,
        parents=PARENTS,
        offsets=reference_offsets() * 1.1,
        root_pos=clip.root_pos * 1.1,
        local_quat=clip.local_quat,
        frame_time_s=1.0 / clip.fps,
    )
    bvh = read_bvh(path)
    out = retarget(bvh, detect_rig(bvh, load_rigs()), name="tall", subject="s")
    np.testing.assert_allclose(out.root_pos, clip.root_pos, atol=1 * MM)
    np.testing.assert_allclose(out.fk()[1], clip.fk()[1], atol=1 * MM)


def test_too_short_after_the_tpose(fixture_bvh: Callable[..., Path], walk: CanonicalClip) -> None:
    one = walk.with_(local_quat=walk.local_quat[:1], root_pos=walk.root_pos[:1])
    bvh = read_bvh(fixture_bvh(one, "cmu_mb"))
    assert bvh.n_frames == 2
    with pytest.raises(BvhError, match="fewer than 2 frames") as info:
        retarget(bvh, detect_rig(bvh, load_rigs()), name="x", subject="s")
    assert info.value.file == bvh.source


def test_align_floor_puts_the_feet_on_the_floor(walk: CanonicalClip) -> None:
    lifted = walk.with_(root_pos=walk.root_pos + np.array([0.0, 0.5, 0.0]))
    out = align_floor(lifted)
    toes = out.fk()[1][:, list(TOES), 1].min(axis=1)
    assert np.percentile(toes, 5.0) == pytest.approx(REST_TOE_HEIGHT_M)
    np.testing.assert_allclose(out.root_pos, walk.root_pos, atol=1e-12)
    np.testing.assert_array_equal(out.local_quat, walk.local_quat)


def test_bones_point_along_the_source_bones(tmp_path: Path) -> None:
    """An unmapped joint that bends mid-thigh (like CMU's LowerBack mid-spine) changes
    where the thigh bone points; the canonical thigh must point there too."""
    clip = walk_clip(seconds=1.0, fps=60.0, seed=7)
    names = [*JOINT_NAMES, "LeftThighBend"]
    parents = [*PARENTS, int(Joint.LEFT_THIGH)]
    parents[Joint.LEFT_SHIN] = len(names) - 1
    offsets = np.vstack([reference_offsets(), [0.0, -0.20, 0.0]])
    offsets[Joint.LEFT_SHIN] = [0.0, -0.23, 0.0]
    t = np.arange(clip.n_frames) / clip.fps
    bend = aa2quat(np.outer(0.4 * np.sin(3.0 * t), [1.0, 0.0, 0.0]))  # (F, 4)
    path = tmp_path / "bent.bvh"
    write_bvh(
        path,
        names=names,
        parents=parents,
        offsets=offsets,
        root_pos=clip.root_pos,
        local_quat=np.concatenate([clip.local_quat, bend[:, None]], axis=1),
        frame_time_s=1.0 / clip.fps,
    )
    bvh = read_bvh(path)
    out = retarget(bvh, detect_rig(bvh, load_rigs()), name="bent", subject="s")
    rot, trans = bvh.local_transforms()
    src = fk_mat(rot, np.zeros(3), trans, bvh.parents)[1]
    _, pos = out.fk()
    for joint, child in ((Joint.LEFT_THIGH, Joint.LEFT_SHIN), (Joint.LEFT_SHIN, Joint.LEFT_FOOT)):
        want = normalize(src[:, bvh.index(child.name)] - src[:, bvh.index(joint.name)])
        np.testing.assert_allclose(normalize(pos[:, child] - pos[:, joint]), want, atol=1e-6)
