"""The shown pelvis's 1-2-1 smoothing (:mod:`posecast.online.engine.pelvis`): uniform
motion kept, a frame-to-frame shake taken out; the engine streams each pose on the
average of its own frame's pelvis and its neighbours', with no lag, on every backend."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from posecast.geometry.rotations import aa2mat, mat2quat, quat2mat
from posecast.online.engine.pelvis import smooth_pelvis, smooth_pelvis_clip
from posecast.online.engine.types import PoseOut, TrackerFrame
from posecast.skeleton import LOWER_BODY, Joint
from posecast.tracking.features import TrackerSlot
from tests.online.engine.conftest import BackendLoader, run_player

WalkFrames = Callable[..., list[TrackerFrame]]


def _turning(n: int, rate: float, axis: tuple[float, float, float]) -> np.ndarray:
    """Rotations ``(n, 3, 3)`` about ``axis`` at ``rate`` radians a frame."""
    a = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    return aa2mat(np.arange(n)[:, None] * rate * a)


def test_uniform_motion_is_kept_and_the_centre_alone_is_the_centre() -> None:
    n = 12
    mats = _turning(n, 0.05, (0.3, 1.0, -0.2))
    places = np.arange(n)[:, None] * np.array([0.01, 0.0, -0.02]) + [0.0, 0.95, 0.0]
    m, p = smooth_pelvis((mats[:-2], mats[1:-1], mats[2:]), (places[:-2], places[1:-1], places[2:]))
    np.testing.assert_allclose(m, mats[1:-1], atol=1e-12)
    np.testing.assert_allclose(p, places[1:-1], atol=1e-12)
    # Neighbours equal to the centre (a player's first frame stands in for its missing one).
    m, p = smooth_pelvis((mats, mats, mats), (places, places, places))
    np.testing.assert_allclose(m, mats, atol=1e-12)
    np.testing.assert_allclose(p, places, atol=1e-12)


def test_a_frame_to_frame_shake_is_taken_out() -> None:
    """A pelvis turning steadily with +-2 degrees of alternating shake on top (and +-5 mm
    of position): the 1-2-1 average is the steady motion again, within 0.2 degrees; the
    sign of a quaternion does not matter."""
    n = 40
    steady = _turning(n, 0.02, (0.0, 1.0, 0.0))
    shake = np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
    noisy = aa2mat(shake[:, None] * np.radians(2.0) * np.array([1.0, 0.0, 0.0])) @ steady
    q = mat2quat(noisy)
    q[::3] *= -1.0  # the same rotations, other signs
    places = np.array([0.0, 0.95, 0.0]) + shake[:, None] * np.array([0.005, 0.0, 0.0])
    m, p = smooth_pelvis_clip(quat2mat(q), places)
    inner = slice(1, n - 1)
    cos = (np.einsum("tij,tij->t", m[inner], steady[inner]) - 1.0) / 2.0
    assert np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))).max() < 0.2
    still = np.broadcast_to([0.0, 0.95, 0.0], p[inner].shape)
    np.testing.assert_allclose(p[inner], still, atol=1e-12)
    raw_cos = (np.einsum("tij,tij->t", noisy[inner], steady[inner]) - 1.0) / 2.0
    assert np.degrees(np.arccos(np.clip(raw_cos, -1.0, 1.0))).min() > 1.9  # the shake was there


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
    """4 points, a shaky waist tracker: with the smoothing (the default) each streamed
    pelvis is the 1-2-1 average of the unsmoothed engine's at the same seq and either
    side (the first frame standing in for its missing neighbour), seq for seq; the legs
    then shake less (mean jerk of the leg joints at most 0.6x); with the smoothing off,
    the pelvis is the waist tracker's."""
    frames = _shaky(walk_frames(0), seed=1)
    cfg = {"samples": 10, "lookahead": 2, "upper_body_ik": False}
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
    """3 points, one sample (so no transitions): the streamed pelvis is the 1-2-1 average
    of the decoder's own pelvis, as the unsmoothed engine streams it."""
    frames = walk_frames(1)
    cfg = {"samples": 1, "lookahead": 1, "upper_body_ik": False}
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


def test_without_look_ahead_the_pelvis_is_its_own(
    backend: BackendLoader, walk_frames: WalkFrames
) -> None:
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
