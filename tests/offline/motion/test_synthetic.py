"""The procedural walk and the fixture BVH layouts the retargeting tests rely on."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from posecast.offline.motion.bvh import read_bvh
from posecast.offline.motion.clip import CanonicalClip
from posecast.offline.motion.rig import builtin_rigs
from posecast.offline.motion.synthetic import walk_clip
from posecast.skeleton import (
    NUM_JOINTS,
    REST_PELVIS_HEIGHT_M,
    REST_TOE_HEIGHT_M,
    TOES,
    Joint,
    reference_offsets,
)


def test_walk_shape(walk: CanonicalClip) -> None:
    assert walk.n_frames == 120
    assert walk.fps == 60.0
    assert walk.local_quat.shape == (120, NUM_JOINTS, 4)
    assert walk.root_pos.shape == (120, 3)
    np.testing.assert_allclose(np.linalg.norm(walk.local_quat, axis=-1), 1.0, atol=1e-12)
    np.testing.assert_array_equal(walk.offsets, reference_offsets())
    assert walk.seconds == pytest.approx(2.0)


def test_walk_is_deterministic_per_seed() -> None:
    a, b, c = walk_clip(1.0, seed=7), walk_clip(1.0, seed=7), walk_clip(1.0, seed=8)
    np.testing.assert_array_equal(a.local_quat, b.local_quat)
    np.testing.assert_array_equal(a.root_pos, b.root_pos)
    assert not np.allclose(a.local_quat, c.local_quat)


def test_walk_walks_pauses_and_stands_on_the_floor() -> None:
    clip = walk_clip(seconds=4.0, fps=60.0, seed=0)
    _, pos = clip.fk()
    toes = pos[:, list(TOES), 1].min(axis=1)
    assert np.percentile(toes, 5.0) == pytest.approx(REST_TOE_HEIGHT_M)
    assert toes.min() > -0.05  # no foot sinks far into the floor
    # It covers ground, forward (+Z) on the whole...
    travel = clip.root_pos[-1] - clip.root_pos[0]
    assert np.hypot(travel[0], travel[2]) > 2.0
    assert travel[2] > 0.0
    # ...at a walking speed, and stands still for the middle fifth.
    speed = np.linalg.norm(np.diff(clip.root_pos[:, [0, 2]], axis=0), axis=-1) * clip.fps
    assert 0.8 < speed.max() < 1.6
    t = np.arange(clip.n_frames - 1) / clip.fps
    assert np.all(speed[np.abs(t / 4.0 - 0.5) < 0.08] < 1e-9)
    # The pelvis stays near its rest height above the floor.
    pelvis_above_toes = clip.root_pos[:, 1] - toes
    assert np.all(np.abs(pelvis_above_toes - REST_PELVIS_HEIGHT_M) < 0.1)


def test_posecast_layout(fixture_bvh: Callable[..., Path], walk: CanonicalClip) -> None:
    bvh = read_bvh(fixture_bvh(walk, "posecast"))
    assert bvh.names == tuple(j.name for j in Joint)
    assert bvh.n_frames == walk.n_frames
    np.testing.assert_allclose(bvh.offsets(), reference_offsets(), atol=1e-6)
    assert all(j.rotation_order == "ZYX" for j in bvh.joints)


def test_cmu_mb_layout(fixture_bvh: Callable[..., Path], walk: CanonicalClip) -> None:
    rig = {r.name: r for r in builtin_rigs()}["cmu_mb"]
    bvh = read_bvh(fixture_bvh(walk, "cmu_mb"))
    assert bvh.n_frames == walk.n_frames + 1
    mapped = {ref.joint for ref in rig.joints.values()}
    extras = set(bvh.names) - mapped
    assert extras == {"LHipJoint", "RHipJoint", "Neck", "LeftShoulder", "RightShoulder"}
    # Zero-offset inserts between a mapped joint and its mapped parent.
    for name in extras:
        joint = bvh.joints[bvh.index(name)]
        assert joint.offset == (0.0, 0.0, 0.0)
    assert bvh.joints[bvh.index("LeftUpLeg")].parent == bvh.index("LHipJoint")
    # Length unit: the rig's, so the reference thigh bone reads 0.43 m / unit_m.
    shin = bvh.joints[bvh.index("LeftLeg")].offset
    assert shin[1] == pytest.approx(-0.43 / rig.unit_m, abs=1e-5)
    # The first frame is the T-pose: every rotation channel zero.
    rot, _ = bvh.local_transforms()
    np.testing.assert_allclose(rot[0], np.broadcast_to(np.eye(3), rot[0].shape), atol=1e-6)
    assert not np.allclose(rot[1:, bvh.index("Neck")], np.eye(3), atol=1e-3)


def test_cmu_daz_layout(fixture_bvh: Callable[..., Path], walk: CanonicalClip) -> None:
    bvh = read_bvh(fixture_bvh(walk, "cmu_daz", gz=True))
    assert bvh.n_frames == walk.n_frames + 1
    assert "lToe" not in bvh.names and len(bvh.names) == NUM_JOINTS - 2
    assert all(j.rotation_order == "ZXY" for j in bvh.joints)
    # Centimetres; the toe is the foot's End Site.
    assert bvh.joints[bvh.index("abdomen")].offset == pytest.approx((0.0, 10.0, 0.0))
    np.testing.assert_allclose(bvh.joints[bvh.index("lFoot")].end_site, [0.0, -6.0, 13.0])
