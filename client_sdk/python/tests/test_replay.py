"""Replay sources: the walk fixture and BVH clips as headsets."""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import numpy as np
import pytest

from posecast_client.errors import BvhError
from posecast_client.sources import RIGS, BvhReplaySource, ReplaySource, TrackerSample, WalkSource
from posecast_client.sources.replay import trackers_from_canonical
from posecast_client.sources.walk import walk_motion, write_walk_bvh

DATA = Path(__file__).resolve().parent / "data"


def walk_trackers(seconds: float, fps: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    return trackers_from_canonical(*walk_motion(seconds, fps, seed))


def same_rotation(a: np.ndarray, b: np.ndarray) -> float:
    """Largest component difference up to the quaternion sign."""
    return float(np.minimum(np.abs(a - b).max(-1), np.abs(a + b).max(-1)).max())


@pytest.mark.parametrize("layout", ["cmu_mb", "cmu_daz"])
def test_cmu_layouts_put_trackers_on_head_hands_and_hips(layout: str) -> None:
    """The golden files hold the walk (seed 1) in CMU units and names; replayed at
    120 Hz with the T-pose frame skipped, the trackers are the walk's own."""
    src = BvhReplaySource(DATA / f"walk_{layout}.bvh", rate_hz=120.0)
    assert src.rig.name == layout
    pos, quat = walk_trackers(0.2, 120.0, seed=1)
    assert src.n_frames == len(pos) == 24
    np.testing.assert_allclose(src.positions, pos, atol=1e-5)  # 6 decimals in file units
    assert same_rotation(src.orientations, quat) < 1e-5


def test_canonical_rig_and_resampling(tmp_path: Path) -> None:
    path = tmp_path / "walk.bvh"
    write_walk_bvh(path, seconds=2.0, fps=120.0, seed=4)
    src = BvhReplaySource(path)  # 120 fps file, 60 Hz out
    assert src.rig is RIGS[0] and src.n_frames == 120 and src.seconds == pytest.approx(2.0)
    pos, quat = walk_trackers(2.0, 120.0, seed=4)
    np.testing.assert_allclose(src.positions, pos[::2], atol=1e-5)
    assert same_rotation(src.orientations, quat[::2]) < 1e-5
    mid = BvhReplaySource(path, rate_hz=80.0)  # 3 source frames per 2 output frames
    np.testing.assert_allclose(mid.positions[1], (pos[1] + pos[2]) / 2, atol=1e-5)


def test_walk_matches_the_servers_walk() -> None:
    synthetic = pytest.importorskip("posecast.offline.motion.synthetic")
    frames = pytest.importorskip("posecast.offline.dataset.frames")
    theirs = frames.derive_frames(synthetic.walk_clip(seconds=3.0, fps=60.0, seed=7))
    ours = WalkSource(seconds=3.0, seed=7)
    np.testing.assert_allclose(ours.positions, theirs["tracker_pos"], atol=1e-5)
    assert same_rotation(ours.orientations, theirs["tracker_quat"]) < 1e-5


def test_unknown_rig_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "odd.bvh"
    path.write_text((DATA / "walk_cmu_mb.bvh").read_text().replace("Head", "Skull"))
    with pytest.raises(BvhError, match="no known rig"):
        BvhReplaySource(path)


def test_noise_and_dropout_statistics() -> None:
    clean = WalkSource(seconds=20.0, seed=2)
    noisy = WalkSource(seconds=20.0, seed=2, noise_m=0.01, noise_rad=0.02, dropout=0.1)
    samples = list(noisy.samples())
    assert len(samples) == clean.n_frames == 1200
    valid = np.array([[s.valid >> i & 1 for i in range(4)] for s in samples])
    assert 0.05 < 1 - valid.mean() < 0.15  # about 10 % of the time lost...
    runs = np.diff(np.flatnonzero(np.diff(valid[:, 0]) != 0))
    assert runs.size and np.median(runs) > 3  # ...in bursts, not single frames
    err = np.array([s.positions - c for s, c in zip(samples, clean.positions, strict=True)])
    assert 0.008 < err.std() < 0.012
    quats = np.array([s.orientations for s in samples])
    np.testing.assert_allclose(np.linalg.norm(quats, axis=-1), 1.0)
    again = [s.valid for s in WalkSource(seconds=20.0, seed=2, dropout=0.1).samples()]
    assert again == [s.valid for s in samples]  # seeded


def test_async_replay_is_paced_in_real_time() -> None:
    src = ReplaySource(np.zeros((12, 4, 3)), np.tile([0, 0, 0, 1.0], (12, 4, 1)), 60.0)

    async def collect() -> list[TrackerSample]:
        return [s async for s in src]

    start = time.monotonic()
    got = asyncio.run(collect())
    assert len(got) == 12 and 0.15 < time.monotonic() - start < 1.0
    times = [s.t for s in got]
    assert all(t is not None for t in times)
    assert np.diff(np.array(times, dtype=float)).mean() == pytest.approx(1 / 60, abs=0.008)


def test_looping_and_offsets() -> None:
    src = WalkSource(seconds=1.0, loop=True, offset_m=(2.0, 0.0, 0.0))
    it = src.samples()
    first = [next(it) for _ in range(130)]
    np.testing.assert_allclose(first[0].positions, first[60].positions)
    assert first[0].positions[3, 0] == pytest.approx(2.0 + walk_trackers(1.0, 60.0, 0)[0][0, 3, 0])
    with pytest.raises(ValueError):
        ReplaySource(np.zeros((5, 11, 3)), np.zeros((5, 11, 4)), 60.0)  # beyond 10 sites
    with pytest.raises(ValueError):
        ReplaySource(np.zeros((5, 3, 3)), np.zeros((5, 4, 4)), 60.0)  # rows disagree


@pytest.mark.parametrize("frame_time", ["inf", "4.9e-324", "1e12"])
def test_a_frame_time_that_is_no_frame_rate_is_refused(tmp_path: Path, frame_time: str) -> None:
    path = tmp_path / "walk.bvh"
    write_walk_bvh(path, seconds=0.5)
    text = path.read_text().replace("Frame Time: 0.01666667", f"Frame Time: {frame_time}")
    path.write_text(text)  # 1/inf, an infinite rate, or resampling to 1.7e15 frames
    with pytest.raises(BvhError, match="Frame Time"):
        BvhReplaySource(path)


def test_rows_the_server_would_refuse_are_untracked() -> None:
    pos = np.zeros((10, 4, 3))
    pos[5, 3, 0] = 0.5  # a one-frame glitch in a clip: 1800 m/s^2 for a synthetic IMU
    quat = np.tile([0.0, 0.0, 0.0, 1.0], (10, 4, 1))
    src = ReplaySource(pos, quat, 60.0, inertial=[False, False, False, True])
    far = ReplaySource(pos + np.array([0.0, 0.0, 999.9]), quat, 60.0, offset_m=(0.0, 0.0, 0.2))
    for s in [*src.samples(), *far.samples()]:
        tracked = [i for i in range(4) if s.valid >> i & 1]
        assert (np.abs(s.positions[tracked]) <= 1000.0).all()
    assert [s.valid for s in src.samples()][3:8] == [0b1111, 0b0111, 0b0111, 0b0111, 0b1111]
    assert {s.valid for s in far.samples()} == {0}
