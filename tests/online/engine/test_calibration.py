"""Per-player calibration onto the canonical body, and the waist-orientation filter."""

from __future__ import annotations

import math

import numpy as np
import pytest

from posecast.errors import ConfigError
from posecast.geometry.fk import fk_positions
from posecast.geometry.rotations import quat_apply, quat_mul, yaw2quat
from posecast.online.engine.calibration import (
    HEAD_TOP_ABOVE_JOINT_M,
    REFERENCE_HEAD_HEIGHT_M,
    Calibration,
    WaistFilter,
    apply_all,
    orient_all,
)
from posecast.skeleton import NUM_JOINTS, REST_PELVIS_HEIGHT_M, reference_offsets
from posecast.tracking.features import TRACKER_JOINT_INDEX, TrackerSlot


def rest_trackers(where: tuple[float, float] = (0.0, 0.0), size: float = 1.0) -> np.ndarray:
    """Trackers ``(4, 3)`` of the reference body in its rest T-pose, standing at
    ``where`` (x, z) on the floor, every length multiplied by ``size``."""
    eye = np.broadcast_to(np.eye(3), (NUM_JOINTS, 3, 3))
    root = np.array([0.0, REST_PELVIS_HEIGHT_M, 0.0])
    pos = fk_positions(eye, root, reference_offsets())[list(TRACKER_JOINT_INDEX)] * size
    return pos + np.array([where[0], 0.0, where[1]])


def identity_quats() -> np.ndarray:
    q = np.zeros((4, 4))
    q[:, 3] = 1.0
    return q


def test_reference_head_height() -> None:
    assert pytest.approx(1.60) == REFERENCE_HEAD_HEIGHT_M


def test_from_height_maps_the_reference_user_to_one() -> None:
    assert Calibration.from_height(1.75).scale == pytest.approx(1.0, abs=1e-9)
    assert Calibration.from_height(1.40).scale == pytest.approx(1.75 / 1.40)
    assert Calibration.from_height(2.0).scale == pytest.approx(
        (REFERENCE_HEAD_HEIGHT_M + HEAD_TOP_ABOVE_JOINT_M) / 2.0
    )
    assert Calibration.from_height(1.75).waist_offset_m == (0.0, 0.0, 0.0)


@pytest.mark.parametrize("height_m", [0.0, -1.75, 0.5, 0.89, 2.51, 3.0, math.nan, math.inf])
def test_from_height_rejects_implausible_heights(height_m: float) -> None:
    with pytest.raises(ConfigError):
        Calibration.from_height(height_m)


@pytest.mark.parametrize("where", [(0.0, 0.0), (1.5, -2.0)])
def test_from_tpose_of_the_reference_body_is_the_identity(where: tuple[float, float]) -> None:
    cal = Calibration.from_tpose(rest_trackers(where), identity_quats())
    assert cal.scale == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_allclose(cal.waist_offset_m, 0.0, atol=1e-9)


def test_from_tpose_scales_a_taller_user() -> None:
    cal = Calibration.from_tpose(rest_trackers(size=1.1), identity_quats())
    assert cal.scale == pytest.approx(1 / 1.1)
    np.testing.assert_allclose(cal.waist_offset_m, 0.0, atol=1e-9)
    out = cal.apply(rest_trackers(size=1.1), identity_quats())
    np.testing.assert_allclose(out, rest_trackers(), atol=1e-9)


