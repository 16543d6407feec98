"""The engine's half of the forecast (:mod:`posecast.body.forecast`): each forecasting
player's last shown poses, kept in its slot, and the forecast of its next one."""

from __future__ import annotations

from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from posecast.body.forecast import SPAN, forecast
from posecast.online.engine.slots import SlotArrays

# Shown poses a forecast extrapolates from: the newest and SPAN frames back.
HISTORY = SPAN + 1


class Forecasting(Protocol):
    forecast_ms: float  # 0: none
    shown: int  # shown poses kept since the forecast (re)started, at most HISTORY


def step_forecast(
    slots: SlotArrays,
    players: list[Forecasting],
    at: NDArray[np.intp],
    pos: NDArray[np.float32],
    rot: NDArray[np.float32],
    fps: float,
) -> list[float]:
    """Keep the shown poses ``pos (E, 19, 3)``, ``rot (E, 19, 4)`` of the emitted
    ``players`` (in slots ``at``) that forecast, in their slot's ``fc_pos`` and
    ``fc_rot``, and replace those poses (in place) by their forecast once
    :data:`HISTORY` are kept; returns each pose's ``ahead_ms`` (0: not a forecast)."""
    ahead = [0.0] * len(players)
    rows = [i for i, p in enumerate(players) if p.forecast_ms > 0.0]
    if not rows:
        return ahead
    hp, hr = slots["fc_pos"], slots["fc_rot"]
    mine = at[rows]
    hp[mine] = np.roll(hp[mine], -1, axis=1)
    hr[mine] = np.roll(hr[mine], -1, axis=1)
    hp[mine, -1], hr[mine, -1] = pos[rows], rot[rows]
    ready = []
    for i in rows:
        p = players[i]
        p.shown = min(p.shown + 1, HISTORY)
        if p.shown == HISTORY:
            ready.append(i)
            ahead[i] = p.forecast_ms
    if ready:
        frames = np.array([ahead[i] for i in ready]) * fps / 1000.0
        fp, fr = forecast(hp[at[ready]], hr[at[ready]], frames, fps)
        pos[ready], rot[ready] = fp, fr
    return ahead
