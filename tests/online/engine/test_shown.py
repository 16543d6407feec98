"""The engine streams what the shown pose's passes make (:mod:`posecast.body`), on every
backend: lifted toes, hinged knees and elbows, the smoothed pelvis, head and hands on
their trackers. The passes themselves are tested in ``tests/body``."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from posecast.body.clearance import CLEARANCE_M, SPEEDS_M_S, TOES, clip_toe_speed
from posecast.body.hinge import KNEES, hinge_elbows_quat
from posecast.body.pelvis import smooth_pelvis, smooth_pelvis_clip
from posecast.body.upper_ik import solve_upper_body
from posecast.geometry.rotations import aa2mat, mat2quat, quat2mat
from posecast.online.engine.calibration import Calibration
from posecast.online.engine.ssi import Engine
from posecast.online.engine.types import PoseOut, TrackerFrame
from posecast.skeleton import LOWER_BODY, Joint
from posecast.tracking.features import TrackerSlot
from tests.body.test_hinge import knee_local, off_hinge_deg
from tests.body.test_upper_ik import HANDS, assert_fk_consistent
from tests.online.engine.conftest import BackendLoader, run_player

WalkFrames = Callable[..., list[TrackerFrame]]


# --- the swing clearance (body/clearance.py) ---


def run_toes(engine: Engine, frames: list[TrackerFrame]) -> np.ndarray:
    return np.stack([p.positions for p in run_player(engine, frames)]).astype(np.float64)


@pytest.mark.parametrize("layout", ["hmd3+waist", "hmd3"])
def test_the_engine_lifts_sliding_toes_straight_up(
    backend: BackendLoader, walk_frames: WalkFrames, layout: str
) -> None:
    """A walk, 8 cm lower (the synthetic walker's 4-point toes swing well clear of the
    floor; lowered, they scrape it): with the clearance (the default) every shown toe is
    at least at the clearance of its averaged speed, recomputed from the shown poses
    (which shows the engine's speed is the evaluation's); without it some toes are
    lower; the toes' horizontal tracks are the same either way (a lift is straight up)."""
    frames = [TrackerFrame(f.seq, f.pos - [0.0, 0.08, 0.0], f.quat) for f in walk_frames(0)]
    cfg = {"samples": 10, "lookahead": 2, "upper_body_ik": False}
    on = run_toes(backend.engine(layout, **cfg), frames)
    off = run_toes(backend.engine(layout, **cfg, swing_clearance=False), frames)
    speed = clip_toe_speed(on, 60.0)
    need = np.interp(speed, SPEEDS_M_S, CLEARANCE_M)
    toe_on, toe_off = on[:, TOES], off[:, TOES]
    assert np.all(toe_on[..., 1] >= need - 1.001e-3)
    # A toe the clearance lifted, where the floor pass alone lifted nothing, sits at the
    # clearance of the speed recomputed here: the engine's speed is this one, not more.
    feet = off[:, [int(f) for f in (Joint.LEFT_FOOT, Joint.RIGHT_FOOT)], 1]
    lifted = (toe_on[..., 1] > toe_off[..., 1] + 1e-3) & (np.minimum(feet, toe_off[..., 1]) > 0)
    assert lifted.sum() > 20
    np.testing.assert_allclose(toe_on[..., 1][lifted], need[lifted], atol=1.5e-3)
    assert np.mean(toe_off[..., 1] < need - 5e-3) > 0.05  # the walk's toes do go low
    np.testing.assert_allclose(toe_on[..., [0, 2]], toe_off[..., [0, 2]], atol=2e-3)
    np.testing.assert_allclose(clip_toe_speed(off, 60.0), speed, atol=0.05)


# --- the hinges (body/hinge.py) ---


