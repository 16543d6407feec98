"""The lower-body pass of tracker sets (:mod:`posecast.body.leg_ik`): ankles on
positional foot trackers, feet turned to them, knees on the side of the pole, bones
unchanged, rotations FK-consistent, only the tracked legs moved, out-of-reach feet
reached for and flagged."""

from __future__ import annotations

import numpy as np
import pytest

from posecast.body.leg_ik import LEG_JOINTS, senses_legs, solve_legs, tracks_legs
from posecast.geometry.fk import fk_mat, world2local_mat
from posecast.geometry.rotations import aa2mat, mat2quat, quat2mat
from posecast.skeleton import PARENTS, Joint, reference_offsets
from posecast.tracking.sites import SITE_JOINT_INDEX, TrackerSet

BONES = np.linalg.norm(reference_offsets(), axis=-1)
FEET = "head,left_hand,right_hand,waist,left_foot,right_foot"
KNEES = FEET + ",left_knee,right_knee"


def pose(
    E: int, seed: int, knee_bend: tuple[float, float], seed_body: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """``E`` poses of the reference body, knees bent by ``knee_bend`` radians (about +X,
    the shin swinging back): world positions and quats. Everything but the legs comes
    from ``seed_body`` (default ``seed``), so two poses can share pelvis and hips."""
    body = aa2mat(
        np.random.default_rng(seed if seed_body is None else seed_body).normal(
            0.0, 0.15, (E, 19, 3)
        )
    )
    legs = aa2mat(np.random.default_rng(seed).normal(0.0, 0.15, (E, 19, 3)))
    local = body.copy()
    local[:, LEG_JOINTS] = legs[:, LEG_JOINTS]
    rng = np.random.default_rng([seed, 1])
    for shin in (Joint.LEFT_SHIN, Joint.RIGHT_SHIN):
        bend = np.zeros((E, 3))
        bend[:, 0] = rng.uniform(*knee_bend, E)
        local[:, shin] = aa2mat(bend)
    wm, wp = fk_mat(local, np.array([0.0, 0.98, 0.0]), reference_offsets())
    return wp, mat2quat(wm)


def sites_of(wp: np.ndarray, wq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    idx = list(SITE_JOINT_INDEX)
    return wp[:, idx], wq[:, idx]


def kinds_of(text: str, E: int) -> np.ndarray:
    return np.broadcast_to(TrackerSet.parse(text).kinds(), (E, 10)).copy()


def check_fk(pos: np.ndarray, quat: np.ndarray) -> None:
    """Positions are FK of the rotations on the reference bones (lengths unchanged)."""
    wm = quat2mat(quat.astype(np.float64))
    local = world2local_mat(wm, PARENTS)
    _, again = fk_mat(local, pos[:, 0].astype(np.float64), reference_offsets())
    np.testing.assert_allclose(pos, again, atol=2e-5)
    for j in range(1, 19):
        np.testing.assert_allclose(
            np.linalg.norm(pos[:, j] - pos[:, PARENTS[j]], axis=-1), BONES[j], atol=2e-5
        )


def test_feet_onto_their_trackers() -> None:
    E = 32
    net_p, net_q = pose(E, 0, (0.2, 0.6))  # the network's pose
    true_p, true_q = pose(E, 1, (0.3, 1.0), seed_body=0)  # the trackers: other legs
    sp, sq = sites_of(true_p, true_q)
    kinds = kinds_of(FEET, E)
    assert tracks_legs(kinds).all()
    pos, quat, limited = solve_legs(net_p, net_q, sp, sq, kinds)
    check_fk(pos, quat)
    for foot, row in ((Joint.LEFT_FOOT, 4), (Joint.RIGHT_FOOT, 5)):
        np.testing.assert_allclose(pos[:, foot], sp[:, row], atol=1e-4)
        dots = np.abs((quat[:, foot].astype(np.float64) * sq[:, row]).sum(-1))
        np.testing.assert_allclose(dots, 1.0, atol=1e-5)  # the tracker's orientation
    assert not limited.any()
    # Only the legs moved.
    others = [j for j in range(19) if j not in LEG_JOINTS]
    np.testing.assert_allclose(pos[:, others], net_p[:, others], atol=1e-5)
    np.testing.assert_allclose(quat[:, others], net_q[:, others], atol=1e-6)
    # The knee stays on the network's side of the hip-ankle line (no flips).
    for thigh, shin, foot in (
        (Joint.LEFT_THIGH, Joint.LEFT_SHIN, Joint.LEFT_FOOT),
        (Joint.RIGHT_THIGH, Joint.RIGHT_SHIN, Joint.RIGHT_FOOT),
    ):
        u = pos[:, foot] - pos[:, thigh]
        u /= np.linalg.norm(u, axis=-1, keepdims=True)

        def across(v: np.ndarray, u: np.ndarray = u) -> np.ndarray:
            return v - (v * u).sum(-1, keepdims=True) * u

        new_knee = across(pos[:, shin] - pos[:, thigh])
        net_knee = across(net_p[:, shin] - net_p[:, thigh])
        assert ((new_knee * net_knee).sum(-1) > 0).all()


def test_knee_trackers_set_the_knee_plane() -> None:
    E = 16
    net_p, net_q = pose(E, 2, (0.2, 0.5))
    true_p, true_q = pose(E, 3, (0.6, 1.2), seed_body=2)
    sp, sq = sites_of(true_p, true_q)
    pos, quat, limited = solve_legs(net_p, net_q, sp, sq, kinds_of(KNEES, E))
    check_fk(pos, quat)
    # Same pelvis, same bones: ankle and knee trackers fix the leg, so the knee lands
    # on its tracker.
    np.testing.assert_allclose(pos[:, Joint.LEFT_SHIN], sp[:, 6], atol=1e-3)
    np.testing.assert_allclose(pos[:, Joint.RIGHT_SHIN], sp[:, 7], atol=1e-3)
    assert not limited.any()


def test_knee_alone_aims_the_thigh_and_inertial_sites_are_ignored() -> None:
    E = 8
    net_p, net_q = pose(E, 4, (0.2, 0.5))
    true_p, true_q = pose(E, 5, (0.2, 0.5), seed_body=4)
    sp, sq = sites_of(true_p, true_q)
    text = "head,left_hand,right_hand,left_knee,right_foot:imu"
    pos, quat, _ = solve_legs(net_p, net_q, sp, sq, kinds_of(text, E))
    check_fk(pos, quat)
    np.testing.assert_allclose(pos[:, Joint.LEFT_SHIN], sp[:, 6], atol=1e-4)
    right = [int(j) for j in range(Joint.RIGHT_THIGH, Joint.RIGHT_TOE + 1)]
    np.testing.assert_allclose(pos[:, right], net_p[:, right], atol=1e-5)  # imu: untouched
    assert not tracks_legs(kinds_of("head,left_hand,right_hand,left_foot:imu", 1)).any()


def test_out_of_reach_reaches_straight_and_flags() -> None:
    E = 4
    net_p, net_q = pose(E, 6, (0.2, 0.5))
    sp, sq = sites_of(net_p, net_q)
    sp = sp.copy()
    sp[:, 4] = net_p[:, Joint.LEFT_THIGH] + [0.0, -2.0, 0.0]  # 2 m below the hip
    pos, quat, limited = solve_legs(net_p, net_q, sp, sq, kinds_of(FEET, E))
    check_fk(pos, quat)
    assert limited.all()
    down = pos[:, Joint.LEFT_FOOT] - pos[:, Joint.LEFT_THIGH]
    np.testing.assert_allclose(
        down[:, 1], -(BONES[Joint.LEFT_SHIN] + BONES[Joint.LEFT_FOOT]), atol=1e-3
    )


def test_the_knee_bends_as_a_hinge() -> None:
    """Whatever twist the network gave the thigh, a bent tracked leg's shin lies in the
    thigh's sagittal plane, behind it (no sideways knee)."""
    plaus = pytest.importorskip("posecast.offline.evaluation.plausibility")
    E = 32
    net_p, net_q = pose(E, 8, (0.3, 0.6))
    wm = quat2mat(net_q)
    twist = aa2mat(np.array([[0.0, 0.8, 0.0]]))  # 46 degrees about the thigh's bone
    for thigh in (Joint.LEFT_THIGH, Joint.RIGHT_THIGH):
        wm[:, thigh] = wm[:, thigh] @ twist  # a twisted thigh, positions unchanged
    true_p, true_q = pose(E, 9, (0.6, 1.2), seed_body=8)
    sp, sq = sites_of(true_p, true_q)
    before = plaus.joint_angles(wm)["knee_side"]
    assert (np.abs(before) > 10.0).all()  # sideways knees before
    pos, quat, _ = solve_legs(net_p, mat2quat(wm), sp, sq, kinds_of(FEET, E))
    check_fk(pos, quat)
    a = plaus.joint_angles(quat2mat(quat.astype(np.float64)))
    np.testing.assert_allclose(a["knee_side"], 0.0, atol=1e-3)
    assert (a["knee_flex"] > 0).all()


def test_a_set_senses_its_legs_with_any_foot_or_knee_tracker() -> None:
    """``senses_legs``: positional or inertial feet or knees count (their sets keep the
    hips as the network has them; a guessed pelvis of the others leans), hands, head
    and waist do not."""
    sensed = [
        FEET,
        KNEES,
        "head,left_hand,right_hand,left_foot:imu,right_foot:imu",
        "head,left_hand,right_hand,left_knee:imu",
    ]
    blind = ["head,left_hand,right_hand", "head,left_hand,right_hand,waist"]
    for text in sensed:
        assert senses_legs(kinds_of(text, 2)).all(), text
    for text in blind:
        assert not senses_legs(kinds_of(text, 2)).any(), text
