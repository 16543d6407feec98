"""posecast.online.engine.forecasting: the served forecast's history (ShownHistory:
per player, the last shown poses, a forecast per horizon asked, held until the history
is full, started again after a gap, forgotten when nobody asks), and the engine's own
per-session forecast (step_forecast: each forecasting player's shown poses kept in its
slot and, once enough are kept, its pose replaced by the forecast of them; the
engine-level behaviour is ``test_presence.py``'s)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from posecast.body.forecast import forecast
from posecast.online.engine.forecasting import HISTORY, MAX_SPAN_FRAMES, ShownHistory, step_forecast
from posecast.online.engine.slots import SlotArrays
from posecast.skeleton import NUM_JOINTS
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


FPS = 60.0


@dataclass
class Player:
    forecast_ms: float
    shown: int = 0


def _poses(t: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``n`` poses moving 1 cm a frame along x, turned a little more each frame."""
    pos = np.zeros((n, NUM_JOINTS, 3), np.float32)
    pos[..., 0] = 0.01 * t
    pos[..., 1] = np.linspace(0.0, 1.7, NUM_JOINTS)
    a = 0.02 * t
    rot = np.zeros((n, NUM_JOINTS, 4), np.float32)
    rot[..., 1], rot[..., 3] = np.sin(a / 2), np.cos(a / 2)
    return pos, rot


def test_only_forecasting_players_change_and_only_once_their_history_is_full() -> None:
    slots = SlotArrays(
        {
            "fc_pos": ((HISTORY, NUM_JOINTS, 3), np.float32),
            "fc_rot": ((HISTORY, NUM_JOINTS, 4), np.float32),
        }
    )
    players = [Player(0.0), Player(50.0)]
    at = np.array([slots.add(), slots.add()], np.intp)
    kept_pos, kept_rot = [], []
    for t in range(HISTORY + 2):
        pos, rot = _poses(t, 2)
        shown_pos, shown_rot = pos.copy(), rot.copy()
        kept_pos.append(shown_pos[1])
        kept_rot.append(shown_rot[1])
        ahead = step_forecast(slots, players, at, pos, rot, FPS)
        np.testing.assert_array_equal(pos[0], shown_pos[0])  # not forecasting: as shown
        assert players[0].shown == 0 and ahead[0] == 0.0
        assert players[1].shown == min(t + 1, HISTORY)
        if t + 1 < HISTORY:
            assert ahead[1] == 0.0
            np.testing.assert_array_equal(pos[1], shown_pos[1])
            continue
        assert ahead[1] == 50.0
        window_pos = np.stack(kept_pos[-HISTORY:])[None]
        window_rot = np.stack(kept_rot[-HISTORY:])[None]
        want_pos, want_rot = forecast(window_pos, window_rot, np.array([50.0 * FPS / 1000]), FPS)
        np.testing.assert_allclose(pos[1], want_pos[0], atol=1e-6)
        np.testing.assert_allclose(rot[1], want_rot[0], atol=1e-6)
        assert pos[1, 0, 0] > shown_pos[1, 0, 0] + 0.02  # 3 frames ahead: 3 cm on
        # the slot keeps the shown poses, not the forecast ones
        np.testing.assert_array_equal(slots["fc_pos"][at[1], -1], shown_pos[1])


def test_no_forecasting_player_leaves_everything_alone() -> None:
    slots = SlotArrays({"fc_pos": ((HISTORY, NUM_JOINTS, 3), np.float32),
                        "fc_rot": ((HISTORY, NUM_JOINTS, 4), np.float32)})  # fmt: skip
    at = np.array([slots.add()], np.intp)
    pos, rot = _poses(3, 1)
    before = pos.copy()
    assert step_forecast(slots, [Player(0.0)], at, pos, rot, FPS) == [0.0]
    np.testing.assert_array_equal(pos, before)
    assert not slots["fc_pos"].any()