def test_the_engine_streams_hinged_knees(backend: BackendLoader, walk_frames: WalkFrames) -> None:
    """A walk, 4 points: every bent knee (over 15 degrees) streamed on its hinge within
    0.05 degrees (float32), the same joints as without the hinge; without it some knees
    are off their hinges by more than a degree."""
    frames = walk_frames(0)
    cfg = {"samples": 10, "lookahead": 2, "upper_body_ik": False}
    on = run_player(backend.engine(**cfg), frames)
    off = run_player(backend.engine(**cfg, knee_hinge=False), frames)
    pos_on = np.stack([p.positions for p in on])
    np.testing.assert_allclose(pos_on, np.stack([p.positions for p in off]), atol=1e-5)
    worst_on, worst_off = 0.0, 0.0
    for shown, pose_pos in ((on, pos_on), (off, None)):
        mat = quat2mat(np.stack([p.rotations for p in shown]).astype(np.float64))
        p = pos_on if pose_pos is None else pose_pos
        for (t, s, f), local in zip(KNEES, knee_local(mat), strict=True):
            a, b = p[:, s] - p[:, t], p[:, f] - p[:, s]
            cos = np.sum(a * b, -1) / np.linalg.norm(a, axis=-1) / np.linalg.norm(b, axis=-1)
            bent = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))) > 15.0
            assert bent.sum() > 10
            worst = float(off_hinge_deg(local)[bent].max())
            if shown is on:
                worst_on = max(worst_on, worst)
            else:
                worst_off = max(worst_off, worst)
    assert worst_on < 0.05
    assert worst_off > 1.0


def test_the_engine_streams_hinged_elbows(backend: BackendLoader, walk_frames: WalkFrames) -> None:
    """A walk, 4 points: the streamed pose is the one without the elbow hinge with its
    elbows then put onto their hinges (the last pass), positions unchanged; and the
    hinge changed something."""
    frames = walk_frames(0)[:40]
    on, off = (
        run_player(backend.engine(samples=4, lookahead=2, elbow_hinge=e), frames)
        for e in (True, False)
    )
    pos = np.stack([p.positions for p in off])
    quat = np.stack([p.rotations for p in off])
    np.testing.assert_array_equal(np.stack([p.positions for p in on]), pos)
    hinged = quat.copy()
    hinge_elbows_quat(pos, hinged)
    got = np.stack([p.rotations for p in on])
    np.testing.assert_allclose(quat2mat(got), quat2mat(hinged), atol=1e-5)
    assert np.abs(quat2mat(got) - quat2mat(quat)).max() > 1e-2


# --- the pelvis smoothing (body/pelvis.py) ---


def _shaky(frames: list[TrackerFrame], seed: int) -> list[TrackerFrame]:
    """The frames with the waist tracker shaken: 1.5 degrees and 3 mm of white noise."""
    rng = np.random.default_rng(seed)
    out = []
    for f in frames:
        pos, quat = f.pos.copy(), f.quat.copy()
        turn = aa2mat(rng.normal(0.0, np.radians(1.5), 3))
        quat[TrackerSlot.WAIST] = mat2quat(turn @ quat2mat(quat[TrackerSlot.WAIST]))
        pos[TrackerSlot.WAIST] += rng.normal(0.0, 0.003, 3)
        out.append(TrackerFrame(f.seq, pos, quat))
    return out


def _jerk(pos: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(pos, 3, axis=0), axis=-1).mean())