def test_from_tpose_measures_and_removes_a_worn_waist_offset() -> None:
    """A belt tracker 3 cm low and 5 cm in front of the pelvis, the user facing +X: the
    offset is found in the waist's own frame, and applying it puts the waist back."""
    quat = np.broadcast_to(yaw2quat(np.pi / 2), (4, 4)).copy()
    pos = rest_trackers((0.4, 0.7))
    worn = np.array([0.0, -0.03, 0.05])
    pos[TrackerSlot.WAIST] += quat_apply(quat[TrackerSlot.WAIST], worn)
    cal = Calibration.from_tpose(pos, quat)
    assert cal.scale == pytest.approx(1.0)
    np.testing.assert_allclose(cal.waist_offset_m, worn, atol=1e-9)

    # The same offset is removed from every later frame, whichever way the user turns.
    turn = yaw2quat(-0.8)
    quat2 = quat_mul(turn, quat)
    pos2 = rest_trackers((-1.0, 0.2))
    pos2[TrackerSlot.WAIST] += quat_apply(quat2[TrackerSlot.WAIST], worn)
    out = cal.apply(pos2, quat2)
    np.testing.assert_allclose(out[TrackerSlot.WAIST], [-1.0, REST_PELVIS_HEIGHT_M, 0.2], atol=1e-9)
    np.testing.assert_allclose(out[: TrackerSlot.WAIST], pos2[: TrackerSlot.WAIST])


def test_apply_does_not_modify_its_input() -> None:
    pos = rest_trackers()
    before = pos.copy()
    Calibration(scale=2.0, waist_offset_m=(0.0, 0.1, 0.0)).apply(pos, identity_quats())
    np.testing.assert_array_equal(pos, before)


@pytest.mark.parametrize("head_y", [0.5, 2.6])
def test_from_tpose_rejects_an_implausible_head_height(head_y: float) -> None:
    pos = rest_trackers()
    pos[TrackerSlot.HEAD, 1] = head_y
    with pytest.raises(ConfigError):
        Calibration.from_tpose(pos, identity_quats())


def _yaw_deg(q: np.ndarray) -> float:
    return float(np.degrees(2.0 * np.arctan2(q[1], q[3])))


def test_waist_filter_approaches_a_step_gradually() -> None:
    """The waist turns a quarter turn at once; the filtered heading creeps toward it,
    each step covering ``alpha = 1 - exp(-2 pi fc / fps)`` of the remaining way."""
    f = WaistFilter(cutoff_hz=5.0, fps=60.0)
    still = np.array([0.0, 0.0, 0.0, 1.0])
    for _ in range(5):
        np.testing.assert_allclose(f(still), still, atol=1e-12)
    turned = yaw2quat(np.pi / 2)
    yaws = np.array([_yaw_deg(f(turned)) for _ in range(20)])
    alpha = 1.0 - math.exp(-2.0 * math.pi * 5.0 / 60.0)
    assert 0.0 < yaws[0] < 45.0  # no jump to the new heading
    assert np.all(np.diff(yaws) > 0.0)  # no overshoot, no stall
    k = np.arange(1, 21)
    np.testing.assert_allclose(yaws, 90.0 * (1.0 - (1.0 - alpha) ** k), rtol=1e-6)
    assert yaws[-1] == pytest.approx(90.0, abs=0.01)


def test_waist_filter_normalises_its_input() -> None:
    f = WaistFilter(cutoff_hz=5.0)
    out = f(np.array([0.0, 0.0, 0.0, 3.0]))
    np.testing.assert_allclose(out, [0.0, 0.0, 0.0, 1.0])


def test_headset_only_tpose_learns_each_devices_rotation_offset() -> None:
    """A headset-only T-pose: the user faces some heading, each device reports its
    own axes (a controller's grip is not the hand joint's frame). After calibration
    every orientation is the joint's: the heading alone in the T-pose, and a later
    turn of the body turns the corrected orientations with it."""
    from posecast.geometry.rotations import axis_mat, mat2quat, quat_conj

    heading = yaw2quat(0.7)
    pos = quat_apply(heading, rest_trackers(size=1.05))
    device = mat2quat(
        np.stack([axis_mat("X", 0.3), axis_mat("Y", 1.4), axis_mat("Z", -1.2), np.eye(3)])
    )  # each device's fixed mounting rotation relative to its joint
    reported = quat_mul(np.broadcast_to(heading, (4, 4)), device)
    cal = Calibration.from_tpose(pos, reported, waist=False)
    assert cal.scale == pytest.approx(1 / 1.05, rel=1e-6)
    assert cal.waist_offset_m == (0.0, 0.0, 0.0)
    fixed = cal.orient(reported)
    for i in range(3):
        assert abs(quat_mul(quat_conj(fixed[i]), heading)[3]) == pytest.approx(1.0, abs=1e-9)
    turn = yaw2quat(-2.0)
    later = cal.orient(quat_mul(np.broadcast_to(turn, (4, 4)), reported))
    want = quat_mul(turn, heading)
    for i in range(3):
        assert abs(quat_mul(quat_conj(later[i]), want)[3]) == pytest.approx(1.0, abs=1e-9)
    # The 4-point T-pose keeps the devices' orientations as they are.
    assert Calibration.from_tpose(pos, reported).orient(reported) is reported


