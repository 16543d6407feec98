"""Float32 FK of the engine's hot path against the float64 reference FK."""

from __future__ import annotations

import numpy as np

from posecast.body.batch_fk import fk32, pelvis_from_head32, r6d2mat32
from posecast.geometry.fk import fk_mat
from posecast.geometry.rotations import normalize, quat2mat, r6d2mat
from posecast.skeleton import NUM_JOINTS, NUM_ROTATIONS, reference_offsets
from posecast.tracking.layouts import pelvis_from_head


def test_r6d2mat32_matches_float64(rng: np.random.Generator) -> None:
    d = rng.normal(size=(64, 6)).astype(np.float32)
    m = r6d2mat32(d)
    assert m.dtype == np.float32
    np.testing.assert_allclose(m, r6d2mat(d.astype(np.float64)), atol=1e-5)


def test_fk32_matches_fk_mat(rng: np.random.Generator) -> None:
    """Arbitrary (not orthonormal) 6D vectors, random root rotations and positions."""
    B = 32
    rot6d = rng.normal(size=(B, NUM_ROTATIONS * 6)).astype(np.float32)
    root_mat = quat2mat(normalize(rng.normal(size=(B, 4)))).astype(np.float32)
    root_pos = rng.normal(size=(B, 3)).astype(np.float32)
    wm, wp = fk32(rot6d, root_mat, root_pos)
    assert wm.shape == (B, NUM_JOINTS, 3, 3)
    assert wp.shape == (B, NUM_JOINTS, 3)
    assert wm.dtype == wp.dtype == np.float32

    local = np.concatenate(
        [
            root_mat.astype(np.float64)[:, None],
            r6d2mat(rot6d.astype(np.float64).reshape(B, NUM_ROTATIONS, 6)),
        ],
        axis=1,
    )  # (B, 19, 3, 3)
    ref_m, ref_p = fk_mat(local, root_pos.astype(np.float64), reference_offsets())
    np.testing.assert_allclose(wm, ref_m, atol=1e-4)
    np.testing.assert_allclose(wp, ref_p, atol=1e-4)


def test_fk32_accepts_joint_shaped_input(rng: np.random.Generator) -> None:
    rot6d = rng.normal(size=(4, NUM_ROTATIONS, 6)).astype(np.float32)
    root_mat = np.broadcast_to(np.eye(3, dtype=np.float32), (4, 3, 3))
    root_pos = np.zeros((4, 3), np.float32)
    a = fk32(rot6d, root_mat, root_pos)
    b = fk32(rot6d.reshape(4, -1), root_mat, root_pos)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])


def test_pelvis_from_head32_matches_the_float64_reference() -> None:
    rng = np.random.default_rng(5)
    G, n = 7, 13
    root = rng.standard_normal((G * n, 9)).astype(np.float32)
    head_pos = rng.standard_normal((G, 3))
    q = rng.standard_normal((G, 4))
    head_quat = q / np.linalg.norm(q, axis=1, keepdims=True)
    mats, places = pelvis_from_head32(root, head_pos, head_quat)
    want_m, want_p = pelvis_from_head(
        root, np.repeat(head_pos, n, axis=0), np.repeat(head_quat, n, axis=0)
    )
    assert mats.dtype == places.dtype == np.float32
    assert np.abs(mats - want_m).max() < 1e-6 and np.abs(places - want_p).max() < 1e-5