def test_the_engine_streams_the_smoothed_pelvis_without_lag(
    backend: BackendLoader, walk_frames: WalkFrames
) -> None:
    """4 points, a shaky waist tracker, the paper's delayed emission: with the smoothing
    (the default) each streamed
    pelvis is the 1-2-1 average of the unsmoothed engine's at the same seq and either
    side (the first frame standing in for its missing neighbour), seq for seq; the legs
    then shake less (mean jerk of the leg joints at most 0.6x); with the smoothing off,
    the pelvis is the waist tracker's."""
    frames = _shaky(walk_frames(0), seed=1)
    cfg = {"samples": 10, "lookahead": 2, "delayed_emission": True, "upper_body_ik": False}
    on = run_player(backend.engine(**cfg), frames)
    off = run_player(backend.engine(**cfg, pelvis_smoothing=False), frames)
    assert [p.seq for p in on] == [p.seq for p in off] == [f.seq for f in frames[:-2]]
    waist = np.stack([f.pos[TrackerSlot.WAIST] for f in frames[:-2]])
    pelvis_off = np.stack([p.positions[Joint.PELVIS] for p in off])
    np.testing.assert_allclose(pelvis_off, waist, atol=1e-5)
    mats_off = quat2mat(np.stack([p.rotations[Joint.PELVIS] for p in off]).astype(np.float64))
    # Frame e + 1 of the last streamed pose is in the look-ahead: smooth over all of it.
    full_m = np.concatenate([mats_off, quat2mat(frames[-2].quat[TrackerSlot.WAIST])[None]])
    full_p = np.concatenate([pelvis_off, frames[-2].pos[TrackerSlot.WAIST][None]])
    want_m, want_p = smooth_pelvis_clip(full_m, full_p)
    got_m = quat2mat(np.stack([p.rotations[Joint.PELVIS] for p in on]).astype(np.float64))
    got_p = np.stack([p.positions[Joint.PELVIS] for p in on])
    np.testing.assert_allclose(got_p, want_p[:-1], atol=1e-5)
    np.testing.assert_allclose(got_m, want_m[:-1], atol=1e-5)
    legs = [int(j) for j in LOWER_BODY]
    shown_on = np.stack([p.positions for p in on])[:, legs]
    shown_off = np.stack([p.positions for p in off])[:, legs]
    assert _jerk(shown_on) <= 0.6 * _jerk(shown_off)


def test_the_headset_only_engine_smooths_its_own_pelvis(
    backend: BackendLoader, walk_frames: WalkFrames
) -> None:
    """3 points, one sample (so no transitions), delayed by one frame: the streamed
    pelvis is the 1-2-1 average
    of the decoder's own pelvis, as the unsmoothed engine streams it."""
    frames = walk_frames(1)
    cfg = {"samples": 1, "lookahead": 1, "delayed_emission": True, "upper_body_ik": False}
    on = run_player(backend.engine("hmd3", **cfg), frames)
    off = run_player(backend.engine("hmd3", **cfg, pelvis_smoothing=False), frames)
    assert [p.seq for p in on] == [p.seq for p in off]
    m_off = quat2mat(np.stack([p.rotations[Joint.PELVIS] for p in off]).astype(np.float64))
    p_off = np.stack([p.positions[Joint.PELVIS] for p in off]).astype(np.float64)
    want_m, want_p = smooth_pelvis_clip(m_off, p_off)
    got_m = quat2mat(np.stack([p.rotations[Joint.PELVIS] for p in on]).astype(np.float64))
    got_p = np.stack([p.positions[Joint.PELVIS] for p in on])
    inner = slice(0, len(on) - 1)  # the last one's e + 1 was never streamed here
    np.testing.assert_allclose(got_p[inner], want_p[inner], atol=1e-5)
    np.testing.assert_allclose(got_m[inner], want_m[inner], atol=1e-5)
    assert np.abs(got_p - p_off).max() > 1e-4  # it did something


def test_served_present_a_guessed_pelvis_is_smoothed_with_the_frame_before(
    backend: BackendLoader, walk_frames: WalkFrames
) -> None:
    """3 points, one sample, served by default (no delay): the streamed pelvis, the
    decoder's guess, is the 1:3 average of the unsmoothed engine's at the frame before
    and its own, position and rotation (a guess, not a measurement)."""
    frames = walk_frames(1)
    cfg = {"samples": 1, "upper_body_ik": False}
    on = run_player(backend.engine("hmd3", **cfg), frames)
    off = run_player(backend.engine("hmd3", **cfg, pelvis_smoothing=False), frames)
    assert [p.seq for p in on] == [p.seq for p in off] == [f.seq for f in frames]
    m_off = quat2mat(np.stack([p.rotations[Joint.PELVIS] for p in off]).astype(np.float64))
    p_off = np.stack([p.positions[Joint.PELVIS] for p in off]).astype(np.float64)
    m_before = np.concatenate([m_off[:1], m_off[:-1]])
    p_before = np.concatenate([p_off[:1], p_off[:-1]])
    want_m, want_p = smooth_pelvis((m_before, m_off, m_off), (p_before, p_off, p_off))
    got_m = quat2mat(np.stack([p.rotations[Joint.PELVIS] for p in on]).astype(np.float64))
    got_p = np.stack([p.positions[Joint.PELVIS] for p in on])
    np.testing.assert_allclose(got_p, want_p, atol=1e-5)
    np.testing.assert_allclose(got_m, want_m, atol=1e-5)
    assert np.abs(got_p - p_off).max() > 1e-4  # it did something


