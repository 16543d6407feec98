"""The engine's half of the forecast (online.engine.forecasting): each forecasting
player's shown poses kept in its slot, and, once enough are kept, its pose replaced by
the forecast of them (the engine-level behaviour is ``test_presence.py``'s)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from posecast.body.forecast import forecast
from posecast.online.engine.forecasting import HISTORY, step_forecast
from posecast.online.engine.slots import SlotArrays
from posecast.skeleton import NUM_JOINTS

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
