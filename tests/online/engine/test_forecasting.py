"""The served forecast's history (posecast.online.engine.forecasting.ShownHistory):
per player, the last shown poses, a forecast per horizon asked, held until the
history is full, started again after a gap, forgotten when nobody asks."""

from __future__ import annotations

import numpy as np

from posecast.body.forecast import forecast
from posecast.online.engine.forecasting import HISTORY, MAX_SPAN_FRAMES, ShownHistory
from posecast.testing.poses import IDENTITY, REST


def _pose(k: int) -> tuple[np.ndarray, np.ndarray]:
    """A body walking along +z at 1.2 m/s (60 fps), its head turning."""
    pos = REST + np.array([0.0, 0.0, 0.02 * k])
    rot = IDENTITY.copy()
    a = 0.01 * k
    rot[4] = (0.0, np.sin(a / 2), 0.0, np.cos(a / 2))
    return pos, rot


Ahead = dict[int, tuple[list[int], np.ndarray, np.ndarray]]


def _step(
    hist: ShownHistory, seqs: list[int], asked: dict[str, frozenset[int]]
) -> tuple[Ahead, np.ndarray, np.ndarray]:
    poses = [_pose(k) for k in seqs]
    pos = np.stack([p for p, _ in poses])
    rot = np.stack([r for _, r in poses])
    return hist.step(["a", "b"][: len(seqs)], seqs, pos, rot, asked, 60.0), pos, rot


def test_held_until_the_history_is_full_then_the_body_forecast() -> None:
    hist = ShownHistory()
    asked = {"a": frozenset({4})}
    for k in range(HISTORY):
        got, pos, _ = _step(hist, [k], asked)
        at, fp, _ = got[4]
        assert at == [0]
        if k < HISTORY - 1:
            np.testing.assert_array_equal(fp[0], pos[0])  # held
    window = np.stack([_pose(k)[0] for k in range(HISTORY)])[None]
    qwin = np.stack([_pose(k)[1] for k in range(HISTORY)])[None]
    want, _ = forecast(window, qwin, np.array([4.0]), 60.0)
    np.testing.assert_allclose(fp, want)
    # constant velocity: 4 frames on, 8 cm further along z
    np.testing.assert_allclose(fp[0, 0], _pose(HISTORY - 1 + 4)[0][0], atol=1e-9)


def test_a_gap_starts_again_and_only_asked_players_and_horizons() -> None:
    hist = ShownHistory()
    asked = {"a": frozenset({2, 6})}
    for k in range(HISTORY):
        got, _, _ = _step(hist, [k, k], asked)
    assert sorted(got) == [2, 6] and got[2][0] == [0] and got[6][0] == [0]  # not b
    got, pos, _ = _step(hist, [10, 10], asked)  # frames 3-9 missing: held again
    np.testing.assert_array_equal(got[2][1][0], pos[0])
    got, _, _ = _step(hist, [11, 11], {})
    assert got == {} and not hist


def test_superseded_frames_leave_holes_the_velocity_spans() -> None:
    """Frames 1 and 3 superseded by the server: the poses of frames 0, 2, 4 span 4
    frames, so 4 frames ahead is still 8 cm on at 2 cm a frame."""
    hist = ShownHistory()
    for k in (0, 2, 4):
        got, _, _ = _step(hist, [k], {"a": frozenset({4})})
    np.testing.assert_allclose(got[4][1][0, 0], _pose(8)[0][0], atol=1e-9)
    assert MAX_SPAN_FRAMES == 6
