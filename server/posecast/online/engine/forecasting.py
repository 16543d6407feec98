"""The engine's half of the forecast (:mod:`posecast.body.forecast`): each forecasting
player's last shown poses, kept in its slot, and the forecast of its next one
(:func:`step_forecast`, per player session: ``Engine.set_forecast``); and the served
path, per receiving client's horizon (:class:`ShownHistory`, the wire's
``forecast_ms``)."""

from __future__ import annotations

from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from posecast.body.forecast import SPAN, forecast
from posecast.online.engine.slots import SlotArrays

# Shown poses a forecast extrapolates from: the newest and SPAN frames back.
HISTORY = SPAN + 1
# The most frames the served history may span (frames the server superseded left
# holes in it); past that the player's stream had a gap and its history starts again.
MAX_SPAN_FRAMES = 3 * SPAN


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


class ShownHistory:
    """The served path of the forecast, per *receiving* client's horizon: each player
    some client forecasts, its last :data:`HISTORY` shown poses (newest last), and
    their forecasts for the horizons asked of it. Kept in the engine thread by the
    worker (:class:`posecast.online.shell.ticker.EngineWorker`); a player no client
    forecasts any more is forgotten, so it costs nothing when nobody asks.

    A frame the server superseded (two arrived in one tick) leaves a hole in a
    player's shown frames: the velocities are then over the frames the kept poses
    really span (up to :data:`MAX_SPAN_FRAMES`; a longer hole, a gap in the player's
    stream, starts the history again)."""

    def __init__(self) -> None:
        self._pos: dict[str, NDArray[np.float64]] = {}  # (HISTORY, 19, 3)
        self._rot: dict[str, NDArray[np.float64]] = {}  # (HISTORY, 19, 4)
        self._seq: dict[str, list[int]] = {}  # the kept poses' frames, newest last

    def __bool__(self) -> bool:
        return bool(self._seq)

    def forget(self, player: str) -> None:
        """Start ``player``'s history again (it left, rejoined or recalibrated)."""
        for d in (self._pos, self._rot, self._seq):
            d.pop(player, None)

    def step(
        self,
        players: list[str],
        seqs: list[int],
        pos: NDArray[np.floating],
        rot: NDArray[np.floating],
        horizons: dict[str, frozenset[int]],
        fps: float,
    ) -> dict[int, tuple[list[int], NDArray[np.float64], NDArray[np.float64]]]:
        """Keep the shown poses ``pos (E, 19, 3)``, ``rot (E, 19, 4)`` of ``players``
        (their frames ``seqs``) that ``horizons`` names, and return, per horizon ``h``
        (frames) asked for, the rows of those players and their poses ``h`` frames
        ahead (:func:`posecast.body.forecast.forecast`). A player with fewer than
        :data:`HISTORY` poses kept (it just started, or came back from a gap) is
        held: its pose as shown."""
        for player in [p for p in self._seq if p not in horizons]:
            self.forget(player)
        rows = [i for i, p in enumerate(players) if p in horizons]
        for i in rows:
            p, seq = players[i], seqs[i]
            kept = self._seq.get(p)
            if kept is None or not 0 < seq - kept[-1] <= MAX_SPAN_FRAMES // SPAN:
                self._pos[p] = np.zeros((HISTORY, 19, 3))
                self._rot[p] = np.zeros((HISTORY, 19, 4))
                kept = self._seq[p] = []
            hp, hr = self._pos[p], self._rot[p]
            hp[:-1], hr[:-1] = hp[1:].copy(), hr[1:].copy()
            hp[-1], hr[-1] = pos[i], rot[i]
            kept.append(seq)
            del kept[:-HISTORY]
        out: dict[int, tuple[list[int], NDArray[np.float64], NDArray[np.float64]]] = {}
        for h in sorted({h for i in rows for h in horizons[players[i]]}):
            at = [i for i in rows if h in horizons[players[i]]]
            fp = np.asarray(pos[at], np.float64).copy()
            fr = np.asarray(rot[at], np.float64).copy()
            ready = [k for k, i in enumerate(at) if len(self._seq[players[i]]) == HISTORY]
            if ready:
                names = [players[at[k]] for k in ready]
                # h frames ahead at the velocity over the frames the history spans
                span = np.array([self._seq[p][-1] - self._seq[p][0] for p in names], np.float64)
                fp[ready], fr[ready] = forecast(
                    np.stack([self._pos[p] for p in names]),
                    np.stack([self._rot[p] for p in names]),
                    h * SPAN / span,
                    fps * SPAN / span,  # the speed bound on the real frames' steps
                )
            out[h] = (at, fp, fr)
        return out
