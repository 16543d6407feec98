from __future__ import annotations

import numpy as np
import pytest

from posecast.offline.evaluation import metrics as m
from posecast.skeleton import Joint


def _still(T: int = 10) -> np.ndarray:
    rng = np.random.default_rng(0)
    pose = rng.normal(size=(19, 3))
    pose[:, 1] = np.abs(pose[:, 1]) + 0.1  # above the floor
    return np.repeat(pose[None], T, axis=0)


def _mean(acc: tuple[float, int]) -> float:
    return acc[0] / acc[1]


def test_mpjpe_of_a_constant_offset() -> None:
    gt = _still()
    pred = gt + np.array([0.03, 0.0, 0.04])  # 5 cm everywhere
    assert _mean(m.mpjpe(pred, gt)) == pytest.approx(5.0)
    assert _mean(m.lower_mpjpe(pred, gt)) == pytest.approx(5.0)
    assert m.mpjpe(pred, gt)[1] == 10 * 19 and m.lower_mpjpe(pred, gt)[1] == 10 * 8


def test_constant_offset_has_no_velocity_or_acceleration_error() -> None:
    gt = _still()
    assert _mean(m.mpjve(gt + 0.1, gt, 60.0)) == pytest.approx(0.0, abs=1e-9)
    assert _mean(m.mpjae(gt + 0.1, gt, 60.0)) == pytest.approx(0.0, abs=1e-9)


def test_velocity_error_units() -> None:
    gt = _still(5)
    pred = gt.copy()
    pred[:, :, 0] += np.arange(5)[:, None] * 0.01  # drifts 1 cm per frame
    assert _mean(m.mpjve(pred, gt, 60.0)) == pytest.approx(60.0)  # cm/s


def test_acceleration_error_units() -> None:
    gt = _still(6)
    pred = gt.copy()
    pred[:, :, 1] += 0.5 * 0.001 * np.arange(6)[:, None] ** 2  # second difference 1 mm
    assert _mean(m.mpjae(pred, gt, 60.0)) == pytest.approx(0.1 * 3600, rel=1e-6)


def test_foot_skate_counts_only_contact_frames() -> None:
    pred = _still(4)
    pred[:, Joint.LEFT_TOE, 0] += np.arange(4) * 0.01  # slides 1 cm per frame
    contacts = np.zeros((4, 2))
    contacts[:, 0] = 1.0  # left in contact
    total, count = m.foot_skate(pred, contacts, 60.0)
    assert count == 3 and total / count == pytest.approx(60.0)
    assert m.foot_skate(pred, np.zeros((4, 2)), 60.0)[1] == 0


def test_ground_penetration() -> None:
    pred = _still(2)
    pred[0, Joint.RIGHT_TOE, 1] = -0.03
    assert _mean(m.ground_penetration(pred)) == pytest.approx(1.5)  # 3 cm on 1 of 2 frames


def test_implausible_share() -> None:
    assert _mean(m.implausible(np.array([0.1, 0.3, 0.5, 0.05]), 0.2)) == pytest.approx(0.5)


def test_accumulator_weights_by_count() -> None:
    acc = m.Accumulator()
    acc.add("x", (10.0, 10))
    acc.add("x", (0.0, 30))
    assert acc.means()["x"] == pytest.approx(0.25)


def test_root_and_hand_errors_read_their_own_joints() -> None:
    from posecast.skeleton import Joint

    gt = np.zeros((5, 19, 3))
    pred = gt.copy()
    pred[:, Joint.PELVIS, 0] = 0.03
    pred[:, Joint.LEFT_HAND, 1] = 0.10
    s, n = m.root_pe(pred, gt)
    assert s / n == pytest.approx(3.0)
    s, n = m.hand_pe(pred, gt)
    assert s / n == pytest.approx(5.0)  # one hand 10 cm off, the other exact


def test_mpjre_is_the_local_rotation_angle_in_degrees() -> None:
    from posecast.geometry.rotations import axis_mat
    from posecast.skeleton import Joint

    world = np.broadcast_to(np.eye(3), (4, 19, 3, 3)).copy()
    s, n = m.mpjre(world, world)
    assert s == pytest.approx(0.0, abs=1e-9) and n == 4 * 19
    # Twist the left forearm by 30 degrees about its bone (a positions-only error
    # measure would not see it); its children turn with it, so only one local differs.
    turned = world.copy()
    twist = axis_mat("X", np.radians(30.0))
    for j in (Joint.LEFT_FOREARM, Joint.LEFT_HAND):
        turned[:, j] = twist
    s, n = m.mpjre(turned, world)
    assert s / n == pytest.approx(30.0 / 19, rel=1e-6)


def test_jitter_is_zero_for_constant_velocity_and_exact_for_a_cubic() -> None:
    t = np.arange(20) / 60.0
    line = np.zeros((20, 19, 3))
    line[..., 0] = 2.0 * t[:, None]
    s, n = m.jitter(line, 60.0)
    assert s / n == pytest.approx(0.0, abs=1e-6)
    cubic = np.zeros((20, 19, 3))
    cubic[..., 1] = 0.5 * t[:, None] ** 3  # jerk = 3 m/s^3 everywhere
    s, n = m.jitter(cubic, 60.0)
    assert s / n == pytest.approx(3.0, rel=1e-6)


def test_present_errors_compare_the_pose_emitted_at_a_tick_with_the_truth_then() -> None:
    """A pose emitted ``d`` ticks after its frame is compared with the truth ``d``
    frames on: a body walking 1 cm a frame is 2 cm behind the present at ``d = 2``,
    and on its own frame (``d = 0``) the present errors are the aligned ones."""
    T = 20
    gt = np.zeros((T, 19, 3))
    gt += np.arange(T)[:, None, None] * np.array([0.01, 0.0, 0.0])
    pred = gt.copy()
    pred[:, int(Joint.HEAD)] += [0.0, 0.05, 0.0]
    now = m.present(gt, gt, 2)
    for key in ("present_mpjpe_cm", "present_lower_mpjpe_cm", "present_root_pe_cm"):
        total, count = now[key]
        assert total / count == pytest.approx(2.0)
    assert now["present_mpjpe_cm"][1] == (T - 2) * 19  # ticks from d on
    assert now["present_head_pe_cm"][0] / now["present_head_pe_cm"][1] == pytest.approx(2.0)
    assert now["present_hand_pe_cm"][1] == (T - 2) * 2
    aligned = m.present(pred, gt, 0)
    assert aligned["present_mpjpe_cm"] == m.mpjpe(pred, gt)
    assert aligned["present_head_pe_cm"] == m.head_pe(pred, gt)
    assert aligned["present_hand_pe_cm"] == m.hand_pe(pred, gt)
    assert _mean(aligned["present_head_pe_cm"]) == pytest.approx(5.0)
    assert m.present(gt[:3], gt[:3], 5)["present_mpjpe_cm"] == (0.0, 0)  # too short a clip