def test_headset_only_tpose_needs_spread_hands() -> None:
    pos = rest_trackers()
    pos[TrackerSlot.LEFT_HAND] = pos[TrackerSlot.RIGHT_HAND] + [0.0, 0.3, 0.0]
    with pytest.raises(ConfigError, match="spread"):
        Calibration.from_tpose(pos, identity_quats(), waist=False)


def test_calibrating_all_players_at_once_gives_each_ones_bits(rng: np.random.Generator) -> None:
    """``orient_all`` and ``apply_all`` (the engine's batched input path) give, row for
    row, exactly what each player's own ``orient`` and ``apply`` give: default, scaled,
    waist-offset and per-device-rotation calibrations mixed."""
    pos = rest_trackers((0.3, -1.2), 1.1)
    tpose_quat = np.tile(yaw2quat(0.4), (4, 1))
    calibrations = [
        Calibration(),
        Calibration.from_height(1.62),
        Calibration.from_tpose(pos, tpose_quat),
        Calibration.from_tpose(pos, tpose_quat, waist=False),
        Calibration(scale=0.9, waist_offset_m=(0.01, -0.02, 0.05)),
    ] * 3
    M = len(calibrations)
    raw = rng.normal(size=(M, 4, 3)) + np.array([0.0, 1.0, 0.0])
    quat = rng.normal(size=(M, 4, 4))
    quat /= np.linalg.norm(quat, axis=-1, keepdims=True)
    oriented = orient_all(calibrations, quat)
    placed = apply_all(calibrations, raw, oriented)
    for i, c in enumerate(calibrations):
        np.testing.assert_array_equal(oriented[i], c.orient(quat[i]))
        np.testing.assert_array_equal(placed[i], c.apply(raw[i], oriented[i]))
    assert not np.array_equal(oriented, quat) and not np.array_equal(placed, raw)


def test_recalibrate_gives_what_the_new_calibration_gives_raw_frames() -> None:
    """Frames calibrated by one calibration, re-expressed in another, are what the other
    makes of the raw frames (scale, waist offset and device rotation offsets alike)."""
    from posecast.geometry.rotations import quat_normalize
    from posecast.online.engine.calibration import apply_all, orient_all, recalibrate

    rng = np.random.default_rng(4)
    raw_pos = rng.normal(size=(6, 4, 3))
    raw_q = quat_normalize(rng.normal(size=(6, 4, 4)))

    def offsets() -> tuple[tuple[float, float, float, float], ...]:
        return tuple(tuple(map(float, q)) for q in quat_normalize(rng.normal(size=(4, 4))))

    old = Calibration(1.1, (0.01, -0.02, 0.03), offsets())
    for new in (Calibration(0.9, (0.0, 0.05, -0.01), offsets()), Calibration(), old):
        q_old = orient_all([old] * 6, raw_q)
        pos, q = recalibrate(old, new, apply_all([old] * 6, raw_pos, q_old), q_old)
        q_new = orient_all([new] * 6, raw_q)
        np.testing.assert_allclose(np.abs((q * q_new).sum(-1)), 1.0, atol=1e-12)
        np.testing.assert_allclose(pos, apply_all([new] * 6, raw_pos, q_new), atol=1e-12)
