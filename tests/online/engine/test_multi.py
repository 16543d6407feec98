"""One engine per model (online.engine.multi): each player in the engine of its layout,
every engine stepped by one tick, their results merged (shipped models, onnx)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from posecast.offline.train.masks import TABLE_SETS
from posecast.online.engine.config import EngineConfig
from posecast.online.engine.multi import MultiEngine
from posecast.online.engine.ssi import Engine
from posecast.online.engine.types import TrackerFrame
from posecast.online.inference.loader import load_engine
from posecast.tracking.sites import TrackerSet

WalkFrames = Callable[..., list[TrackerFrame]]


def _engine(layout: str) -> Engine:
    return load_engine(EngineConfig(samples=4), None, 1, layout, "onnx")


def test_players_go_to_their_layouts_engine_and_one_tick_steps_them_all(
    walk_frames: WalkFrames,
) -> None:
    """A player's poses equal those of an engine of its own layout with it alone, and
    the merged tick carries every player's."""
    multi = MultiEngine({"hmd3+waist": _engine("hmd3+waist"), "hmd3": _engine("hmd3")})
    assert multi.layouts == ("hmd3+waist", "hmd3")
    assert multi.backends == {"hmd3+waist": "onnx", "hmd3": "onnx"}
    multi.add_player("four", 1)  # the default layout
    multi.add_player("three", 2, "hmd3")
    assert multi.counts() == {"hmd3+waist": 1, "hmd3": 1} and multi.player_count == 2
    alone = _engine("hmd3")
    alone.add_player("three", 2)
    frames = walk_frames(0)[:8]
    seen = {"four": 0, "three": 0}
    for f in frames:
        for p in seen:
            multi.push(p, f)
        alone.push("three", f)
        mine = {p.player: p for p in multi.tick().poses}
        for p in mine:
            seen[p] += 1
        for pose in alone.tick().poses:
            np.testing.assert_allclose(mine["three"].positions, pose.positions, atol=1e-5)
    assert seen == {"four": 8, "three": 8}
    multi.remove_player("four")
    assert multi.counts() == {"hmd3+waist": 0, "hmd3": 1} and multi.player_count == 1
    multi.push("three", frames[-1])
    assert [p.player for p in multi.tick().poses] == ["three"]


def test_a_tracker_set_goes_to_the_sites_engine() -> None:
    multi = MultiEngine({"sites": _engine("sites"), "hmd3+waist": _engine("hmd3+waist")})
    multi.add_player("s", 0, TrackerSet.parse(TABLE_SETS["6p"]))
    multi.add_player("t", 1, TrackerSet.parse(TABLE_SETS["3p"]))
    assert multi.counts() == {"sites": 2, "hmd3+waist": 0}


def test_what_a_multi_engine_cannot_serve_is_refused() -> None:
    with pytest.raises(ValueError, match="at least one engine"):
        MultiEngine({})
    with pytest.raises(ValueError, match="the hmd3\\+waist engine runs a hmd3 model"):
        MultiEngine({"hmd3+waist": _engine("hmd3")})
    multi = MultiEngine({"hmd3+waist": _engine("hmd3+waist")})
    with pytest.raises(ValueError, match="'hmd3' is not served"):
        multi.add_player("x", 1, "hmd3")
    multi.add_player("x", 1)
    with pytest.raises(ValueError, match="already in the engine"):
        multi.add_player("x", 2)
    assert multi.player_count == 1