def test_served_present_the_pelvis_rotation_is_smoothed_and_its_position_its_own(
    backend: BackendLoader, walk_frames: WalkFrames
) -> None:
    """4 points, a shaky waist tracker, served by default (no delay, no frame ``e + 1``):
    each streamed pelvis stands where the waist tracker is, and its rotation is the
    1:3 average of the unsmoothed engine's at the frame before and its own (the first
    frame its own); the legs shake less than on each frame's own pelvis (mean jerk of
    the leg joints at most 0.75x)."""
    frames = _shaky(walk_frames(0), seed=1)
    cfg = {"samples": 10, "upper_body_ik": False}
    on = run_player(backend.engine(**cfg), frames)
    off = run_player(backend.engine(**cfg, pelvis_smoothing=False), frames)
    assert [p.seq for p in on] == [p.seq for p in off] == [f.seq for f in frames]
    waist = np.stack([f.pos[TrackerSlot.WAIST] for f in frames])
    got_p = np.stack([p.positions[Joint.PELVIS] for p in on])
    np.testing.assert_allclose(got_p, waist, atol=1e-5)
    m_off = quat2mat(np.stack([p.rotations[Joint.PELVIS] for p in off]).astype(np.float64))
    before = np.concatenate([m_off[:1], m_off[:-1]])
    here = np.zeros((len(m_off), 3))
    want_m, _ = smooth_pelvis((before, m_off, m_off), (here, here, here))
    got_m = quat2mat(np.stack([p.rotations[Joint.PELVIS] for p in on]).astype(np.float64))
    np.testing.assert_allclose(got_m, want_m, atol=1e-5)
    assert np.abs(got_m - m_off).max() > 1e-3  # it did something
    legs = [int(j) for j in LOWER_BODY]
    shown_on = np.stack([p.positions for p in on])[:, legs]
    shown_off = np.stack([p.positions for p in off])[:, legs]
    assert _jerk(shown_on) <= 0.75 * _jerk(shown_off)  # measured 0.63 on every backend


def test_without_look_ahead_the_pelvis_is_its_own(
    backend: BackendLoader, walk_frames: WalkFrames
) -> None:
    """Served present (no delay): the pelvis position is the newest waist tracker's."""
    frames = _shaky(walk_frames(2), seed=2)
    poses = run_player(backend.engine(samples=4, lookahead=0, upper_body_ik=False), frames)
    waist = np.stack([f.pos[TrackerSlot.WAIST] for f in frames])
    pelvis = np.stack([p.positions[Joint.PELVIS] for p in poses])
    np.testing.assert_allclose(pelvis, waist, atol=1e-5)


def test_rest_frames_before_the_first_frame_are_no_neighbours(
    backend: BackendLoader, walk_frames: WalkFrames
) -> None:
    """A player added a few ticks before its first frame stands at the origin in the
    rest pose meanwhile; from its first real frame on, its pelvis (4 points: the waist
    tracker's, smoothed) is the one a player added with its first frame streams: no
    rest frame at the origin is smoothed into it. (The rest of the body differs: the
    network's state stepped through the rest frames.)"""
    frames = walk_frames(0)
    cfg = {"samples": 4, "lookahead": 2}
    direct = run_player(backend.engine(**cfg), frames)
    late = backend.engine(**cfg)
    late.add_player("p", seed=3)
    waited: list[PoseOut] = []
    for _ in range(5):
        waited += late.tick().poses
    for f in frames:
        late.push("p", f)
        waited += late.tick().poses
    real = [p for p in waited if p.seq >= 0]
    assert len(waited) > len(real) and [p.seq for p in real] == [p.seq for p in direct]
    for a, b in zip(real, direct, strict=True):
        np.testing.assert_allclose(a.positions[Joint.PELVIS], b.positions[Joint.PELVIS], atol=1e-5)
        np.testing.assert_allclose(
            np.abs(a.rotations[Joint.PELVIS] @ b.rotations[Joint.PELVIS]), 1.0, atol=1e-5
        )


