"""The look-ahead ring's rows (online.engine.ring): the rest frame, a tick's inputs
written in (calibrated, with velocities over held frames) and a shown pelvis's
neighbours read out, on slot arrays of the engine's ring fields (4-point layout)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from posecast.geometry.fk import fk_positions
from posecast.geometry.rotations import quat2mat
from posecast.online.engine.calibration import Calibration, WaistFilter
from posecast.online.engine.ring import pelvis_neighbours, rest_frame, write_inputs
from posecast.online.engine.slots import SlotArrays
from posecast.online.engine.types import TrackerFrame
from posecast.skeleton import NUM_JOINTS, REST_PELVIS_HEIGHT_M, reference_offsets
from posecast.tracking.features import TRACKER_JOINT_INDEX, TrackerSlot
from posecast.tracking.layouts import Layout, spec
from posecast.tracking.sites import SITE_JOINT_INDEX

FPS = 60.0
RING = 4
LAYOUT = spec(Layout.HMD3_WAIST)


@dataclass
class Player:
    slot: int
    calibration: Calibration = field(default_factory=Calibration)
    waist_filter: WaistFilter | None = None
    last: TrackerFrame | None = None


def _slots(players: int) -> SlotArrays:
    s = SlotArrays(
        {
            "ring_x": ((LAYOUT.n_features,), np.float32, RING),
            "ring_pos": ((4, 3), np.float64, RING),
            "ring_quat": ((4, 4), np.float64, RING),
            "ring_rootm": ((3, 3), np.float32, RING),
            "ring_root": ((1, 1), np.float32, RING),
            "ring_seq": ((), np.int64, RING),
            "ring_held": ((), np.bool_, RING),
            "kinds": ((4,), np.int8),
        }
    )
    for _ in range(players):
        s.add()
    return s


def _frame(seq: int, shift: float, turn: float = 0.0) -> TrackerFrame:
    rest = rest_frame(4)
    quat = np.tile([0.0, np.sin(turn / 2), 0.0, np.cos(turn / 2)], (4, 1))
    return TrackerFrame(seq, rest.pos + np.array([shift, 0.0, 0.0]), quat)


def test_the_rest_frame_is_the_reference_body_standing_at_the_origin() -> None:
    eye = np.broadcast_to(np.eye(3), (NUM_JOINTS, 3, 3))
    joints = fk_positions(eye, np.array([0.0, REST_PELVIS_HEIGHT_M, 0.0]), reference_offsets())
    for rows, index in ((4, TRACKER_JOINT_INDEX), (10, SITE_JOINT_INDEX)):
        rest = rest_frame(rows)
        assert rest.seq == -1 and rest.pos.shape == (rows, 3) and rest.quat.shape == (rows, 4)
        np.testing.assert_allclose(rest.pos, joints[list(index)])
        np.testing.assert_array_equal(rest.quat, np.tile([0.0, 0.0, 0.0, 1.0], (rows, 1)))


def test_a_fresh_frame_is_calibrated_and_its_velocity_is_over_the_frames_held() -> None:
    s, p = _slots(1), Player(0, Calibration(scale=0.5))
    rest = rest_frame(4)
    write_inputs(s, 0, RING - 1, [(p, rest)], [], [0], {}, LAYOUT, FPS, rest)
    assert p.last is None and s["ring_held"][0, 0]  # the stand-in is held, never "last"
    f1 = _frame(1, 0.2, turn=0.3)
    write_inputs(s, 1, 0, [(p, f1)], [], [], {}, LAYOUT, FPS, rest)
    assert p.last is f1 and not s["ring_held"][1, 0] and s["ring_seq"][1, 0] == 1
    cal1 = f1.pos * 0.5
    np.testing.assert_allclose(s["ring_pos"][1, 0], cal1)
    np.testing.assert_allclose(s["ring_quat"][1, 0], f1.quat)
    np.testing.assert_allclose(
        s["ring_rootm"][1, 0], quat2mat(f1.quat[TrackerSlot.WAIST]), atol=1e-7
    )
    want = LAYOUT.features(cal1[None], cal1[None], f1.quat[None], FPS, None)[0]  # first: still
    np.testing.assert_allclose(s["ring_x"][1, 0], want, rtol=1e-6, atol=1e-6)
    # frame 2 missing: row 2 keeps row 1's inputs, held
    write_inputs(s, 2, 1, [], [0], [0], {}, LAYOUT, FPS, rest)
    assert s["ring_held"][2, 0] and s["ring_seq"][2, 0] == 1
    np.testing.assert_array_equal(s["ring_x"][2, 0], s["ring_x"][1, 0])
    # frame 3 arrives: it moved over two frames, so its velocity is half the step
    f3 = _frame(3, 0.26, turn=0.3)
    write_inputs(s, 3, 2, [(p, f3)], [], [], {0: 1}, LAYOUT, FPS, rest)
    cal3 = f3.pos * 0.5
    prev = cal3 - (cal3 - cal1) / 2
    want = LAYOUT.features(cal3[None], prev[None], f3.quat[None], FPS, None)[0]
    np.testing.assert_allclose(s["ring_x"][3, 0], want, rtol=1e-6, atol=1e-6)
    moved = LAYOUT.features(cal3[None], cal1[None], f3.quat[None], FPS, None)[0]
    assert not np.allclose(want, moved)  # the gap matters


def test_the_pelvis_neighbours_are_the_frames_either_side() -> None:
    """4-point layout: the pelvis is the waist tracker's. Frame ``e``'s neighbours are
    ``e - 1`` and ``e + 1`` (the look-ahead holds it); a first frame stands in for its
    missing ``e - 1``; without a delay ``e`` stands in for ``e + 1`` and the waist's
    position stays ``e``'s own (the shown pelvis's)."""
    s, p = _slots(1), Player(0)
    rest = rest_frame(4)
    frames = [_frame(t, 0.1 * t, turn=0.2 * t) for t in range(3)]
    for k, f in enumerate(frames):
        write_inputs(s, k, (k - 1) % RING, [(p, f)], [], [], {}, LAYOUT, FPS, rest)
    slots, samples = np.array([0], np.intp), np.array([0], np.intp)
    shown_m = np.eye(3, dtype=np.float32)[None]
    shown = (shown_m, np.array([[9.0, 9.0, 9.0]], np.float32))

    def waist(t: int) -> tuple[np.ndarray, np.ndarray]:
        return quat2mat(frames[t].quat[TrackerSlot.WAIST]), frames[t].pos[TrackerSlot.WAIST]

    def check(first: bool, ahead: bool, before: int, after: int) -> None:
        mats, places = pelvis_neighbours(
            s, 1, RING, LAYOUT, slots, samples, np.array([first]), None, shown, None, ahead
        )
        assert mats.shape == (2, 1, 3, 3) and places.shape == (2, 1, 3)
        for i, t in enumerate((before, after)):
            np.testing.assert_allclose(mats[i, 0], waist(t)[0], atol=1e-6)
            if ahead:
                np.testing.assert_allclose(places[i, 0], waist(t)[1], atol=1e-6)
            else:  # the waist tracker's position is the shown (newest) one
                np.testing.assert_array_equal(places[i, 0], shown[1][0])

    check(first=False, ahead=True, before=0, after=2)
    check(first=True, ahead=True, before=1, after=2)
    check(first=False, ahead=False, before=0, after=1)
