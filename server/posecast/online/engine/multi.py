"""One engine per model, one batch per model: players of both layouts in one step.

A server that serves 4-point and headset-only players keeps an :class:`Engine` per
layout. Each player lives in the engine of the layout it declared in ``hello``; a tick
steps every engine that has players (each one decoder call for all of its players'
samples) and merges the results. Rooms do not matter here: a room may mix layouts,
and poses of every engine go to the same broadcast. A player that declared a tracker
set joins the ``sites`` engine, whatever its set: one batch for them all.
"""

from __future__ import annotations

from collections.abc import Mapping

from posecast.online.engine.calibration import Calibration
from posecast.online.engine.selectors import SampleSelector
from posecast.online.engine.ssi import Engine
from posecast.online.engine.types import TickResult, TrackerFrame
from posecast.tracking.layouts import Layout, PlayerLayout, model_layout
from posecast.tracking.sites import TrackerSet


class MultiEngine:
    """The :class:`Engine` interface the server uses, over one engine per layout."""

    def __init__(self, engines: Mapping[str, Engine]) -> None:
        if not engines:
            raise ValueError("a MultiEngine needs at least one engine")
        self.engines = {Layout(k): e for k, e in engines.items()}
        for layout, e in self.engines.items():
            if e.layout.layout is not layout:
                raise ValueError(f"the {layout} engine runs a {e.layout.layout} model")
        self.players: dict[str, Layout] = {}

    @property
    def layouts(self) -> tuple[str, ...]:
        return tuple(str(k) for k in self.engines)

    @property
    def player_count(self) -> int:
        return len(self.players)

    @property
    def backends(self) -> dict[str, str]:
        """The backend each layout's engine runs (``Engine.backend_name``)."""
        return {str(k): e.backend_name for k, e in self.engines.items()}

    def counts(self) -> dict[str, int]:
        """Players per layout (what each batch holds)."""
        return {str(k): e.player_count for k, e in self.engines.items()}

    def _engine(self, player: str) -> Engine:
        return self.engines[self.players[player]]

    def add_player(
        self, player: str, seed: int, layout: PlayerLayout | str = Layout.HMD3_WAIST
    ) -> None:
        """Join ``player`` to the engine of its ``layout`` (a named layout, or a
        :class:`TrackerSet`: the ``sites`` engine)."""
        given = layout if isinstance(layout, TrackerSet) else Layout(layout)
        key = model_layout(given)
        if key not in self.engines:
            raise ValueError(f"layout {str(layout)!r} is not served")
        if player in self.players:
            raise ValueError(f"player {player!r} is already in the engine")
        tracker_set = given if isinstance(given, TrackerSet) else None
        self.engines[key].add_player(player, seed, tracker_set=tracker_set)
        self.players[player] = key

    def remove_player(self, player: str) -> None:
        self._engine(player).remove_player(player)
        del self.players[player]

    def set_selector(self, player: str, selector: SampleSelector) -> None:
        self._engine(player).set_selector(player, selector)

    def set_calibration(self, player: str, calibration: Calibration) -> None:
        self._engine(player).set_calibration(player, calibration)

    def push(self, player: str, frame: TrackerFrame) -> None:
        self._engine(player).push(player, frame)

    def tick(self) -> TickResult:
        out = TickResult([], [], 0)
        for e in self.engines.values():
            r = e.tick()  # an engine without players only advances its clock
            out.poses += r.poses
            out.events += r.events
            out.transitions += r.transitions
        return out
