"""Where the shown pose's heaviest passes run (posecast.body.passes): the numpy reference
of :class:`Passes` is FK with the display contact IK, the upper-body pass and the hinges
exactly as their own modules compute them, and the contact-IK state steps in place
(that each backend's pool is held to it is ``test_pipeline.py``'s)."""

from __future__ import annotations

import numpy as np

from posecast.body.batch_fk import fk32
from posecast.body.hinge import ELBOW_LIMBS, KNEE_LIMBS, hinge_quat
from posecast.body.ik import MAX_DRIFT_M, RELEASE_FRAMES, ContactIK
from posecast.body.passes import NumpyPasses, PoolIK
from posecast.body.upper_ik import solve_upper_body
from posecast.geometry.rotations import mat2quat, mat2r6d
from posecast.skeleton import Joint

E = 3


def _decoded(seed: int, frames: int, noise: float = 0.05) -> tuple[np.ndarray, ...]:
    """``frames`` of ``E`` rows: 6D rotations near rest, contacts, pelvis walking +z."""
    rng = np.random.default_rng(seed)
    rest = np.broadcast_to(mat2r6d(np.eye(3)), (frames, E, 18, 6)).reshape(frames, E, 108)
    rot = (rest + rng.normal(scale=noise, size=rest.shape)).astype(np.float32)
    contacts = np.ones((frames, E, 2), np.float32)
    contacts[:, 0] = 0.0  # row 0 never in contact
    root_mat = np.broadcast_to(np.eye(3, dtype=np.float32), (frames, E, 3, 3)).copy()
    root_pos = np.zeros((frames, E, 3), np.float32)
    root_pos[..., 1] = 0.95
    root_pos[..., 2] = 0.01 * np.arange(frames)[:, None]  # 1 cm a frame forward
    return rot, contacts, root_mat, root_pos


def test_the_state_of_n_rows_that_hold_no_foot() -> None:
    ik = PoolIK.zeros(4)
    assert ik.locked.shape == ik.suppressed.shape == ik.release.shape == (4, 2)
    assert ik.lock_pos.shape == (4, 2, 3)
    assert (ik.locked.dtype, ik.release.dtype, ik.lock_pos.dtype) == (
        np.bool_,
        np.int64,
        np.float64,
    )
    assert not ik.locked.any() and not ik.lock_pos.any() and not ik.release.any()
    p = NumpyPasses()
    assert (p.release_frames, p.max_drift_m) == (RELEASE_FRAMES, MAX_DRIFT_M)


def test_emit_is_fk_then_the_display_contact_ik_stepped_in_place() -> None:
    rot, con, root_mat, root_pos = _decoded(0, 6)
    passes = NumpyPasses(release_frames=5, max_drift_m=0.2)
    ik = PoolIK.zeros(E)
    ref = ContactIK.zeros(E, 5, 0.2)
    for t in range(6):
        wp, quats = passes.emit(rot[t], con[t], root_mat[t], root_pos[t], ik)
        wm, want_p = fk32(rot[t], root_mat[t], root_pos[t])
        assert wm is not None
        ref.step(wm, want_p, con[t])
        assert wp.dtype == quats.dtype == np.float32
        assert wp.shape == (E, 19, 3) and quats.shape == (E, 19, 4)
        np.testing.assert_array_equal(wp, want_p)
        np.testing.assert_allclose(quats, mat2quat(wm), atol=1e-6)
        np.testing.assert_array_equal(ik.locked, ref.locked)
        np.testing.assert_array_equal(ik.lock_pos, ref.lock_pos)
    assert not ik.locked[0].any() and ik.locked[1:].all()  # the rows in contact locked
    ankles = [Joint.LEFT_FOOT, Joint.RIGHT_FOOT]
    # a locked foot stays where it was planted while the pelvis walks on
    np.testing.assert_allclose(wp[1:, ankles], ik.lock_pos[1:], atol=2e-3)
    _, free = fk32(rot[5], root_mat[5], root_pos[5])
    assert np.abs(free[1:, ankles, 2] - wp[1:, ankles, 2]).max() > 0.02


def test_the_upper_body_pass_and_the_hinges_are_their_modules() -> None:
    rot, con, root_mat, root_pos = _decoded(1, 1, noise=0.4)  # bent, twisted limbs
    passes = NumpyPasses()
    wp, quats = passes.emit(rot[0], con[0], root_mat[0], root_pos[0], PoolIK.zeros(E))
    assert passes.upper_body is solve_upper_body
    for limbs in (KNEE_LIMBS, ELBOW_LIMBS):
        got, want = quats.copy(), quats.copy()
        passes.hinge(wp, got, limbs)
        hinge_quat(wp, want, limbs)
        np.testing.assert_array_equal(got, want)
        assert not np.array_equal(got, quats)  # it changed the pose, in place