# --- the upper-body pass (body/upper_ik.py) ---


def run_calibrated(
    engine: Engine, frames: list[TrackerFrame], calibration: Calibration | None = None
) -> list[PoseOut]:
    engine.add_player("p", seed=0, calibration=calibration)
    poses = []
    for f in frames:
        engine.push("p", f)
        poses += engine.tick().poses
    return poses


def test_the_engine_streams_head_and_hands_on_the_trackers(
    backend: BackendLoader, walk_frames: WalkFrames
) -> None:
    """On a synthetic walk (trackers on the reference body's joints, so the walk's own
    head and hands are within reach) every streamed pose has its head and hands within
    1 cm of the trackers (measured: within 1 mm) and FK-consistent rotations; with
    ``upper_body_ik=False`` (and no elbow hinge) the pose is the one before the pass:
    the pass and then the elbow hinge applied to it give the streamed pose, and the
    pelvis and legs are the same either way."""
    frames = walk_frames(0)
    by_seq = {f.seq: f for f in frames}
    on = run_calibrated(backend.engine(samples=10), frames)
    off = run_calibrated(backend.engine(samples=10, upper_body_ik=False, elbow_hinge=False), frames)
    assert len(on) == len(off) == len(frames)  # served present: every frame's pose at once
    for pose in on:
        f = by_seq[pose.seq]
        for joint, slot in ((Joint.HEAD, TrackerSlot.HEAD), *HANDS):
            assert np.linalg.norm(pose.positions[joint] - f.pos[slot]) < 0.01, (pose.seq, joint)
    assert not any(p.reach_limited for p in on)
    assert not any(p.reach_limited for p in off)
    pos_on = np.stack([p.positions for p in on])
    quat_on = np.stack([p.rotations for p in on])
    pos_off = np.stack([p.positions for p in off])
    quat_off = np.stack([p.rotations for p in off])
    assert_fk_consistent(pos_on, quat_on, atol=1e-4)
    legs = [int(Joint.PELVIS), *(int(j) for j in LOWER_BODY)]
    np.testing.assert_array_equal(pos_on[:, legs], pos_off[:, legs])
    assert np.abs(pos_on - pos_off).max() > 1e-3  # the pass did something
    tp = np.stack([by_seq[p.seq].pos for p in off])
    tq = np.stack([by_seq[p.seq].quat for p in off])
    again, again_q, _ = solve_upper_body(pos_off, quat_off, tp, tq)
    hinge_elbows_quat(again, again_q)  # then the elbows onto their hinges
    np.testing.assert_allclose(again, pos_on, atol=1e-5)
    np.testing.assert_allclose(quat2mat(again_q), quat2mat(quat_on), atol=1e-5)


def test_the_engine_reaches_calibrated_trackers_at_the_users_scale(
    backend: BackendLoader, walk_frames: WalkFrames
) -> None:
    """A half-size user (``scale = 2``): the pass works on the calibrated trackers, and the
    streamed head and hands land on the user's own trackers at the user's size."""
    frames = [TrackerFrame(f.seq, f.pos / 2.0, f.quat) for f in walk_frames(0)[:30]]
    by_seq = {f.seq: f for f in frames}
    poses = run_calibrated(backend.engine(samples=10, lookahead=2), frames, Calibration(scale=2.0))
    assert poses
    for pose in poses:
        f = by_seq[pose.seq]
        for joint, slot in ((Joint.HEAD, TrackerSlot.HEAD), *HANDS):
            assert np.linalg.norm(pose.positions[joint] - f.pos[slot]) < 0.005
